"""Contract A in practice: a sweep written by the storage engineer's RunWriter reads back."""

from __future__ import annotations

import numpy as np
import pytest

from control.run.listener import FanOut, RecordingListener
from control.run.pump import PumpRelay
from control.run.sweep.engine import SweepEngine, SweepSpec
from daq.channels import default_channel_map
from storage import reader, runfile
from tests.control.conftest import make_backend


def test_sweep_into_a_run_file(tmp_path):
    be = make_backend(seed=12)
    pump = PumpRelay(be)
    pump.set(True)
    cm = default_channel_map()
    spec = SweepSpec(motion="x", lubricated=True, amplitude_m=[25e-6], freq_hz=[30.0, 50.0],
                     record_cycles=20)
    path = tmp_path / "run.h5"
    writer = runfile.RunWriter.create(
        path, "test-run", "sweep", channels=cm.to_json_dict()["ai"], ao_names=cm.ao_names,
        sample_rate_hz=cm.sample_rate_hz, channel_map=cm.to_json_dict(),
        test_spec=spec.model_dump(mode="json"), lubricated=True,
    )
    rec = RecordingListener(keep_blocks=False)
    out = SweepEngine(be, spec, listener=FanOut([writer, rec]), pump=pump).run()
    writer.close(out.status, out.reason)
    assert out.status == "completed"
    run = reader.open_run(path)
    steps = run.steps
    assert [s["freq_hz"] for s in steps] == [30.0, 50.0]
    for st, mine in zip(steps, rec.wire_steps, strict=True):
        assert st["first_sample"] == mine["first_sample"] and st["converged"]
        x = run.signal("x", st["first_sample"], st["last_sample"])
        t = np.arange(st["first_sample"], st["last_sample"]) / cm.sample_rate_hz
        z = 2 * np.mean(x * np.exp(-2j * np.pi * st["freq_hz"] * t))
        assert abs(z) == pytest.approx(25e-6, rel=0.01)
    kinds = {e["kind"] for e in run.events}
    assert {"state", "pump", "info"} <= kinds
