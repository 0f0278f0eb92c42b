"""Anticipating control on the simulated rig: limits are kept by the controller, not by trips.

The dry rig (seal friction 26 N, C_rv = 370 N.s/m, resonance near 45 Hz) answers a small drive
raise near break-away with a large jump; the lubricated rig is well damped. Every sweep here must
end without a limit trip and with its orbit inside the displacement limit; a step either
converges or says why not (a target the shakers cannot reach, the soft limit).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from control.run.listener import RecordingListener
from control.run.pump import PumpRelay
from control.run.safety import AxisSignals, SafetyLimits
from control.run.sweep.approach import RAISE_STOP
from control.run.sweep.engine import SweepEngine, SweepSpec
from control.signal.synthesis import SineSynthesizer
from daq.channels import default_channel_map
from rig_model.params import RigParams
from tests.control.conftest import make_backend

LIMIT_M = SafetyLimits().displacement_limit_m  # 63.5 um
EXAMPLE_LUBRICATED = Path(__file__).parents[3] / "examples" / "lubricated_x.toml"
FRAME = {"effects": {"second_mode": {"enabled": True, "frequency_hz": 39.0}}}


class PeakOrbit(RecordingListener):
    """Keeps the largest measured orbit radius of the run (mean of the probes per axis)."""

    def __init__(self) -> None:
        super().__init__(keep_blocks=False)
        self.signals = AxisSignals.from_channel_map(default_channel_map())
        self.peak_m = 0.0

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        super().on_block(first_sample, ai, ao)
        d = self.signals.displacement(ai)
        self.peak_m = max(self.peak_m, float(np.max(np.hypot(d[0], d[1]))))


def _sweep(spec: SweepSpec, frame: bool = False, seed: int = 0) -> tuple:
    be = make_backend(RigParams.model_validate(FRAME) if frame else RigParams(), seed=seed)
    pump = None
    if spec.lubricated:
        pump = PumpRelay(be)
        pump.set(True)
    rec = PeakOrbit()
    out = SweepEngine(be, spec, listener=rec, pump=pump).run()
    return out, rec


@pytest.mark.parametrize(("motion", "amps", "freqs", "updates"), [
    ("x", [20e-6], [20.0], 10),  # tripped at step 1: the stuck branch tripled the drive
    ("circular_forward", [10e-6, 20e-6], [20.0], 10),
    ("circular_forward", [30e-6], [70.0], 10),
    # friction-held: 1 % of 10 um is 0.1 um; 11 updates since the run no longer starts with a
    # glide from 0 Hz (issue 21), 9 before
    ("y", [10e-6], [20.0], 12),
    ("x", [30e-6], [20.0, 70.0], 10),  # tripped on the way from 20 to 70 Hz
])
def test_the_issues_dry_cases_converge_without_a_trip(motion, amps, freqs, updates):
    spec = SweepSpec(motion=motion, amplitude_m=amps, freq_hz=freqs, max_updates=updates)
    out, rec = _sweep(spec)
    assert not rec.events_of("limit_trip"), rec.events_of("limit_trip")
    assert out.status == "completed", out.reason
    assert all(s.converged for s in out.steps)
    assert rec.peak_m < LIMIT_M


def _matrix_case(spec: SweepSpec, frame: bool) -> tuple[int, int, list[str]]:
    out, rec = _sweep(spec, frame)
    where = f"{spec.motion}, frame mode {frame}"
    assert not rec.events_of("limit_trip"), (where, rec.events_of("limit_trip"))
    assert out.status == "completed", (where, out.reason)
    assert rec.peak_m < LIMIT_M, (where, rec.peak_m)
    for s in out.steps:
        # not converged: the reason is given, and it is a reason, not a trip
        assert s.converged or s.reason.startswith(("did not converge", "stopped below")), s.reason
    reasons = [s.reason for s in out.steps if not s.converged]
    return sum(s.converged for s in out.steps), len(out.steps), reasons


MOTIONS = ["x", "y", "circular_forward", "circular_backward", "elliptical"]


def test_dry_displacement_through_the_resonance_subset():
    """CI's share of the matrix below: X and a backward orbit, up and down through 45 Hz."""
    spec = SweepSpec(motion="circular_backward", amplitude_m=[25e-6], freq_hz=[30.0, 45.0, 60.0],
                     on_not_converged="continue")
    ok, n, _ = _matrix_case(spec, frame=False)
    assert ok == n
    spec = SweepSpec(motion="x", amplitude_m=[40e-6, 10e-6], freq_hz=[60.0, 35.0, 20.0],
                     on_not_converged="continue")
    ok, n, _ = _matrix_case(spec, frame=True)
    assert ok >= n - 1


