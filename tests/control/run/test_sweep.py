"""Sweeps on the simulated rig (fast mode): holding amplitudes, orbits, events, contract A."""

from __future__ import annotations

import json

import numpy as np
import pytest

from control.run.listener import RecordingListener
from control.run.pump import PumpRelay
from control.run.safety import SafetyLimits
from control.run.sweep.engine import SweepEngine, SweepSpec
from rig_model.params import RigParams
from tests.control.conftest import make_backend

# The simulated dry rig (C_rv = 370 N.s/m, F_mu = 26 N) would answer a 40 N circular load with
# ~141 um near 45 Hz (~190 um near 30 Hz with the 39 Hz frame mode on): past the 127 um clearance,
# where the journal now stops it (contact, a fault). The report's rig ran these loads safely; here
# the dry load sweeps leave the resonance out, as examples/dry_circular.toml does.
DRY_FREQS_HZ = [20.0, *[float(f) for f in range(70, 201, 10)]]
DRY_LIMITS = SafetyLimits(max_displacement_m=110e-6)


def _amp(step: dict, names: list[str]) -> complex:
    return complex(np.mean([complex(*step["harmonics"][n][0]) for n in names]))


def test_lubricated_x_sweep_holds_displacement_within_1_percent():
    be = make_backend(seed=11)
    pump = PumpRelay(be)
    pump.set(True)
    rec = RecordingListener(keep_blocks=False)
    spec = SweepSpec(motion="x", lubricated=True, amplitude_m=[13e-6, 38e-6],
                     freq_start_hz=20, freq_stop_hz=60, freq_step_hz=10)
    out = SweepEngine(be, spec, listener=rec, pump=pump).run()
    assert out.status == "completed", out.reason
    assert len(rec.wire_steps) == 10
    for step in rec.wire_steps:
        assert step["converged"], step["reason"]
        x = _amp(step, ["x1", "x2"])
        assert abs(abs(x) / step["target_value"] - 1) <= 0.01, (step["freq_hz"], abs(x))
        assert step["drive_v"]["shaker_y"] == [0.0, 0.0]
        assert step["last_sample"] - step["first_sample"] == round(40 * 10_000 / step["freq_hz"])
    assert [s["target_value"] for s in rec.wire_steps[:5]] == [13e-6] * 5
    assert rec.events_of("pump")
    assert not pump.shakers_active


@pytest.mark.parametrize("second_mode", [False, True])
def test_dry_circular_load_orbit_40n_20_to_200_hz_off_resonance(second_mode: bool):
    params = RigParams()
    if second_mode:
        params = RigParams.model_validate(
            {"effects": {"second_mode": {"enabled": True, "frequency_hz": 39.0}}})
    be = make_backend(params, seed=5)
    rec = RecordingListener(keep_blocks=False)
    spec = SweepSpec(motion="circular_forward", load_n=[40.0], freq_hz=DRY_FREQS_HZ)
    out = SweepEngine(be, spec, limits=DRY_LIMITS, listener=rec).run()
    assert out.status == "completed", out.reason
    assert [s["freq_hz"] for s in rec.wire_steps] == DRY_FREQS_HZ
    for step in rec.wire_steps:
        fx, fy = complex(*step["harmonics"]["fx"][0]), complex(*step["harmonics"]["fy"][0])
        assert abs(abs(fx) / 40.0 - 1) <= 0.01
        assert abs(abs(fy) / 40.0 - 1) <= 0.01
        assert np.degrees(np.angle(fy / fx)) == pytest.approx(-90.0, abs=1.0)


def test_lubricated_circular_displacement_orbit_through_seal_coupling():
    """Displacement control of a circular orbit: the seal's friction acts against the velocity
    vector and couples X and Y, so the 2x2 matrix matters here."""
    be = make_backend(seed=2)
    pump = PumpRelay(be)
    pump.set(True)
    rec = RecordingListener(keep_blocks=False)
    spec = SweepSpec(motion="circular_backward", lubricated=True, amplitude_m=[25e-6],
                     freq_hz=[20.0, 35.0, 50.0])
    out = SweepEngine(be, spec, listener=rec, pump=pump).run()
    assert out.status == "completed", out.reason
    for step in rec.wire_steps:
        x, y = _amp(step, ["x1", "x2"]), _amp(step, ["y1", "y2"])
        assert abs(abs(x) / 25e-6 - 1) <= 0.01 and abs(abs(y) / 25e-6 - 1) <= 0.01
        assert np.degrees(np.angle(y / x)) == pytest.approx(90.0, abs=1.0)


