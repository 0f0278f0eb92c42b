"""The board's safe states, as parts that own their state: `SafeStates` (the watchdog timer
tasks, and the AO terminals and lines an expired one holds until its expiration is cleared) and
`EmergencyStop` (the button the wiring puts on an input line), parts of the board
(`simulated_hw.board.device.SimDevice`, which the in-process backend adapts too); what an expiry
does to the generations running is the device's (`SimDevice._expire`: they stop with -200678 at
the expiry's instant)."""

from __future__ import annotations

import threading
from collections.abc import Callable

from daq.channels import EmergencyStopInput
from daq.errors import CANT_RESET_EXPIRED_WATCHDOG, WRITE_FAILED_WATCHDOG_EXPIRED
from simulated_hw.board.codes import daq_error
from simulated_hw.board.watchdog import Watchdog, WatchdogTimer


class SafeStates:
    """The watchdog timer tasks and what their expiry holds.

    Parameters
    ----------
    clock : callable
        The device clock [s].
    lock : lock
        The device lock (the timer's thread expires under it).
    expire : callable
        The owner's action on an expiry, called under the lock with the watchdog; it calls
        `hold` once it has done what happens before the expiry's instant.
    live : bool
        Whether a thread expires the watchdogs on time (a server, whose client may die);
        otherwise they expire when the owner next calls `check` (in process).
    """

    def __init__(self, clock: Callable[[], float], lock: threading.RLock,
                 expire: Callable[[Watchdog], None], live: bool = True) -> None:
        self._clock = clock
        self._lock = lock
        self._live = live
        self._watchdogs: list[Watchdog] = []
        self.locked_ao: dict[str, float] = {}  # AO terminals an expired watchdog holds [V]
        self.locked_do: set[str] = set()  # lines an expired watchdog holds
        self.timer = WatchdogTimer(clock, lock, self.watchdogs, expire)

    def _changed(self) -> None:
        if self._live:
            self.timer.changed()

    def watchdogs(self) -> list[Watchdog]:
        return list(self._watchdogs)

    def add(self, w: Watchdog) -> None:
        with self._lock:
            self._watchdogs.append(w)

    def remove(self, w: Watchdog) -> None:
        """Clearing the task (an expired watchdog's locks stay until ResetDevice)."""
        with self._lock:
            w.running = False
            if w in self._watchdogs:
                self._watchdogs.remove(w)
        self._changed()

    def start(self, w: Watchdog) -> None:
        w.running, w.fed_at = True, self._clock()
        self._changed()

    def stop(self, w: Watchdog) -> None:
        w.running = False
        self._changed()

    def check(self) -> None:
        """Expire what is due now (under the lock)."""
        self.timer.check()

    def feed(self, w: Watchdog, task_name: str) -> None:
        """Reset the timer (DAQmx ControlWatchdogTask RESET_TIMER); -200644 once expired."""
        with self._lock:
            self.timer.check()
            if w.expired:
                raise daq_error(
                    CANT_RESET_EXPIRED_WATCHDOG,
                    f"watchdog task {task_name!r} expired "
                    f"{self._clock() - (w.expired_at or 0.0):.3f} s ago (timeout "
                    f"{w.timeout_s:g} s); clear the expiration first",
                )
            w.fed_at = self._clock()
        self._changed()

    def clear_expiration(self, w: Watchdog) -> dict[str, float]:
        """Unlock what ``w`` holds and restart its timer; returns the AO terminals it unlocked
        with the values they keep [V]."""
        kept: dict[str, float] = {}
        with self._lock:
            if w.expired:
                for p, v in w.ao_states.items():
                    kept[p] = self.locked_ao.pop(p, v)
                for line in w.do_states:
                    self.locked_do.discard(line)
            w.expired, w.expired_at, w.fed_at = False, None, self._clock()
            w.expired_event.clear()
        self._changed()
        return kept

    def hold(self, w: Watchdog) -> None:
        """``w`` has expired (at its deadline): its outputs and lines are held in their
        expiration states from now on."""
        deadline = w.deadline()
        w.expired = True
        w.expired_at = deadline if deadline is not None else self._clock()
        self.locked_ao.update(w.ao_states)
        self.locked_do.update(w.do_states)

    def refuse_locked(self, where: str, physical: list[str]) -> None:
        """-200678 if a write would change a terminal or line an expired watchdog holds."""
        held = sorted(p for p in physical if p in self.locked_ao or p in self.locked_do)
        if held:
            raise daq_error(
                WRITE_FAILED_WATCHDOG_EXPIRED,
                f"{where}: {held} held in the watchdog expiration state; clear the expiration",
            )

    def close(self) -> None:
        self.timer.close()


class EmergencyStop:
    """The emergency-stop button on an input line (``button``: the wiring's; None: none)."""

    def __init__(self, button: EmergencyStopInput | None) -> None:
        self.button = button
        self.pressed = False

    def press(self, pressed: bool) -> tuple[str, bool] | None:
        """Press or release it; returns its line and the level the line now reads (None
        without a button)."""
        self.pressed = bool(pressed)
        if self.button is None:
            return None
        b = self.button
        return b.physical_channel, b.pressed_level if self.pressed else not b.pressed_level

    def level_on(self, line: str) -> bool:
        """What ``line`` reads from the button: its level on the button's line; any other line
        is open and reads low (the board's pull-down)."""
        b = self.button
        if b is None or b.physical_channel != line:
            return False
        return b.pressed_level if self.pressed else not b.pressed_level
