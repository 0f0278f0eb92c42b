"""How a client command learns that its terminal or its process is being taken away.

A terminal that hangs up sends SIGHUP; a shell, a session manager or `kill` sends SIGTERM. Left
to Python's defaults, both end the process on the spot and whatever it was doing for the rig is
simply dropped. `raising_when_lost` turns them into `ClientLost` in the main thread, so the
command decides what its run needs (`sfdrig structure`: abort the test; `sfdrig sweep`: stop
following, the sweep runs on). SIGKILL cannot be caught: the daemon's operator lease covers it
(`control.daemon.lease`).
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator

#: The signals that take a client away, and what each is called in a run's reason.
LOST_BY = {signal.SIGHUP: "the operator's terminal hung up (SIGHUP)",
           signal.SIGTERM: "the client was told to end (SIGTERM)"}


class ClientLost(Exception):
    """The terminal hung up (SIGHUP) or the process is told to end (SIGTERM)."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.how = LOST_BY[signal.Signals(signum)]
        super().__init__(self.how)

    @property
    def exit_code(self) -> int:
        return 128 + self.signum

    @property
    def hung_up(self) -> bool:
        return self.signum == signal.SIGHUP


def _raise(signum: int, frame: object) -> None:
    raise ClientLost(signum)


@contextlib.contextmanager
def raising_when_lost() -> Iterator[None]:
    """SIGHUP and SIGTERM raise `ClientLost` inside the block (then the old handlers again)."""
    old = {sig: signal.signal(sig, _raise) for sig in LOST_BY}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def hold_further_signals() -> None:
    """While the command answers one loss (an abort on its way), a second signal must not cut
    that short."""
    for sig in LOST_BY:
        signal.signal(sig, signal.SIG_IGN)


def silence_hung_up_terminal() -> None:
    """A hung-up terminal takes no more output: stdout and stderr go to /dev/null, so nothing
    fails (EIO) on the way out."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    for fd in (1, 2):
        os.dup2(devnull, fd)
    os.close(devnull)


__all__ = ["LOST_BY", "ClientLost", "hold_further_signals", "raising_when_lost",
           "silence_hung_up_terminal"]
