"""The sweep engine's states and the transitions allowed between them (one table, no flags)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from enum import StrEnum


class State(StrEnum):
    IDLE = "idle"
    CHECKING = "checking"  # validating targets, limits and the pump interlock
    PRIMING = "priming"  # zero drive, waiting for inlet pressure and the film to fill
    RUNNING = "running"
    PAUSED = "paused"  # drives ramped to zero, acquisition continues
    STOPPING = "stopping"  # drives ramping to zero, buffer read out
    COMPLETED = "completed"
    ABORTED = "aborted"
    FAILED = "failed"
    REFUSED = "refused"  # refused before any output was written


TRANSITIONS: dict[State, frozenset[State]] = {
    State.IDLE: frozenset({State.CHECKING}),
    State.CHECKING: frozenset({State.PRIMING, State.RUNNING, State.REFUSED, State.STOPPING}),
    State.PRIMING: frozenset({State.RUNNING, State.STOPPING}),
    State.RUNNING: frozenset({State.PAUSED, State.STOPPING}),
    State.PAUSED: frozenset({State.RUNNING, State.STOPPING}),
    State.STOPPING: frozenset({State.COMPLETED, State.ABORTED, State.FAILED}),
    State.COMPLETED: frozenset(),
    State.ABORTED: frozenset(),
    State.FAILED: frozenset(),
    State.REFUSED: frozenset(),
}

FINAL = frozenset({State.COMPLETED, State.ABORTED, State.FAILED, State.REFUSED})


class StateMachine:
    """Holds the state; `to` checks each transition against `TRANSITIONS` (thread-safe)."""

    def __init__(self, on_change: Callable[[State, State], None] | None = None) -> None:
        self._state = State.IDLE
        self._lock = threading.Lock()
        self._on_change = on_change

    @property
    def state(self) -> State:
        return self._state

    def to(self, new: State) -> None:
        with self._lock:
            old = self._state
            if new not in TRANSITIONS[old]:
                raise RuntimeError(f"illegal state transition {old.value} -> {new.value}")
            self._state = new
        if self._on_change is not None:
            self._on_change(old, new)