@pytest.mark.slow
@pytest.mark.parametrize("frame", [False, True])
@pytest.mark.parametrize("motion", MOTIONS)
def test_dry_displacement_matrix(motion: str, frame: bool):
    """10-40 um, 20-200 Hz through the resonance (45 Hz; with the frame mode near 39 Hz).

    Measured on this rig model: 18 steps per sweep, 15-17 converge; the rest are 40 um at
    200 Hz (needs ~580 N, held by the load limit) and a few 10-25 um steps near the dry
    resonance, where 1 % of 10 um is 0.01 N of drive on a friction-held housing."""
    spec = SweepSpec(motion=motion, amplitude_m=[10e-6, 25e-6, 40e-6],
                     freq_hz=[20.0, 35.0, 45.0, 60.0, 100.0, 200.0], ellipse_ratio=0.6,
                     ellipse_phase_deg=-60.0, on_not_converged="continue")
    ok, n, _ = _matrix_case(spec, frame)
    assert n == 18 and ok >= 14


@pytest.mark.slow
@pytest.mark.parametrize("motion", MOTIONS)
def test_lubricated_displacement_matrix(motion: str):
    """13-38 um, 20-200 Hz: all converge but 25 and 38 um at 200 Hz, which need more than the
    load limit (M + D ~ 18 kg: 25 um at 200 Hz is ~700 N) and stop with that reason (measured:
    16 of 18 for X and Y, 15-16 for the orbits)."""
    spec = SweepSpec(motion=motion, lubricated=True, amplitude_m=[13e-6, 25e-6, 38e-6],
                     freq_hz=[20.0, 30.0, 45.0, 60.0, 100.0, 200.0], ellipse_ratio=0.6,
                     ellipse_phase_deg=-60.0, on_not_converged="continue")
    ok, n, reasons = _matrix_case(spec, frame=False)
    assert n == 18 and ok >= 15
    assert all("load limit" in r for r in reasons), reasons


@pytest.mark.parametrize("amp_m", [13e-6, 25e-6, 38e-6])
def test_the_readme_lubricated_sweep_moves_no_further_than_its_target(amp_m):
    """The README's lubricated X sweep (examples/lubricated_x.toml, one level at a time): no
    approach drives the orbit past `RAISE_STOP` (1.2) of its target, where a watched raise is to
    stop, with 0.05 for the probes' noise and the orbit's harmonics. The seal slipping more as the
    drive rises makes the orbit grow 2-4x faster than the drive; while the first correction at a
    new frequency took the secant through the origin (twice the drive the target needed), 30 Hz
    ran to 1.55x (13 um), 1.42x (25 um), 1.37x (38 um); raised by the elasticity measured at the
    last frequency, 0.96x, 1.01x, 1.08x."""
    spec = SweepSpec.model_validate(
        {**tomllib.loads(EXAMPLE_LUBRICATED.read_text()), "amplitude_m": [amp_m]})
    out, rec = _sweep(spec)
    assert out.status == "completed" and all(s.converged for s in out.steps), out.reason
    assert rec.peak_m <= (RAISE_STOP + 0.05) * amp_m, (rec.peak_m, amp_m)


