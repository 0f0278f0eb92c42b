"""The board's safe states, as a mixin of `simulated_hw.board.device.SimDevice`: the watchdog
timer tasks (what their expiry does to the outputs and lines, and the locks it leaves until the
expiration is cleared) and the emergency-stop button on an input line."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from daq.channels import ChannelMap
from daq.errors import CANT_RESET_EXPIRED_WATCHDOG, WRITE_FAILED_WATCHDOG_EXPIRED
from simulated_hw.board.codes import daq_error
from simulated_hw.board.tasks import SimTask
from simulated_hw.board.watchdog import Watchdog, WatchdogTimer

_log = logging.getLogger("simulated_hw.board.device")


class SafeStates:
    """Watchdogs and the emergency stop; needs the device's state declared below."""

    lock: threading.RLock
    fast: bool
    wiring: ChannelMap
    _clock: Callable[[], float]
    watchdog_timer: WatchdogTimer
    _watchdogs: list[Watchdog]
    ao_tasks: list[SimTask]
    ai_task: SimTask | None
    ao_hold: dict[str, float]
    locked_ao: dict[str, float]
    locked_do: set[str]
    inputs: dict[str, bool]
    lines: dict[str, bool]
    _advance: Callable[[int], None]
    _due: Callable[[], int]
    _sample_at: Callable[[float], int]
    _set_lines: Callable[[dict[str, bool]], None]

    # --- the watchdog timer ---------------------------------------------------------------
    def _start_watchdog(self, task: SimTask) -> None:
        w = task.watchdog
        w.running, w.fed_at = True, self._clock()
        self.watchdog_timer.changed()

    def feed_watchdog(self, task: SimTask) -> None:
        """Reset the timer (DAQmx ControlWatchdogTask RESET_TIMER); -200644 once expired."""
        with self.lock:
            self.watchdog_timer.check()
            w = task.watchdog
            if w.expired:
                raise daq_error(
                    CANT_RESET_EXPIRED_WATCHDOG,
                    f"watchdog task {task.name!r} expired "
                    f"{self._clock() - (w.expired_at or 0.0):.3f} s ago (timeout "
                    f"{w.timeout_s:g} s); clear the expiration first",
                )
            w.fed_at = self._clock()
        self.watchdog_timer.changed()

    def clear_expiration(self, task: SimTask) -> None:
        """Unlock the lines and outputs an expired watchdog holds (they keep their values)."""
        with self.lock:
            w = task.watchdog
            if w.expired:
                for p, v in w.ao_states.items():
                    self.ao_hold[p] = self.locked_ao.pop(p, v)
                for line in w.do_states:
                    self.locked_do.discard(line)
            w.expired, w.expired_at, w.fed_at = False, None, self._clock()
            w.expired_event.clear()
        self.watchdog_timer.changed()

    def _expire(self, w: Watchdog) -> None:
        """The board's own action on expiry: outputs and lines to their expiration states,
        the generations on them stopped, both held there until the expiration is cleared."""
        deadline = w.deadline()
        if self.ai_task is not None and not self.fast:
            due = self._due()  # everything before the expiry happened first, nothing after
            if deadline is not None:
                due = min(due, self._sample_at(deadline))
            self._advance(due)
        w.expired = True
        w.expired_at = deadline if deadline is not None else self._clock()
        _log.warning("watchdog on %s expired: AO %s, lines %s", w.device_name, w.ao_states,
                     w.do_states)
        for task in list(self.ao_tasks):
            if any(ch.physical[0] in w.ao_states for ch in task.channels):
                task.error = task.error or daq_error(
                    WRITE_FAILED_WATCHDOG_EXPIRED,
                    f"task {task.name!r}: the watchdog timer expired (not reset for "
                    f"{w.timeout_s:g} s); its outputs are held in the expiration states",
                )
        self.locked_ao.update(w.ao_states)
        self.locked_do.update(w.do_states)
        self._set_lines(w.do_states)
        w.expired_event.set()

    def _refuse_locked(self, task: SimTask | None, physical: list[str]) -> None:
        held = sorted(p for p in physical if p in self.locked_ao or p in self.locked_do)
        if held:
            where = f"write to {task.name!r}" if task is not None else "write"
            raise daq_error(
                WRITE_FAILED_WATCHDOG_EXPIRED,
                f"{where}: {held} held in the watchdog expiration state; clear the expiration",
            )

    def watchdogs(self) -> list[Watchdog]:
        return list(self._watchdogs)

    def add_watchdog(self, w: Watchdog) -> None:
        with self.lock:
            self._watchdogs.append(w)

    def remove_watchdog(self, w: Watchdog) -> None:
        """Clearing the task (an expired watchdog's locks stay until ResetDevice)."""
        with self.lock:
            w.running = False
            if w in self._watchdogs:
                self._watchdogs.remove(w)
        self.watchdog_timer.changed()

    def press_estop(self, pressed: bool) -> None:
        """Press or release the emergency-stop button the wiring map puts on an input line
        (no-op without one): the line then reads its ``pressed_level``."""
        estop = self.wiring.estop
        if estop is not None:
            with self.lock:
                level = estop.pressed_level if pressed else not estop.pressed_level
                self.inputs[estop.physical_channel] = level
                _log.warning("emergency stop %s (%s reads %s)", "pressed" if pressed else
                             "released", estop.physical_channel, "high" if level else "low")

    def line_level(self, line: str) -> bool:
        """What a digital line reads: an input's external level, else what the port drives."""
        with self.lock:
            return self.inputs.get(line, self.lines.get(line, False))
