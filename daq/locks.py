"""Advisory locks that a dead process releases: one holder at a time of a board or a runs
directory.

An exclusive, non-blocking `fcntl.flock` on a lock file. The kernel drops a flock when its holder
exits, however it exits (killed, crashed), so the lock of a dead holder is simply taken over: no
stale locks. The lock files are never deleted (deleting one would let two holders lock two
files). Each lock file holds its holder's pid, its command line and what it serves, for the
message of the refusal. The board's lock is `daq.board.board_lock`; the runs directory's is
`control.daemon.instance.runs_lock`.
"""

from __future__ import annotations

import fcntl
import json
import os
import shlex
import sys
import tempfile
from pathlib import Path
from typing import Any


class AlreadyRunning(RuntimeError):
    """Another live process holds the lock; ``holder`` is what its lock file says."""

    def __init__(self, message: str, holder: dict[str, Any]) -> None:
        super().__init__(message)
        self.holder = holder


class InstanceLock:
    """An exclusive, non-blocking flock on ``path``, held until `release` or the process ends.

    Parameters
    ----------
    path : Path
        The lock file (created if missing, never deleted).
    what : str
        What the lock guards, for messages ("runs directory runs", "nidaqmx device Dev1 ...").
    """

    def __init__(self, path: Path, what: str) -> None:
        self.path = Path(path)
        self.what = what
        self._fd: int | None = None

    def acquire(self, **info: Any) -> InstanceLock:
        """Take the lock and write ``{"pid": ..., "argv": ..., **info}`` into the file.

        Raises
        ------
        AlreadyRunning
            If another process holds it (the message names its pid, its command line and
            ``info``).
        """
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise AlreadyRunning(f"{self.what} is in use by {describe_holder(holder)}",
                                 holder) from None
        except BaseException:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({"pid": os.getpid(), "argv": command_line(), **info}).encode(),
                  0)
        self._fd = fd
        return self

    def update(self, **info: Any) -> None:
        """Add to what the lock file says about its holder (e.g. the endpoints once bound)."""
        if self._fd is None:
            return
        holder = {**_read_holder(self._fd), **info, "pid": os.getpid()}
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, json.dumps(holder).encode(), 0)

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None


def command_line() -> str:
    """This process's command as typed: ``sfdrig daemon --backend nidaqmx ...`` (``python -m
    sfdrig`` and the ``sfdrig`` script alike)."""
    prog = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "python"
    if prog in ("__main__.py", "sfdrig"):
        prog = "sfdrig"
    return shlex.join([prog, *sys.argv[1:]])


def _read_holder(fd: int) -> dict[str, Any]:
    try:
        data = json.loads(os.pread(fd, 65536, 0) or b"{}")
    except ValueError:
        return {}
    return data if isinstance(data, dict) else {}


def describe_holder(holder: dict[str, Any]) -> str:
    """``pid 1234 (sfdrig daemon ...), command=tcp://... data=tcp://..., runs dir runs`` from a
    lock file's fields."""
    parts = [f"pid {holder.get('pid', '?')}"
             + (f" ({holder['argv']})" if holder.get("argv") else "")]
    if holder.get("command"):
        parts.append(f"command={holder['command']} data={holder.get('data', '?')}")
    elif holder.get("daemon") and "command" not in holder:
        parts.append("still starting")
    if holder.get("runs_dir"):
        parts.append(f"runs dir {holder['runs_dir']}")
    return ", ".join(parts)


def runtime_dir() -> Path:
    """This user's directory for board locks: ``$SFDRIG_RUNTIME_DIR`` if set, else
    ``$XDG_RUNTIME_DIR/sfdrig``, else ``<tmp>/sfdrig-<uid>``."""
    if os.environ.get("SFDRIG_RUNTIME_DIR"):
        return Path(os.environ["SFDRIG_RUNTIME_DIR"])
    base = os.environ.get("XDG_RUNTIME_DIR")
    if base and Path(base).is_dir():
        return Path(base) / "sfdrig"
    return Path(tempfile.gettempdir()) / f"sfdrig-{os.getuid()}"
