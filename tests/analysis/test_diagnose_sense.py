"""The default diagnose of this rig's own run reads as sense: the lubricated X programme of
``examples/lubricated_x.toml`` (shortened: three levels, 20 record cycles), recorded by the real
sweep engine on the nominal simulated rig as the daemon records it.

The film makes the housing overdamped over 20-60 Hz (damping ratio 1.5-4 per level): no mode is
in the band, a one-mode fit's natural frequency is an extrapolation at the lowest level, and
the y probes only record their noise (the drive is X only)."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from analysis.diagnose import load_run
from analysis.diagnose.amplitude import T_MIN, amplitude_dependence
from analysis.diagnose.data import RunRecord
from analysis.diagnose.effects import Context
from analysis.diagnose.modes import modal_dependence
from analysis.diagnose.residual_analysis import harmonics
from analysis.diagnose.residual_structure import Z_STRUCTURE
from rig_model import RigParams
from tests.analysis.recorded import record_sweep

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lubricated_x.toml"
DRY = EXAMPLE.with_name("dry_circular.toml")


@pytest.fixture(scope="module")
def lubricated_x(tmp_path_factory) -> RunRecord:
    spec = tomllib.loads(EXAMPLE.read_text())
    spec.update(amplitude_m=spec["amplitude_m"][::2], record_cycles=20, settle_cycles=5)
    path = tmp_path_factory.mktemp("sense") / "lubricated_x.h5"
    assert record_sweep(RigParams(), spec, path, seed=0) == "completed"
    rec = load_run(path)
    assert len(rec.segments) == 15
    return rec


def _zeta_equivalent(rig: RigParams, amp_m: float, f_hz: float) -> float:
    """The housing's equivalent damping ratio on the lubricated rig at one dwell, from the
    report's model (eq. 9-11, 15-16): C_t = C_film (eq. 16, at the orbit's eccentricity) + C_rv
    + 4 F_mu / (pi w |z|), over 2 sqrt(K_sx M_t), M_t = M + M_f + D."""
    film, st = rig.film, rig.structure
    eps = amp_m / film.clearance_m
    c_film = (film.eq16_damping_centred(film.viscosity_pa_s(rig.oil.initial_temperature_c))
              * (1 + 2 * eps**2) / (1 - eps**2) ** 2)
    c_seal = 4 * rig.seal.friction_force_n / (math.pi * 2 * math.pi * f_hz * amp_m)
    m_t = st.mass_kg + film.fluid_mass_kg + film.added_mass()
    return (c_film + st.residual_damping_ns_per_m + c_seal) / (
        2 * math.sqrt(st.stiffness_x_n_per_m * m_t))


def test_the_overdamped_film_is_said_overdamped_not_a_mode(lubricated_x):
    """The lubricated housing is overdamped over the whole programme (the report's VI.3: "highly
    over damped"; its model's equivalent damping ratio is 1.0 at 38 um and 60 Hz to 3.4 at 13 um
    and 20 Hz, the centred film at 0 um giving the least): every level's pole says so with
    its damping ratio within that range (3 sd), and the text lists no mode (it was "x: 1 mode
    (56.37 Hz (damping >= 70 %))", the pole pinned on the fit's bound at 0.7)."""
    rig = RigParams()
    lo = _zeta_equivalent(rig, 38e-6, 60.0) * (1 - 0.02)  # the eccentricity law at its least
    hi = _zeta_equivalent(rig, 13e-6, 20.0)
    assert 1.0 < lo < hi
    modes = modal_dependence([lubricated_x], lubricated_x.segments)
    assert len(modes.levels) == 3, modes.text
    for lv in modes.levels:
        assert lv.band_hz == pytest.approx((20.0, 60.0))
        assert [lv.shown(m) for m in lv.modes] == [False] * len(lv.modes)
        pole = max(lv.modes, key=lambda m: m.damping_ratio)
        assert "overdamped: no resonance" in lv.why_not(pole)
        sd = pole.damping_ratio_sd
        assert 0 < sd < 0.5 * pole.damping_ratio, (lv.label, pole)
        assert lo - 3 * sd <= pole.damping_ratio <= hi + 3 * sd, (lv.label, pole)
    assert modes.per_axis() == {"x": 0}
    assert modes.text.startswith("x: no mode; overdamped, no resonance in the band at 3 of 3 "
                                 "levels (a pole's damping ratio "), modes.text
    assert "Hz (damping" not in modes.text


@pytest.fixture(scope="module")
def dry_circular(tmp_path_factory) -> RunRecord:
    """The dry circular programme of ``examples/dry_circular.toml`` (40 N, 20 Hz and 70-200 Hz:
    30-60 Hz left out near the 45 Hz resonance), shortened to 10 record cycles."""
    spec = tomllib.loads(DRY.read_text())
    spec.update(load_n=spec["load_n"][:1], record_cycles=10, settle_cycles=5)
    path = tmp_path_factory.mktemp("sense") / "dry_circular.h5"
    assert record_sweep(RigParams(), spec, path, seed=0, lubricated=False) == "completed"
    rec = load_run(path)
    assert [s.freq_hz for s in rec.segments] == spec["freq_hz"]
    return rec


def test_no_mode_in_a_gap_of_the_plan(dry_circular):
    """The dry programme has no dwell between 20 and 70 Hz, where the housing's resonance lies
    (sqrt(K_sx / M) = 45.4 Hz): no mode is listed there, nor anywhere (above 70 Hz the
    receptance is the mass line); the poles the fit puts in the gap are reported as no mode,
    between the points, with their sd (it listed "x: 2 modes (22.24 Hz ...; 40.96 Hz ...)").
    The seal's friction makes the points no linear structure's: said with the fit's chi2."""
    rec = dry_circular
    modes = modal_dependence([rec], rec.segments)
    assert {lv.axis for lv in modes.levels} == {"x", "y"}, modes.text
    assert modes.per_axis() == {"x": 0, "y": 0}, modes.text
    gap = 0
    for lv in modes.levels:
        for m in lv.modes:
            near = np.abs(lv.freqs_hz - m.natural_hz).min()
            if 20.0 < m.natural_hz < 70.0 and m.damping_ratio < 0.7:
                gap += 1
                assert near > 2 * m.damping_ratio * m.natural_hz or "not determined by the " \
                    "points" in lv.why_not(m), (lv.label, m)
                assert not lv.shown(m)
        assert not lv.linear, lv.orders
    assert gap >= 1
    assert "no mode: a pole at" in modes.text and "between the points at 20 and 70 Hz" \
        in modes.text, modes.text
    assert "not a linear structure's" in modes.text
    assert not re.search(r"\d Hz \(damping", modes.text), modes.text


def test_per_level_figures_only_where_determined(lubricated_x):
    """Each level's natural frequency is given only within its points' band and at
    ``T_MIN`` sd from zero; the trend says "not resolved" (with its sd) where the levels
    could not show the least change called one, never "level-independent"."""
    dep = amplitude_dependence([lubricated_x], lubricated_x.segments)
    assert len(dep.levels) == 3, dep.text
    for lv in dep.levels:
        inside = 20.0 <= lv.natural_hz <= 60.0
        assert lv.frequency_determined == (inside and lv.natural_hz_sd < lv.natural_hz / T_MIN)
        if not lv.frequency_determined:
            assert lv.text.startswith("natural frequency not determined (")
        if not lv.damping_determined:
            assert "damping ratio not determined (" in lv.text
    # the lowest level's one-mode fit is an extrapolation below the band, with an sd as large
    # as its value: not shown as a figure
    low = min(dep.levels, key=lambda lv: lv.level)
    assert low.natural_hz < 20.0 or low.natural_hz_sd > low.natural_hz / T_MIN
    assert not low.frequency_determined
    f = dep.frequency["x"]
    assert f.verdict == "none" and f.sd > f.min_change / T_MIN and not f.resolved
    assert "level-independent" not in dep.text
    assert dep.text.startswith("x: natural frequency not resolved by the levels (")


def test_no_gain_or_delay_candidate_on_an_undriven_channel(lubricated_x):
    """On the X-only run the y probes and the y accelerometer record their noise: their 1X
    stands under ``Z_STRUCTURE`` sd of it in every dwell, so they carry nothing of a gain or a
    delay and are no candidates (the best candidate was "sensor_gain (channel=y2,
    gain_ratio=0.2)", the fit's bound); the x channels stand hundreds of sd above."""
    rec = lubricated_x
    fs = rec.sample_rate_hz

    def z_sd(ch: str) -> float:  # the largest 1X over the dwells, in sd of its noise
        sig = rec.signal(ch)
        out = 0.0
        for s in rec.segments:
            z, _, rest = harmonics(sig[s.start:s.stop], s.start, fs, s.freq_hz, 1)
            out = max(out, abs(z[0]) / (rest * math.sqrt(2.0 / (s.stop - s.start))))
        return out

    for ch in ("y1", "y2", "ay"):
        assert z_sd(ch) < Z_STRUCTURE
    for ch in ("x1", "x2", "ax"):
        assert z_sd(ch) > 50 * Z_STRUCTURE
    ctx = Context(records=[rec], base=None, fitted_baseline=False,  # type: ignore[arg-type]
                  duration_s=0.0, x_rms_m=0.0, f_rms_n=0.0, f_typ_hz=40.0)
    assert ctx.redundant_channels() == ["x1", "x2", "ax"]


def test_a_candidate_on_a_bound_of_its_fit_is_no_best_candidate():
    """On the dry circular run the nearest candidate was a micro-slip joint with its slip force
    and stiffness on their fit's bounds, gain 1.000: its size says where the fit stopped. It is
    passed over for the next nearest; with none left there is no best candidate."""
    from types import SimpleNamespace

    from analysis.diagnose.engine import Diagnosis

    bound = {"effect": "joint_microslip", "held_out_error": 0.9,
             "not_a_finding": "parameter(s) ['slip_force_N'] on a bound of the fit"}
    worse = {"effect": "quadratic_stiffness", "held_out_error": 0.95}
    diag = SimpleNamespace(findings=[], rounds=[[bound, worse]], baseline_rms=1.0)
    best = Diagnosis.best_candidate(diag)  # type: ignore[arg-type]
    assert best is not None and best["effect"] == "quadratic_stiffness"
    assert best["gain"] == pytest.approx(1.0 / 0.95)
    diag.rounds = [[bound]]
    assert Diagnosis.best_candidate(diag) is None  # type: ignore[arg-type]
