"""Diagnose a run recorded by the real sweep engine (closed-loop displacement control) on the
simulated rig with a hidden cubic spring: the run file as the daemon writes it, nothing else."""

from __future__ import annotations

import pytest

from analysis.diagnose import diagnose, load_run
from control.pump import PumpRelay
from control.sweep import SweepEngine
from daq.channels import default_channel_map
from simulated_hw import RigParams, SimulatedBackend
from storage.runfile import RunWriter
from tests.analysis.hidden_effects import config_rig


def test_sweep_engine_run_with_hidden_cubic_spring(tmp_path):
    config = config_rig()
    data = config.model_dump(mode="python")
    data["effects"]["cubic_stiffness"] = {"enabled": True, "k3_n_per_m3": 3e13}
    backend = SimulatedBackend(RigParams.model_validate(data), seed=3)
    cm = default_channel_map()
    backend.configure(cm)
    pump = PumpRelay(backend)
    pump.set(True)
    spec = {"motion": "circular_forward", "lubricated": True,
            "amplitude_m": [15e-6, 30e-6, 45e-6], "freq_hz": [20.0, 30.0, 40.0, 50.0],
            "record_cycles": 10, "settle_cycles": 5, "on_not_converged": "continue"}
    path = tmp_path / "sweep.h5"
    writer = RunWriter.create(path, "sweep-1", "sweep", cm.to_json_dict()["ai"], cm.ao_names,
                              cm.sample_rate_hz, channel_map=cm.to_json_dict(),
                              rig_config=config.model_dump(mode="json"), lubricated=True,
                              flush_interval_s=0, swmr=False)
    outcome = SweepEngine(backend, spec, pump=pump, listener=writer).run()
    writer.close()
    assert outcome.status == "completed"
    record = load_run(path)
    assert len(record.segments) == 12
    diag = diagnose([record], seed=1)
    assert diag.baseline_kind == "config"
    assert [f.effect for f in diag.findings] == ["cubic_stiffness"]
    k3 = diag.findings[0].parameters["k3_N_per_m3"]
    assert k3 == pytest.approx(3e13, rel=0.10)
    assert not diag.unexplained