def test_step_dict_follows_contract_a_and_blocks_are_contiguous(backend):
    rec = RecordingListener()
    spec = SweepSpec(motion="y", load_n=[30.0], freq_hz=[80.0, 60.0], record_cycles=20)
    out = SweepEngine(backend, spec, listener=rec).run()
    assert out.status == "completed"
    step = rec.wire_steps[0]
    assert set(step) == {"index", "freq_hz", "target_kind", "target_value", "motion",
                         "first_sample", "last_sample", "updates", "converged", "reason",
                         "harmonics", "drive_v"}
    json.dumps(step)
    assert step["target_kind"] == "load" and step["motion"] == "y"
    assert len(step["harmonics"]["fy"]) == 5
    assert set(step["drive_v"]) == {"shaker_x", "shaker_y"}
    # harmonics are the lock-in of the recorded span, in the run's time base
    ai = rec.ai()
    f, k0, k1 = step["freq_hz"], step["first_sample"], step["last_sample"]
    t = np.arange(k0, k1) / 10_000.0
    fy = ai[1, k0:k1]
    z = 2 * np.mean(fy * np.exp(-2j * np.pi * f * t))  # whole cycles: a plain DFT bin agrees
    assert z == pytest.approx(complex(*step["harmonics"]["fy"][0]), abs=0.02)
    # the AO stream the listener saw is what was written, and it ends at zero
    np.testing.assert_array_equal(rec.ao(), backend.ao_written())
    assert np.all(rec.ao()[:, -100:] == 0)
    assert rec.samples == out.samples
    kinds = [e[1] for e in rec.events_of("state")]
    assert kinds[0] == "idle -> checking" and kinds[-1] == "stopping -> completed"
    # the AO lead and the margin it left: in fast mode nothing is generated between the read
    # and the next write, so 3 blocks of 100 samples are always queued: exactly the lead
    margin = [e[1] for e in rec.events_of("info") if e[1].startswith("AO lead")]
    assert margin == ["AO lead 30 ms; underflow margin 30.0 ms at the tightest (AI sample 0)"]


def test_not_converging_aborts_with_the_reason(backend):
    rec = RecordingListener(keep_blocks=False)
    # the dry housing sticks below ~26 N: 2 um cannot be reached in one update from the prior
    spec = SweepSpec(motion="x", amplitude_m=[2e-6], freq_hz=[30.0], max_updates=1)
    out = SweepEngine(backend, spec, listener=rec).run()
    assert out.status == "aborted"
    assert "did not converge in 1 updates" in out.reason
    assert rec.wire_steps and rec.wire_steps[0]["converged"] is False
    assert rec.wire_steps[0]["reason"].startswith("did not converge")
    assert rec.events_of("abort")
    assert np.all(backend.ao_written()[:, -100:] == 0)


def test_pause_resume_and_abort_from_the_stream():
    """Operator actions arrive between blocks; driven here by the listener (deterministic)."""
    be = make_backend(seed=4)

    class Operator(RecordingListener):
        engine: SweepEngine

        def on_block(self, first_sample, ai, ao):
            super().on_block(first_sample, ai, ao)
            if first_sample == 3000:
                self.engine.pause()
            if first_sample == 6000:
                assert self.engine.progress.state == "paused"
                self.engine.resume()
            if first_sample == 12_000:
                self.engine.abort("operator pressed stop")

    rec = Operator(keep_blocks=True)
    spec = SweepSpec(motion="x", load_n=[40.0], freq_hz=[40.0, 50.0, 60.0])
    engine = SweepEngine(be, spec, limits=DRY_LIMITS, listener=rec)
    rec.engine = engine
    out = engine.run()
    assert out.status == "aborted" and out.reason == "operator pressed stop"
    ao = rec.ao()
    # paused: zero drive between the pause ramp and the resume
    assert np.all(ao[:, 4500:6000] == 0)
    assert np.any(ao[:, 8000:9000] != 0)
    assert np.all(ao[:, 12_000 + 1000:] == 0)  # within 100 ms of the abort
    ops = [e[1] for e in rec.events_of("operator")]
    assert ops[0].startswith("paused") and ops[1].startswith("resumed")


def test_abort_from_another_thread_while_running():
    """The daemon's use: run() in one thread, abort() from another, progress readable."""
    import threading

    be = make_backend(seed=6)
    running = threading.Event()
    release = threading.Event()

    class Gate(RecordingListener):
        def on_step(self, step):
            super().on_step(step)
            running.set()
            release.wait(timeout=30)  # hold the acquisition thread until the abort is sent

    rec = Gate(keep_blocks=False)
    spec = SweepSpec(motion="x", load_n=[20.0], freq_hz=[60.0, 70.0, 80.0])
    engine = SweepEngine(be, spec, limits=DRY_LIMITS, listener=rec)
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("out", engine.run()))
    worker.start()
    assert running.wait(timeout=60)
    progress = engine.progress
    assert progress.state == "running" and progress.steps_total == 3
    assert progress.steps_done == 1 and progress.freq_hz == 60.0
    engine.abort("operator abort from the console")
    release.set()
    worker.join(timeout=60)
    out = result["out"]
    assert out.status == "aborted" and out.reason == "operator abort from the console"
    assert len(out.steps) == 1
    assert engine.progress.state == "aborted"
    assert np.all(be.ao_written()[:, -100:] == 0)


