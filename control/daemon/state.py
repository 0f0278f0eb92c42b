"""The daemon's state machine: one transition table; refusals name the state, the requests it
allows and, in fault, how to reset it."""

from __future__ import annotations

import threading
from collections.abc import Callable

from control.wire.protocol import DaemonState

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


#: The requests that fire an event of the table (the other events are the daemon's own:
#: armed, finished, fault); `start_test` fires "start" as `start` does.
COMMAND_EVENTS = {"start": ("start", "start_test"), "pause": ("pause",), "resume": ("resume",),
                  "abort": ("abort",), "reset": ("reset",)}
#: Requests no state refuses (the pump interlock may refuse a switch; see `control.run.pump`).
ALWAYS_ALLOWED = ("pump", "status", "list_runs")
#: How an operator acknowledges a fault, named in every refusal while in fault.
RESET_HINT = ("reset the fault with `sfdrig status --reset` (or Reset fault on the web page) "
              "once its cause is cleared")


def allowed_commands(state: DaemonState) -> list[str]:
    """The requests the daemon takes in ``state``, in the order of `COMMAND_EVENTS`."""
    fired = {e for (s, e) in TRANSITIONS if s is state}
    if state is S.ABORTING:
        fired.add("abort")  # answered ok (under way), not refused: `Daemon._dispatch`
    return [c for e, cmds in COMMAND_EVENTS.items() if e in fired for c in cmds] \
        + list(ALWAYS_ALLOWED)


def refusal(request: str, state: DaemonState) -> str:
    """Why ``request`` is refused in ``state``: the requests allowed now, and in fault how to
    reset it."""
    text = (f"'{request}' is not allowed while {state.value} (allowed now: "
            f"{', '.join(allowed_commands(state))})")
    return text + ("; " + RESET_HINT if state is S.FAULT else "")


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
                raise TransitionError(refusal(event, self._state))
            old, self._state = self._state, new
            if self._on_change is not None:
                self._on_change(old, new, event)
            return new

