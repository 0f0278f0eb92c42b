"""A structure or instrument test run by the daemon: the programme of
`control.run.programs.procedures` behind the `control.run.engine.Engine` protocol, with its
operator desk, whose pending question the daemon's status shows to every front end."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from control.run.listener import Listener
from control.run.programs.impact import run_impact_test
from control.run.programs.operator import OperatorDesk
from control.run.programs.procedures import run_flow_test, run_probe_calibration, run_static_test
from control.run.programs.specs import FlowSpec, ImpactSpec, ProbeCalSpec, ProgramSpec, StaticSpec
from control.run.programs.stream import ProgramOutcome, RigHands
from daq.backend import DaqBackend
from storage.records import StepRecord

SPECS: dict[str, type[ProgramSpec]] = {"static": StaticSpec, "impact": ImpactSpec,
                                       "probe_calibration": ProbeCalSpec, "flow": FlowSpec}
DRY_TESTS = ("static", "impact", "probe_calibration")


class _Counting:
    """Passes everything on to the run's listener and counts the steps."""

    def __init__(self, listener: Listener) -> None:
        self.listener = listener
        self.steps = 0

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        self.listener.on_block(first_sample, ai, ao)

    def on_step(self, step: StepRecord) -> None:
        self.steps += 1
        self.listener.on_step(step)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        self.listener.on_event(kind, message, sample)


class ProgramEngine:
    """One test programme with its operator desk. ``hands`` only on the simulated rig."""

    can_pause = False  # a person is in the loop: they answer, repeat, skip or abort
    steps_total = None  # the operator decides: repeat, skip, abort

    def __init__(self, kind: str, backend: DaqBackend, spec: ProgramSpec, listener: Listener,
                 desk: OperatorDesk, hands: RigHands | None = None,
                 set_pump: Callable[[bool], None] | None = None) -> None:
        self.kind, self.backend, self.spec = kind, backend, spec
        self.listener = _Counting(listener)
        self.desk, self.hands, self.set_pump = desk, hands, set_pump

    def run(self) -> ProgramOutcome:
        b, lst, d, h = self.backend, self.listener, self.desk, self.hands
        try:
            match self.spec:
                case StaticSpec():
                    return run_static_test(b, lst, self.spec, operator=d, hands=h)
                case ImpactSpec():
                    return run_impact_test(b, lst, d, self.spec, hands=h)
                case ProbeCalSpec():
                    return run_probe_calibration(b, lst, d, self.spec, hands=h)
                case FlowSpec():
                    return run_flow_test(b, lst, d, self.spec, hands=h, set_pump=self.set_pump)
        finally:
            if h is not None and self.kind in DRY_TESTS:
                h.set_journal(True)  # the simulated rig's next sweep has its seal again

    def check(self) -> None:
        return None  # the person at the rig checks the set-up; the daemon checks the pump

    def abort(self, reason: str) -> None:
        self.desk.abort(reason)

    def pause(self) -> None:
        raise RuntimeError("a structure test does not pause (answer its question, or abort)")

    def resume(self) -> None:
        raise RuntimeError("a structure test does not pause, so it does not resume")

    @property
    def progress(self) -> dict[str, Any]:
        return {"test": self.kind, "steps_done": self.listener.steps}

    def progress_fields(self) -> dict[str, Any]:
        return self.progress

    @property
    def summary(self) -> None:
        return None  # peaks are a sweep's: a programme's drive is a DC level the operator sets

    def tolerance(self) -> None:
        return None


__all__ = ["DRY_TESTS", "SPECS", "ProgramEngine"]