@pytest.mark.paced
def test_paced_backend_keeps_up_with_the_clock():
    """Against the wall clock (as on hardware) the loop keeps the AO stream fed: 30 ms ahead
    in the regenerating ring (the daemon's default; without it this test underflowed in 2 of
    7 runs on the loaded test machine, issue 21), lock-in of long records accumulated block
    by block."""
    from daq.channels import default_channel_map
    from simulated_hw.backend import SimulatedBackend

    warm = make_backend()  # compile the rig's kernel before the clock starts
    warm.write_ao(np.zeros((2, 100)))
    warm.start()
    warm.read_ai(100)
    be = SimulatedBackend(RigParams(), seed=9, realtime=True, ao_ring_s=2.0)
    be.configure(default_channel_map())
    rec = RecordingListener(keep_blocks=False)
    spec = SweepSpec(motion="circular_forward", load_n=[30.0], freq_hz=[60.0, 120.0],
                     record_cycles=30)
    out = SweepEngine(be, spec, limits=DRY_LIMITS, listener=rec).run()
    assert out.status == "completed", out.reason
    assert all(s["converged"] for s in rec.wire_steps)
    # against the clock the AO is generated while the loop works: the lead left is below the
    # 30 ms written (negative if the host was late and the ring played on)
    (report,) = [e[1] for e in rec.events_of("info") if e[1].startswith("AO ring 2 s")]
    left_ms = float(report.split("tightest lead ")[1].split(" ms")[0])
    assert left_ms < 30.0, report


def test_lubricated_elliptical_orbit_downwards():
    """A general ellipse (|Y| = 0.6 |X|, Y leading X by 40 deg), swept downwards."""
    be = make_backend(seed=7)
    pump = PumpRelay(be)
    pump.set(True)
    rec = RecordingListener(keep_blocks=False)
    spec = SweepSpec(motion="elliptical", lubricated=True, amplitude_m=[30e-6],
                     ellipse_ratio=0.6, ellipse_phase_deg=40.0, freq_start_hz=55,
                     freq_stop_hz=25, freq_step_hz=15)
    out = SweepEngine(be, spec, listener=rec, pump=pump).run()
    assert out.status == "completed", out.reason
    assert [s["freq_hz"] for s in rec.wire_steps] == [55.0, 40.0, 25.0]
    for step in rec.wire_steps:
        x, y = _amp(step, ["x1", "x2"]), _amp(step, ["y1", "y2"])
        assert abs(abs(x) / 30e-6 - 1) <= 0.01 and abs(abs(y) / 18e-6 - 1) <= 0.01
        assert np.degrees(np.angle(y / x)) == pytest.approx(40.0, abs=1.0)



def test_a_long_record_is_not_kept_in_memory(backend):
    """The recording is demodulated as it arrives: the stream's look-back holds a control window,
    whatever the record length (it held the whole record: 2.5 GB in the daemon for 1,500 cycles
    at 20 Hz and 1 MS/s)."""
    kept: list[int] = []

    class Watch(RecordingListener):
        def on_block(self, first: int, ai: np.ndarray, ao: np.ndarray) -> None:
            super().on_block(first, ai, ao)
            assert engine._stream is not None
            kept.append(engine._stream.kept_samples)

    spec = SweepSpec(motion="x", load_n=[20.0], freq_hz=[80.0], record_cycles=800)
    engine = SweepEngine(backend, spec, limits=DRY_LIMITS, listener=Watch())
    out = engine.run()
    assert out.status == "completed"
    fs = 10_000.0  # samples per second; blocks of 10 ms (100 samples)
    record = 800 * fs / 80.0  # 100,000 samples (10 s) recorded in the step
    assert out.steps[0].last_sample - out.steps[0].first_sample == record
    # what a lock-in needs to look back over: its window and the two cycles before it at 80 Hz
    # (4 cycles, 50 ms) and a few blocks (40 ms); and what a host late by up to a quarter of a
    # second reads at once when it catches up (issue 21's busy PC), one block more: 0.35 s,
    # 3.5 % of the record. Measured: 3,400 samples at most.
    look_back_s = 4 / 80.0 + 0.04 + 0.25 + 0.01
    assert max(kept) <= look_back_s * fs


def test_a_step_where_a_step_converged_starts_from_the_compliance_measured_there():
    """A step at a frequency where a step converged (here the 32 um steps after the 13 um ones)
    starts from the compliance measured there, not from the model's worst case, which is many
    times the lubricated rig's and started it at a tenth of its drive: 1.63x and 1.81x the
    ideal time before, 1.28x and 1.39x measured with it (issue 41; the report's programme from
    1.62x to 1.37x). Still a new frequency each: the drive at zero before, every step
    converged."""
    be = make_backend(seed=11)
    pump = PumpRelay(be)
    pump.set(True)
    rec = RecordingListener(keep_blocks=False)
    spec = SweepSpec(motion="x", lubricated=True, amplitude_m=[13e-6, 32e-6],
                     freq_hz=[30.0, 50.0])
    out = SweepEngine(be, spec, listener=rec, pump=pump).run()
    assert out.status == "completed", out.reason
    assert all(r.converged for r in out.steps)
    for r in out.steps[2:]:
        ratio = (r.last_sample - r.start_sample) / out.sample_rate_hz / spec.ideal_step_s(
            r.plan.freq_hz)
        assert ratio <= 1.45, (r.plan.freq_hz, ratio)
