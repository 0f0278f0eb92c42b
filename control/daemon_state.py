"""The daemon's state machine: one transition table, refusals name the state and what it allows."""

from __future__ import annotations

import threading
from collections.abc import Callable

from control.wire import DaemonState

S = DaemonState

#: (state, event) -> next state. Anything absent is refused.
TRANSITIONS: dict[tuple[DaemonState, str], DaemonState] = {
    (S.IDLE, "start"): S.ARMING,
    (S.ARMING, "armed"): S.RUNNING,
    (S.ARMING, "abort"): S.ABORTING,
    (S.RUNNING, "pause"): S.PAUSED,
    (S.RUNNING, "abort"): S.ABORTING,
    (S.PAUSED, "resume"): S.RUNNING,
    (S.PAUSED, "abort"): S.ABORTING,
    (S.ARMING, "finished"): S.IDLE,
    (S.RUNNING, "finished"): S.IDLE,
    (S.PAUSED, "finished"): S.IDLE,
    (S.ABORTING, "finished"): S.IDLE,
    (S.IDLE, "fault"): S.FAULT,  # the emergency stop pressed between runs
    (S.ARMING, "fault"): S.FAULT,
    (S.RUNNING, "fault"): S.FAULT,
    (S.PAUSED, "fault"): S.FAULT,
    (S.ABORTING, "fault"): S.FAULT,
    (S.FAULT, "reset"): S.IDLE,
}


class TransitionError(RuntimeError):
    """An event the transition table does not allow in the current state."""


class StateMachine:
    """The daemon's state, changed only through `TRANSITIONS`; thread-safe.

    ``on_change(old, new, event)`` is called (under the lock) after every transition.
    """

    def __init__(self, on_change: Callable[[DaemonState, DaemonState, str], None] | None = None):
        self.lock = threading.RLock()
        self._state = S.IDLE
        self._on_change = on_change

    @property
    def state(self) -> DaemonState:
        return self._state

    def allowed(self, event: str) -> bool:
        return (self._state, event) in TRANSITIONS

    def fire(self, event: str) -> DaemonState:
        with self.lock:
            new = TRANSITIONS.get((self._state, event))
            if new is None:
                allowed = sorted(e for (s, e) in TRANSITIONS if s is self._state)
                raise TransitionError(
                    f"'{event}' is not allowed while {self._state.value} "
                    f"(allowed: {', '.join(allowed) or 'none'})"
                )
            old, self._state = self._state, new
            if self._on_change is not None:
                self._on_change(old, new, event)
            return new