def test_a_load_whose_orbit_would_pass_the_margin_stops_with_that_reason():
    """The lead's case: 40 N on X below the dry resonance moves the housing 56-64 um (the trip is
    at 63.5 um); 25 Hz used to 'converge' at a 63.5 um 1X orbit. Each step now stops below the
    soft limit with the displacement limit as its reason, its drive held where the orbit is
    under the 80 % margin (measured: peak 51.9 um; held 1X 47, 42, 39 um; since issue 21's
    approach at each step's own frequency peak 51.5 um, held 1X 47, 46, 40 um)."""
    spec = SweepSpec(motion="x", load_n=[40.0], freq_hz=[20.0, 25.0, 30.0],
                     on_not_converged="continue")
    out, rec = _sweep(spec)
    assert not rec.events_of("limit_trip"), rec.events_of("limit_trip")
    assert out.status == "completed", out.reason
    assert rec.peak_m < 0.9 * LIMIT_M  # never at the soft limit, let alone the trip
    assert len(out.steps) == 3
    for s in out.steps:
        assert not s.converged
        assert "held by the displacement limit" in s.reason, s.reason
        held = abs(0.5 * (s.harmonics[2, 0] + s.harmonics[3, 0]))  # X probes' 1X
        assert held < 0.8 * LIMIT_M, (s.plan.freq_hz, held)


def test_short_blocks_watch_the_first_raise_from_the_start_of_the_run():
    """With 5 ms blocks the first watched raise begins before a whole cycle has been read (it
    failed with 'window start -200 no longer kept')."""
    spec = SweepSpec(motion="x", amplitude_m=[20e-6], freq_hz=[20.0],
                     control={"block_s": 0.005, "ahead_blocks": 1})
    out, rec = _sweep(spec)
    assert out.status == "completed", out.reason
    assert out.steps[0].converged
    assert rec.peak_m < LIMIT_M


def test_a_load_orbit_moves_to_a_new_frequency_below_the_margin():
    """bench_control's dry circular 40 N sweep with the frame mode tripped on its way from 20 to
    30 Hz (the frequency moved at 80 % of the 40 N drive: 32 N gave 63.6 um at 30 Hz). It now
    moves at the load that gives half the margin at the compliance measured at 20 Hz and is
    raised from there (measured: 30 Hz held at 22.6 N, 55.3 um, no trip). Since issue 21 the
    frequency moves at zero drive and 30 Hz starts from the plant estimate there (6 N); its
    break-away orbit kept growing at a held drive (52 -> 57.4 um, the soft limit) until a raise
    that passes the margin backed off at once (measured: peak 53.6 um, 30 Hz held at ~20 N)."""
    spec = SweepSpec(motion="circular_forward", load_n=[40.0], freq_hz=[20.0, 30.0],
                     on_not_converged="continue")
    out, rec = _sweep(spec, frame=True)
    assert not rec.events_of("limit_trip"), rec.events_of("limit_trip")
    assert out.status == "completed", out.reason
    assert len(out.steps) == 2
    assert rec.peak_m < 0.9 * LIMIT_M
    for s in out.steps:
        assert s.converged or "held by the displacement limit" in s.reason, s.reason


class GainRamp(PeakOrbit):
    """Turns the simulated amplifier gain from 1 to ``gain`` times over ``ramp_s`` from 1 s on
    (an outside change the controller did not make)."""

    def __init__(self, backend, gain: float, ramp_s: float) -> None:
        super().__init__()
        self.backend, self.gain, self.ramp = backend, gain, ramp_s * 10_000
        self.g0 = backend.rig.params.shaker.force_per_volt_n

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        super().on_block(first_sample, ai, ao)
        end = first_sample + ai.shape[1]
        if end >= 10_000:
            rig = self.backend.rig
            frac = min(1.0, (end - 10_000) / self.ramp)
            shaker = rig.params.shaker.model_copy(
                update={"force_per_volt_n": self.g0 * (1 + (self.gain - 1) * frac)})
            rig.params = rig.params.model_copy(update={"shaker": shaker})


