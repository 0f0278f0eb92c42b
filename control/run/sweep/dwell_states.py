"""The states of one dwell and the transitions allowed between them (one table, as the sweep
engine's `states`).

    approach  the drive and the frequency move to the predicted drive, raises watched
              (`control.run.sweep.approach`)
    converge  a window outside the tolerance band: the controller corrects the drive
    settle    windows inside the band: wait ``settle_cycles`` after the last change until
              successive windows agree
    record    ``record_cycles`` whole cycles demodulated as they arrive; a recording that
              drifted out of the band goes back to converge
    done      the dwell's result is made (converged, or why not)

A soft-limit event in settle (the drive halved) goes back to converge; a dwell that cannot
converge ends from converge or settle.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from enum import StrEnum

log = logging.getLogger(__name__)


class DwellState(StrEnum):
    APPROACH = "approach"
    CONVERGE = "converge"
    SETTLE = "settle"
    RECORD = "record"
    DONE = "done"


DWELL_TRANSITIONS: dict[DwellState, frozenset[DwellState]] = {
    DwellState.APPROACH: frozenset({DwellState.CONVERGE}),
    DwellState.CONVERGE: frozenset({DwellState.SETTLE, DwellState.DONE}),
    DwellState.SETTLE: frozenset({DwellState.CONVERGE, DwellState.RECORD, DwellState.DONE}),
    DwellState.RECORD: frozenset({DwellState.CONVERGE, DwellState.DONE}),
    DwellState.DONE: frozenset(),
}


class DwellMachine:
    """The present dwell's state; `to` checks each transition against `DWELL_TRANSITIONS` and
    logs it with the dwell and the sample (a move to the state it is in is no transition).
    ``on_change(state)`` is told every new state (the sweep's progress shows it)."""

    def __init__(self, on_change: Callable[[DwellState], None] | None = None) -> None:
        self.state = DwellState.DONE
        self.where = ""  # the dwell, for the log (`StepPlan.describe`)
        self.on_change = on_change

    def begin(self, where: str, sample: int) -> None:
        """A new dwell starts with its approach."""
        self.state, self.where = DwellState.APPROACH, where
        log.debug("%s: approach at sample %d", where, sample)
        if self.on_change is not None:
            self.on_change(self.state)

    def to(self, new: DwellState, sample: int) -> None:
        old = self.state
        if new is old:
            return
        if new not in DWELL_TRANSITIONS[old]:
            raise RuntimeError(f"{self.where}: illegal dwell transition {old.value} -> "
                               f"{new.value}")
        self.state = new
        log.debug("%s: %s -> %s at sample %d", self.where, old.value, new.value, sample)
        if self.on_change is not None:
            self.on_change(new)
