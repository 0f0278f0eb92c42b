"""Safety: limit trips ramp to zero within 100 ms, open loop, bad targets refused up front."""

from __future__ import annotations

import numpy as np
import pytest

from control.run.errors import LimitTrip
from control.run.listener import RecordingListener
from control.run.safety import SafetyLimits, SafetyMonitor
from control.run.sweep.engine import SweepEngine, SweepSpec
from control.wire.errors import SpecError, TargetError
from daq.channels import default_channel_map
from daq.errors import DaqTimeoutError
from rig_model.params import RigParams
from tests.control.conftest import TRIP_AT_S, GainJump, GainKnob, WriteLog, make_backend

FS = 10_000


def _assert_safe_ramp(ao: np.ndarray, trip_sample: int) -> None:
    """Both drives at zero within 100 ms of the trip, and no step on the way down."""
    assert np.any(ao[:, trip_sample - 200:trip_sample] != 0)  # it was driving
    assert np.all(ao[:, trip_sample + FS // 10:] == 0)
    fade = ao[:, trip_sample:trip_sample + FS // 10]
    steady = np.abs(np.diff(ao[:, max(0, trip_sample - 2000):trip_sample], axis=1)).max()
    assert np.abs(np.diff(fade, axis=1)).max() <= 1.05 * steady + 1e-12


def test_displacement_trip_cuts_both_drives_to_zero_within_a_block():
    # the controller keeps its own drive inside the limits; a trip needs a cause it cannot
    # foresee: the amplifier's gain doubles at 1.5 s of a dry 30 N X step at 30 Hz
    be = GainJump(RigParams(), seed=8, factor=2.0, at_sample=15_000)
    be.configure(default_channel_map())
    rec = RecordingListener()
    spec = SweepSpec(motion="x", load_n=[30.0], freq_hz=[30.0], record_cycles=200)
    out = SweepEngine(be, spec, listener=rec).run()
    assert out.status == "aborted"
    trips = rec.events_of("limit_trip")
    assert len(trips) == 1 and "exceeds the 63.5 um limit" in trips[0][1]
    k = trips[0][2]
    assert k > 15_000
    # the trip is stamped at the first sample over the limit
    ai = rec.ai()
    cm = default_channel_map()
    x = ai[[cm.ai_index("x1"), cm.ai_index("x2")]].mean(axis=0)
    y = ai[[cm.ai_index("y1"), cm.ai_index("y2")]].mean(axis=0)
    r = np.hypot(x, y)
    assert r[k] > 63.5e-6 and np.all(r[:k] <= 63.5e-6)
    # the AO already queued (30 ms) does not play: the generation stops at the end of the
    # block the trip was seen in, and the drives show 0 V from there (idle output 0 V)
    written, shown = be.ao_written(), rec.ao()
    cut = (k // 100 + 1) * 100
    assert written.shape[1] >= cut + 300  # it had been written
    np.testing.assert_array_equal(shown[:, :cut], written[:, :cut])
    assert np.any(shown[:, cut - 100:cut] != 0)
    assert np.all(shown[:, cut:] == 0) and shown.shape[1] >= cut + 400  # the motion read out
    assert out.reason == trips[0][1]


def test_a_resuming_cut_fades_from_the_first_sample_not_generated():
    """A backend that can take back its queue (the in-process rig with ``cut_stops=False``):
    the fade starts at the end of the trip's block, continuing the sine without a step."""
    be = GainJump(RigParams(), seed=8, factor=2.0, at_sample=15_000, cut_stops=False)
    be.configure(default_channel_map())
    rec = RecordingListener()
    spec = SweepSpec(motion="x", load_n=[30.0], freq_hz=[30.0], record_cycles=200)
    out = SweepEngine(be, spec, listener=rec).run()
    assert out.status == "aborted" and "exceeds the 63.5 um limit" in out.reason
    cut = (rec.events_of("limit_trip")[0][2] // 100 + 1) * 100
    written, shown = be.ao_written(), rec.ao()
    np.testing.assert_array_equal(shown[:, :cut], written[:, :cut])
    _assert_safe_ramp(shown, cut)
    assert np.all(shown[:, cut + 400:] == 0)  # the 40 ms fade, then zeros


def test_unhandled_exception_ramps_down_and_is_recorded():
    be = make_backend(seed=1)

    class Broken(RecordingListener):
        def on_step(self, step):
            super().on_step(step)
            raise RuntimeError("disk full")

    rec = Broken()
    out = SweepEngine(be, SweepSpec(motion="x", load_n=[30.0], freq_hz=[50.0, 60.0]),
                      listener=rec).run()
    assert out.status == "failed" and out.reason == "RuntimeError: disk full"
    err = rec.events_of("error")
    assert err and err[0][1] == "RuntimeError: disk full"
    _assert_safe_ramp(be.ao_written(), err[0][2])


def test_stalled_acquisition_still_writes_the_fade_and_zeros():
    class Stalls(WriteLog):
        def read_ai(self, n, timeout_s=10.0):
            if self.samples_read >= 20_000:  # in the dwell (from 1.8 s; 0.5 s before issue 21)
                raise DaqTimeoutError("read timed out", -200284)
            return super().read_ai(n, timeout_s)

    be = Stalls(RigParams(), seed=0)
    be.configure(default_channel_map())
    rec = RecordingListener()
    out = SweepEngine(be, SweepSpec(motion="x", load_n=[30.0], freq_hz=[50.0]),
                      listener=rec).run()
    assert out.status == "failed" and "read timed out" in out.reason
    written = be.ao_written()
    assert np.all(written[:, -100:] == 0)
    _assert_safe_ramp(written, 20_000)


def test_open_loop_is_detected():
    params = RigParams.model_validate({"shaker": {"force_per_volt_n": 0.5}})  # amplifier dead
    be = make_backend(params)
    rec = RecordingListener(keep_blocks=False)
    out = SweepEngine(be, SweepSpec(motion="x", load_n=[40.0], freq_hz=[30.0]),
                      listener=rec).run()
    assert out.status == "aborted"
    assert out.reason.startswith("open loop: check the stinger and the amplifier")
    trip = rec.events_of("limit_trip")[0]
    assert trip[1].startswith("open loop") and "load cell fx reads" in trip[1]
    _assert_safe_ramp(be.ao_written(), trip[2])


@pytest.mark.parametrize(
    ("spec", "limits", "message"),
    [
        ({"motion": "x", "amplitude_m": [10e-6], "freq_hz": [2600.0]},
         SafetyLimits(max_freq_hz=5000), "above a quarter of the sample rate (2500 Hz"),
        ({"motion": "x", "amplitude_m": [10e-6], "freq_hz": [20.0, 600.0]},
         SafetyLimits(), "600 Hz is outside the permitted range 5-500 Hz"),
        ({"motion": "x", "amplitude_m": [10e-6], "freq_hz": [3.0]},
         SafetyLimits(), "3 Hz is outside the permitted range"),
        ({"motion": "circular_forward", "amplitude_m": [13e-6, 70e-6], "freq_hz": [30.0]},
         SafetyLimits(), "displacement 70 um exceeds the limit 63.5 um"),
        ({"motion": "y", "load_n": [500.0], "freq_hz": [30.0]},
         SafetyLimits(), "load 500 N exceeds the shaker rating 448 N"),
        ({"motion": "y", "load_n": [100.0], "freq_hz": [30.0]},
         SafetyLimits(max_load_n=80.0), "load 100 N exceeds the configured limit 80 N"),
        # issue 39: under the limit, over the share of it the controller aims at: accepted, it
        # spent its 10 updates held at the margin and aborted
        ({"motion": "circular_forward", "amplitude_m": [30e-6, 60e-6], "freq_hz": [20.0, 40.0]},
         SafetyLimits(), "amplitude_m = 6e-05 (60 um) (circular_forward, 2 steps from step 3/4): "
         "asks for an orbit radius of 60 um, over 50.8 um (80 % of the 63.5 um displacement "
         "limit, the most the controller aims at, a margin for harmonics, noise and prediction "
         "error); the largest amplitude_m accepted is 5.08e-05 (50.8 um)"),
        ({"motion": "elliptical", "ellipse_ratio": 1.5, "amplitude_m": [40e-6],
          "freq_hz": [30.0]}, SafetyLimits(), "the largest amplitude_m accepted is 3.387e-05"),
        ({"motion": "x", "amplitude_m": [58e-6], "freq_hz": [30.0],
          "control": {"algorithm": "proportional"}}, SafetyLimits(),
         "over 57.15 um (90 % of the 63.5 um displacement limit, where the soft limit halves"),
        ({"motion": "x", "load_n": [420.0], "freq_hz": [150.0]}, SafetyLimits(),
         "load_n = 420 (x, 1 step from step 1/1): asks for a load of 420 N, over 403.2 N (90 % "
         "of the 448 N load limit"),
        ({"motion": "y", "load_n": [60.0], "freq_hz": [30.0]}, SafetyLimits(max_load_n=60.0),
         "the largest load_n accepted is 54"),
    ],
)
def test_bad_targets_are_refused_before_any_output(spec, limits, message):
    be = make_backend()
    rec = RecordingListener()
    engine = SweepEngine(be, spec, limits=limits, listener=rec)
    with pytest.raises(TargetError, match="sweep refused") as info:
        engine.run()
    assert message in str(info.value)
    assert be.written == [] and be.samples_read == 0
    assert engine.state.value == "refused"
    assert rec.events_of("abort")[0][1].startswith("refused")


@pytest.mark.parametrize("amp", [0.0, -13e-6])
def test_non_positive_amplitude_is_refused(amp):
    be = make_backend()
    with pytest.raises(SpecError, match=r"amplitude_m\.0 = .*greater than 0"):
        SweepEngine(be, {"motion": "x", "amplitude_m": [amp], "freq_hz": [30.0]})
    with pytest.raises(SpecError, match=r"load_n\.1"):
        SweepEngine(be, {"motion": "x", "load_n": [10.0, amp], "freq_hz": [30.0]})
    assert be.written == []


def test_limits_must_be_consistent():
    with pytest.raises(ValueError, match="exceeds the shaker rating"):
        SafetyLimits(max_load_n=500.0)
    with pytest.raises(ValueError, match="min_freq_hz"):
        SafetyLimits(min_freq_hz=100.0, max_freq_hz=50.0)
    assert SafetyLimits().displacement_limit_m == pytest.approx(63.5e-6)


def test_monitor_stamps_the_first_offending_sample():
    cm = default_channel_map()
    mon = SafetyMonitor(SafetyLimits(max_load_n=100.0), cm)
    eng = np.zeros((len(cm.ai), 50))
    eng[cm.ai_index("fy"), 30] = -120.0
    eng[cm.ai_index("fx"), 40] = 150.0
    with pytest.raises(LimitTrip, match="load fy = -120.0 N exceeds the 100 N limit") as info:
        mon.check_ai(eng, 1000)
    assert info.value.sample == 1030 and info.value.limit == "load_n"
    with pytest.raises(LimitTrip, match="above the 9 V limit"):
        mon.check_ao(np.full((2, 10), 9.5), 0)
    mon2 = SafetyMonitor(SafetyLimits(), cm)
    with pytest.raises(LimitTrip, match="slew"):
        mon2.check_ao(np.array([[0.0, 8.0], [0.0, 0.0]]), 0)


def test_unreachable_target_stops_at_the_load_limit_without_tripping():
    """The controller will not push the load past 90 % of its limit to chase a target."""
    be = make_backend(seed=3)
    rec = RecordingListener()
    limits = SafetyLimits(max_load_n=60.0)
    # dry X at 100 Hz, above the 45 Hz resonance: 40 um needs ~120 N, over the 60 N limit
    spec = SweepSpec(motion="x", amplitude_m=[40e-6], freq_hz=[100.0], max_updates=6)
    out = SweepEngine(be, spec, limits=limits, listener=rec).run()
    assert out.status == "aborted"
    assert "held by the load limit (60 N)" in out.reason
    assert not rec.events_of("limit_trip")
    fx = rec.ai()[default_channel_map().ai_index("fx")]
    assert np.abs(fx).max() < 60.0


def test_contact_after_a_trip_is_recorded_as_a_fault():
    """A sudden tripling of the amplifier's gain at 60 Hz: the trip comes at 63.5 um and the
    drives are at 0 V from the end of that block, but the housing's momentum carries it on to
    the journal. The contact is a fault event of the run, with its sample."""
    # in the recording (from 1.8 s); the jump's phase is one whose momentum carries the housing
    # to the journal after the cut (at most phases the housing now stops short of it, or
    # reaches it within the block in which the limit is passed: then contact is the trip)
    be = GainJump(RigParams(), seed=8, factor=3.0, at_sample=30_028)
    be.configure(default_channel_map())
    rec = RecordingListener()
    spec = SweepSpec(motion="x", load_n=[40.0], freq_hz=[60.0], record_cycles=200)
    out = SweepEngine(be, spec, listener=rec).run()
    assert out.status == "aborted" and "exceeds the 63.5 um limit" in out.reason
    faults = rec.events_of("fault")
    assert len(faults) == 1 and faults[0][1].startswith("journal-housing contact")
    trip_k, contact_k = rec.events_of("limit_trip")[0][2], faults[0][2]
    cut = (trip_k // 100 + 1) * 100
    assert trip_k < cut <= contact_k < trip_k + FS // 10
    assert np.all(rec.ao()[:, cut:] == 0)
    cm = default_channel_map()
    ai = rec.ai()
    x = ai[[cm.ai_index("x1"), cm.ai_index("x2")]].mean(axis=0)
    y = ai[[cm.ai_index("y1"), cm.ai_index("y2")]].mean(axis=0)
    r = np.hypot(x, y)
    assert r[contact_k] >= 0.97 * 127e-6 > r[contact_k - 1]


LIMIT_M = 63.5e-6
#: dry X 30 um at 40 Hz (near the resonance), amplifier gain x3 from `TRIP_AT_S` (conftest)
TRIP_SPEC = SweepSpec(motion="x", amplitude_m=[30e-6], freq_hz=[40.0])


def test_a_trip_after_a_gain_rise_over_0_1_s_stops_within_10_percent_of_the_limit():
    """The AO queued ahead (30 ms) does not play after a trip: the drives are at 0 V from the
    end of the block the trip was seen in. Measured 1.03x the limit (1.68x when the queue and
    a 40 ms fade played out first, 1.46x with a 10 ms fade instead of the stop)."""
    be = make_backend(seed=0)
    knob = GainKnob(lambda: be.rig, factor=3.0, ramp_s=0.1, at_s=TRIP_AT_S)
    out = SweepEngine(be, TRIP_SPEC, listener=knob).run()
    assert out.status == "aborted" and "exceeds the 63.5 um limit" in out.reason
    k = knob.events_of("limit_trip")[0][2]
    assert np.all(knob.ao()[:, (k // 100 + 1) * 100:] == 0)
    assert knob.peak_m <= 1.10 * LIMIT_M, f"peak {knob.peak_m / LIMIT_M:.3f}x the limit"


@pytest.mark.xfail(strict=True, reason=(
    "out of reach by a software cut: gain x3 at once moves the housing from under 63.5 um to "
    "the journal (2.0x) within the 10 ms AI block in which the limit is passed, before the "
    "block is read; 0 V from the very first sample over the limit would still give 1.68x "
    "(benchmarks/bench_trip.py)"))
def test_a_trip_after_a_sudden_gain_rise_stops_within_10_percent_of_the_limit():
    be = make_backend(seed=0)
    knob = GainKnob(lambda: be.rig, factor=3.0, ramp_s=0.0, at_s=TRIP_AT_S)
    out = SweepEngine(be, TRIP_SPEC, listener=knob).run()
    assert out.status == "aborted" and knob.events_of("limit_trip")
    assert knob.peak_m <= 1.10 * LIMIT_M, f"peak {knob.peak_m / LIMIT_M:.3f}x the limit"


def test_a_displacement_limit_at_the_journal_is_refused():
    with pytest.raises(ValueError, match="reaches the journal"):
        SafetyLimits(max_displacement_m=125e-6)