def test_an_orbit_growing_at_a_held_drive_is_cut_before_the_lead_plays_out():
    """The amplifier gain rises x3 over 0.5 s during a 40 um X dwell at 60 Hz (dry): the orbit
    grows while the controller holds the drive. The soft limit halves the drive when its growth
    per cycle would pass the limit before the 30 ms of drive already written have played; the
    trip still comes, but the peak stays within 10 % of the limit (measured: 1.02x; 1.15x without
    the growth check; benchmarks/bench_trip.py for more cases)."""
    be = make_backend(RigParams(), seed=0)
    spec = SweepSpec(motion="x", amplitude_m=[40e-6], freq_hz=[60.0])
    rec = GainRamp(be, 3.0, 0.5)
    SweepEngine(be, spec, listener=rec).run()
    assert rec.peak_m <= 1.1 * LIMIT_M  # the trip still comes, but 10 % past the limit at most


# --- issue 21: every step approached at its own frequency ---------------------------------------
class FrequencyWatch(SineSynthesizer):
    """The engine's synthesiser, noting every block in which the frequency moved while a drive
    was on (`changes_under_drive`): the glide through the resonance that issue 21 tripped on."""

    changes_under_drive: list[tuple[float, float, float]] = []

    def next_block(self, n: int) -> np.ndarray:
        f0, p0 = self.freq_hz, float(np.max(np.abs(self.phasors)))
        out = super().next_block(n)
        if abs(self.freq_hz - f0) > 1e-9 and max(p0, float(np.max(np.abs(self.phasors)))) > 0:
            FrequencyWatch.changes_under_drive.append((f0, self.freq_hz, p0))
        return out


@pytest.fixture
def watched_frequency(monkeypatch):
    FrequencyWatch.changes_under_drive = []
    monkeypatch.setattr("control.run.sweep.engine.SineSynthesizer", FrequencyWatch)
    return FrequencyWatch


def test_the_frequency_watch_sees_a_glide_under_drive(watched_frequency):
    synth = FrequencyWatch(2, 10_000.0)
    synth.ramp_to(np.array([1.0, 0.0], dtype=complex), 150.0, 0.05)  # the old start from 0 Hz
    synth.next_block(100)
    assert len(watched_frequency.changes_under_drive) == 1


def _never_through_the_resonance(spec: SweepSpec, watch) -> tuple:
    out, rec = _sweep(spec)
    where = f"{spec.motion} {spec.load_n or spec.amplitude_m} lubricated {spec.lubricated}"
    assert not rec.events_of("limit_trip"), (where, rec.events_of("limit_trip"))
    assert not rec.events_of("fault"), (where, rec.events_of("fault"))
    assert out.status == "completed", (where, out.reason)
    assert watch.changes_under_drive == [], where  # the frequency moved only at zero drive
    assert rec.peak_m < 0.9 * LIMIT_M, (where, rec.peak_m)  # never at the soft limit
    assert out.summary["peak_displacement_m"] == pytest.approx(rec.peak_m)
    assert out.summary["contact"] == "" and out.summary["tripped_at"] is None
    assert len(out.steps) == len(spec.steps())
    for s in out.steps:
        # reached, or ended with a clear reason: held by a limit (never a trip)
        assert s.converged or "held by the" in s.reason, (where, s.plan.freq_hz, s.reason)
    return out, rec


#: X, dry and lubricated, below and above the resonance (~45 Hz dry, ~33 Hz with the film's
#: added mass), crossing it both ways between steps
ISSUE_21_FREQS = [20.0, 80.0, 30.0, 150.0]


