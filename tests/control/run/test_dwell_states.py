"""Each dwell as named states: approach -> converge -> settle -> record -> done."""

from __future__ import annotations

import logging
import re

import pytest

from control.run.listener import RecordingListener
from control.run.pump import PumpRelay
from control.run.sweep.dwell_states import DWELL_TRANSITIONS, DwellMachine, DwellState
from control.run.sweep.engine import SweepEngine, SweepSpec
from tests.control.conftest import make_backend


def test_every_dwell_of_a_sweep_passes_its_states_in_order(caplog):
    be = make_backend(seed=11)
    pump = PumpRelay(be)
    pump.set(True)
    seen_at_step: list[str] = []

    class Steps(RecordingListener):
        def on_step(self, step):
            super().on_step(step)
            seen_at_step.append(engine.progress.dwell)

    spec = SweepSpec(motion="x", lubricated=True, amplitude_m=[25e-6], freq_hz=[30.0, 50.0])
    engine = SweepEngine(be, spec, listener=Steps(keep_blocks=False), pump=pump)
    with caplog.at_level(logging.DEBUG, logger="control.run.sweep.dwell_states"):
        out = engine.run()
    assert out.status == "completed", out.reason
    paths: dict[str, list[tuple[str, int]]] = {}
    for rec in caplog.records:
        m = re.fullmatch(r"(step \d+/\d+ .*\)): (?:\w+ -> )?(\w+) at sample (\d+)",
                         rec.getMessage())
        assert m, rec.getMessage()
        paths.setdefault(m[1], []).append((m[2], int(m[3])))
    assert len(paths) == 2
    for step, (where, path) in zip(out.steps, paths.items(), strict=True):
        states = [s for s, _ in path]
        assert states[:2] == ["approach", "converge"] and states[-2:] == ["record", "done"], where
        assert states[-3] == "settle"  # recorded only after windows inside the band agreed
        samples = [k for _, k in path]
        assert samples == sorted(samples)
        # the recording starts where record was entered and ends where done was
        assert (path[-2][1], path[-1][1]) == (step.first_sample, step.last_sample)
    assert seen_at_step == ["done", "done"]


def test_the_transition_table_refuses_a_skipped_state():
    machine = DwellMachine()
    machine.begin("step 0 (x, 25 um displacement, 30 Hz)", 0)
    with pytest.raises(RuntimeError, match=r"step 0 \(x, 25 um displacement, 30 Hz\): illegal "
                                           "dwell transition approach -> record"):
        machine.to(DwellState.RECORD, 10)
    machine.to(DwellState.CONVERGE, 10)
    machine.to(DwellState.CONVERGE, 20)  # still converging: no transition
    assert machine.state is DwellState.CONVERGE
    # every state but done is left, and done is reached from every state after the approach
    assert all(DWELL_TRANSITIONS[s] for s in DwellState if s is not DwellState.DONE)
    assert {s for s in DwellState if DwellState.DONE in DWELL_TRANSITIONS[s]} == {
        DwellState.CONVERGE, DwellState.SETTLE, DwellState.RECORD}
