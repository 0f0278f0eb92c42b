"""The board's watchdog timer task (DAQmx ``WatchdogTask``): if the program stops resetting it
for ``timeout_s``, the board puts its lines and analog outputs in the expiration states on its
own, and keeps them there (writes fail with -200678) until the expiration is cleared.

`WatchdogTimer` is the board's timer: one thread that sleeps until the earliest deadline of the
running watchdogs and expires them; it needs no RPC, so a client that dies still trips it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class Watchdog:
    """One watchdog timer task's settings and state (times on the device clock [s])."""

    device_name: str
    timeout_s: float  # -1: never expires on time
    ao_states: dict[str, float] = field(default_factory=dict)  # AO terminal -> volts
    do_states: dict[str, bool] = field(default_factory=dict)  # DO line -> level
    running: bool = False
    fed_at: float = 0.0
    expired: bool = False
    expired_at: float | None = None
    #: set when it expires (for observers in this process, e.g. tests)
    expired_event: threading.Event = field(default_factory=threading.Event)

    def deadline(self) -> float | None:
        """When it expires unless fed; None when it cannot expire now."""
        if not self.running or self.expired or self.timeout_s < 0:
            return None
        return self.fed_at + self.timeout_s


class WatchdogTimer:
    """Expires the running watchdogs whose deadline has passed, on its own thread.

    Parameters
    ----------
    clock : callable
        The device clock [s].
    lock : lock
        The device lock, held while deadlines are read and watchdogs expire.
    watchdogs : callable
        The watchdogs to watch (read under the lock).
    expire : callable
        Called under the lock with a watchdog whose deadline passed.
    """

    def __init__(self, clock: Callable[[], float], lock: threading.RLock,
                 watchdogs: Callable[[], list[Watchdog]],
                 expire: Callable[[Watchdog], None]) -> None:
        self._clock = clock
        self._lock = lock
        self._watchdogs = watchdogs
        self._expire = expire
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def changed(self) -> None:
        """A watchdog was started, fed or stopped: recompute the next deadline."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, name="sim-daqmx-watchdog",
                                            daemon=True)
            self._thread.start()
        self._wake.set()

    def deadlines(self) -> list[float]:
        """When each running watchdog expires unless fed (device clock) [s]."""
        return [d for w in self._watchdogs() if (d := w.deadline()) is not None]

    def expire_due(self, now: float) -> None:
        """Expire what is due at ``now`` (under the lock; a catch-up's instant)."""
        for w in self._watchdogs():
            deadline = w.deadline()
            if deadline is not None and now >= deadline:
                self._expire(w)

    def check(self) -> None:
        """Expire what is due now (under the lock)."""
        now = self._clock()
        for w in self._watchdogs():
            deadline = w.deadline()
            if deadline is not None and now >= deadline:
                self._expire(w)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(5.0)

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._wake.clear()
            with self._lock:
                self.check()
                deadlines = [d for w in self._watchdogs() if (d := w.deadline()) is not None]
            wait = max(min(deadlines) - self._clock(), 0.0) if deadlines else None
            self._wake.wait(wait)