@pytest.mark.parametrize(("lubricated", "load_n"), [
    (False, 400.0),
    (True, 250.0),
    pytest.param(False, 100.0, marks=pytest.mark.slow),
    pytest.param(False, 250.0, marks=pytest.mark.slow),
    pytest.param(True, 100.0, marks=pytest.mark.slow),
    pytest.param(True, 400.0, marks=pytest.mark.slow),
])
def test_load_targets_up_to_the_rating_never_glide_through_the_resonance(
        watched_frequency, lubricated: bool, load_n: float):
    """Issue 21: 400 N on X at 150 Hz started at 0 Hz and glided up through the resonance at a
    growing drive: it tripped every time at 87-126 um (once at the journal). Before this change
    this matrix (X, 100-440 N, 20/80/30/150 Hz, seed 0) tripped in 7 of 8 sweeps (peaks
    88.7-126.1 um). Measured now: no trip, peaks 51.1-52.1 um; 150 Hz converges up to 400 N dry
    (1X 11.5 um at 100 N, 50.5 um at 400 N; 440 N, over the 403 N the controller aims at, is
    refused at the start now: `test_safety`); 20 and 30 Hz (50-150 um needed) and 80 Hz above
    100-250 N are held by the displacement limit at 39-51 um."""
    spec = SweepSpec(motion="x", lubricated=lubricated, load_n=[load_n], freq_hz=ISSUE_21_FREQS,
                     on_not_converged="continue")
    out, _ = _never_through_the_resonance(spec, watched_frequency)
    at = {s.plan.freq_hz: s for s in out.steps}
    if load_n <= 400.0:  # 150 Hz: 0.13 um/N dry, far less lubricated: reachable
        assert at[150.0].converged, at[150.0].reason
        assert abs(at[150.0].controlled[0]) == pytest.approx(load_n, rel=0.01)
    for f in (20.0, 30.0):  # 100 N below the resonance is already 100-150 um: held
        assert "held by the displacement limit" in at[f].reason, at[f].reason


def test_the_reported_case_400_n_at_150_hz(watched_frequency):
    """The report: `motion=x load_n=[400] freq_hz=[150]` tripped at 64.5 um after 0.06 s, peak
    86.9 um (98.7-125.8 um on the paced daemon). Now: converged, 1X 50.5 um, peak 52.0 um."""
    spec = SweepSpec(motion="x", load_n=[400.0], freq_hz=[150.0])
    out, rec = _never_through_the_resonance(spec, watched_frequency)
    assert out.steps[0].converged
    assert rec.peak_m < 0.85 * LIMIT_M


def test_several_loads_at_one_frequency_then_across_the_resonance(watched_frequency):
    """Frequency-major: 100, 250, 400 N at 150 Hz (the drive raised from the last step's, the
    frequency unchanged), then at 80 Hz (measured dry: 150 Hz all converge, 80 Hz held by the
    displacement limit at 50.8-50.9 um: 100 N there is ~60 um; peak 52.0 um)."""
    spec = SweepSpec(motion="x", load_n=[100.0, 250.0, 400.0], freq_hz=[150.0, 80.0],
                     order="frequency_major", on_not_converged="continue")
    out, _ = _never_through_the_resonance(spec, watched_frequency)
    assert [s.converged for s in out.steps if s.plan.freq_hz == 150.0] == [True, True, True]


def test_a_displacement_target_across_the_resonance_both_ways(watched_frequency):
    """30 um on X through the dry resonance, up and down (45 and 60 Hz need little force: the
    plant estimate starts them a few newtons from rest); all converge (measured: 4 of 4)."""
    spec = SweepSpec(motion="x", amplitude_m=[30e-6], freq_hz=[30.0, 60.0, 45.0, 20.0],
                     on_not_converged="continue")
    out, _ = _never_through_the_resonance(spec, watched_frequency)
    assert sum(s.converged for s in out.steps) >= 3


def test_the_readme_40_n_x_example_is_held_at_20_hz_by_the_displacement_limit(watched_frequency):
    """The load example on X (`load_n=[40] freq_hz=[20, 80]`): 40 N at 20 Hz moves the
    dry housing 55.8 um (static compliance 1.27 um/N, x1.3 at 20 Hz, less the seal's friction),
    past the 80 % margin (50.8 um) of the 63.5 um limit: the step is held below it and says so;
    with `on_not_converged = "abort"` (the default) the run then stops there. 80 Hz converges."""
    spec = SweepSpec(motion="x", load_n=[40.0], freq_hz=[20.0, 80.0],
                     on_not_converged="continue")
    out, _ = _never_through_the_resonance(spec, watched_frequency)
    assert "held by the displacement limit" in out.steps[0].reason
    assert "the orbit reached" in out.steps[0].reason
    assert out.steps[1].converged
