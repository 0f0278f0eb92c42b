"""Hidden-effect tests: diagnose must name the effect hidden in simulated runs and recover it.

The generator (`hidden_effects.py`) hides one effect (or two, or none) in the true rig, records
sine dwells through the simulator with sensor noise, writes run files, and diagnose gets only the
files. Each effect's main parameter must come back within the tolerance written here
(`TOLERANCE`, sized from the accuracy measured on `SEEDS`, not the library's documented one), and
the finding must take the held-out error down by `MIN_GAIN` and to the noise floor (not the
engine's own acceptance rule). CI runs one fixed seed per effect (`CI_SEEDS`: the development
seeds dealt out over the effects); the other seeds of each effect are `slow`. Seeds nobody looks
at while changing diagnose are in `test_diagnose_held_out.py` (marker `held_out`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose import LIBRARY, diagnose, load_run
from tests.analysis.hidden_effects import make_case, step_harmonics

CI_SEED = 11  # clean, pairs, out-of-library, several runs
#: the development seeds (the tolerances below were measured on them)
SEEDS = (11, 21, 32, 43, 54)

#: Each effect's main parameter: (name, relative tolerance), the tolerance a few times the largest
#: error measured over SEEDS (2026-11-25; in brackets, against the library's documented one).
TOLERANCE: dict[str, tuple[str, float]] = {
    "coulomb_friction": ("friction_force_N", 2e-4),  # max 0.004 % [10 %]
    "cubic_stiffness": ("k3_N_per_m3", 0.02),  # max 0.49 % [10 %]
    "quadratic_stiffness": ("k2_N_per_m2", 0.005),  # max 0.14 % [10 %]
    "amplitude_dependent_damping": ("clearance_m", 0.001),  # max 0.023 % [10 %]
    "added_mass": ("added_mass_kg", 0.003),  # max 0.066 % [10 %]
    "cross_coupling": ("c_xy_Ns_per_m", 0.001),  # max 0.028 % [15 %]
    "second_mode": ("frequency_hz", 2e-4),  # max 0.005 % [10 %]
    "joint_microslip": ("slip_force_N", 0.06),  # max 2.1 % [20 %]
    "viscosity_drift": ("relative_change", 0.002),  # max 0.04 % [15 %]
    "sensor_gain": ("gain_ratio", 5e-4),  # max 0.012 % [10 %]
    "channel_delay": ("delay_s", 0.003),  # max 0.088 % [10 %]
    "air_entrainment": ("coefficient_s_per_m", 0.005),  # max 0.14 % [15 %]
}
#: one fixed seed per effect in CI (SEEDS dealt out in turn over the effects); the others `slow`
CI_SEEDS = {e: SEEDS[i % 4] for i, e in enumerate(TOLERANCE)}
#: The held-out error a lone finding must remove, error before / after (the engine accepts a
#: finding above 1.05 with its interval above 1): half the least measured over SEEDS.
MIN_GAIN: dict[str, float] = {
    "coulomb_friction": 25.0,  # 58-158 (high confidence)
    "cubic_stiffness": 1.25,  # 2.5-4.7
    "quadratic_stiffness": 3.4,  # 6.9-12.9
    "amplitude_dependent_damping": 7.5,  # 15-36
    "added_mass": 3.7,  # 7.5-19
    "cross_coupling": 13.0,  # 27-59
    "second_mode": 20.0,  # 40-99
    "joint_microslip": 5.3,  # 10.7-22 (replayed from the drive's start; 6.8-16 before)
    "viscosity_drift": 12.0,  # 25-40
    "sensor_gain": 3.0,  # 6.0-12
    "channel_delay": 2.1,  # 4.2-22
    "air_entrainment": 11.0,  # 23-93
}
#: After a lone finding the held-out error is at the noise floor: at most this many noise floors
#: where an effect needs more than one (measured 0.14-0.77; the joint's Dahl element 0.58-0.69
#: since a model with memory replays from the drive's start, 0.64-1.52 before, when it had 2)
AT_NOISE: dict[str, float] = {}
#: Cases judged wrong today (strict xfail, so that a fix shows), with what diagnose does instead.
#: None since session 13: coulomb_friction 21 and 43 and joint_microslip 11 and 54 were named
#: with low confidence and "unexplained" (1.2-7.4 noise floors left) because each held-out
#: dwell was replayed from rest 0.5 s before it, which a sticking seal or a micro-slipping
#: joint does not forget (`model.remembers`: such models replay from the run's start)
KNOWN_WRONG: dict[tuple[str, int], str] = {}
SLOW_CASES = [
    pytest.param(e, s, marks=[pytest.mark.xfail(reason=KNOWN_WRONG[e, s], strict=True)]
                 if (e, s) in KNOWN_WRONG else [])
    for e in TOLERANCE for s in SEEDS if s != CI_SEEDS[e]]


def _run(tmp_path, effects, seed):
    case = make_case(tmp_path, effects, seed)
    records = [load_run(p, i) for i, p in enumerate(case.paths)]
    return case, diagnose(records, seed=seed)


def _check_recovered(effect, truth, finding, tolerance=None):
    main, rel = TOLERANCE[effect]
    rel = rel if tolerance is None else tolerance
    true_v = truth[main]
    got = finding.parameters[main]
    assert math.isclose(got, true_v, rel_tol=rel), (
        f"{effect}: {main} = {got:.6g}, true {true_v:.6g} (off {got / true_v - 1:+.3%}, "
        f"tolerance {rel:.3%})")
    if "channel" in truth:
        assert finding.parameters["channel"] == truth["channel"]


def check_one(tmp_path, effect, seed):
    """One effect hidden at ``seed``: named alone, with high confidence, recovered within
    `TOLERANCE`, the held-out error down by `MIN_GAIN` and at the noise floor."""
    case, diag = _run(tmp_path, [effect], seed)
    names = [f.effect for f in diag.findings]
    assert names and names[0] == effect, f"hidden {case.effects}, found {names}"
    assert len(names) == 1, f"hidden {case.effects}, found {names} (spurious second finding)"
    f = diag.findings[0]
    _check_recovered(effect, case.effects[effect], f)
    assert f.evidence["confidence"] == "high"
    assert not diag.unexplained
    assert f.error_before / f.error_after >= MIN_GAIN[effect], (f.error_before, f.error_after)
    assert f.error_after <= AT_NOISE.get(effect, 1.0) * diag.noise_floor, (
        f"held-out error after {f.error_after:.3g} m, noise floor {diag.noise_floor:.3g} m")
    assert f.gain_interval[0] <= f.gain <= f.gain_interval[1]


def test_the_generators_step_harmonics_follow_the_run_file_convention():
    """The harmonics the generator writes (its own fit, not diagnose's): Z = c - i s for
    c cos + s sin of each harmonic, time from the run's sample 0 (docs/run-files.md)."""
    fs, f_hz, first = 10_000.0, 30.0, 1234
    t = (first + np.arange(1000)) / fs  # three whole cycles, starting mid-run
    w = 2 * math.pi * f_hz
    sig = 0.5 + 3.0 * np.cos(w * t) + 4.0 * np.sin(2 * w * t) - 2.0 * np.sin(5 * w * t)
    got = step_harmonics(np.vstack([sig, 2 * sig]), first, fs, f_hz)
    want = np.array([3.0, -4.0j, 0.0, 0.0, 2.0j])
    assert got.shape == (2, 5) and np.allclose(got, [want, 2 * want], atol=1e-12)


def test_every_library_effect_has_its_criteria_here():
    # a new effect in the library is tested only once its tolerance and gain are written here
    assert set(TOLERANCE) == set(MIN_GAIN) == set(LIBRARY)
    assert all(TOLERANCE[e][0] == LIBRARY[e].main for e in TOLERANCE)


#: The air case (seed 43) was "unexplained" when the whole-record checks landed: lines at
#: 43.2-43.5 Hz on the probes (7e-8 m, 10.8-11.4 sd) and 163.7-163.9 Hz on the
#: accelerometers (8.9-9.4 sd), all from the 60 Hz, 62 um dwell, where the rig's damping,
#: following the mean speed, grows a self-excited oscillation at its natural frequency (and
#: its sideband 120 + 43.7 Hz) which the fitted model grows too (3e-7 m over the 3 dwells,
#: 4x the residual's): the model's own response, no input (``whole_record._own_lines``).
@pytest.mark.parametrize("effect", list(TOLERANCE))
def test_hidden_effect_is_named_and_recovered(tmp_path, effect):
    check_one(tmp_path, effect, CI_SEEDS[effect])


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "seed"), SLOW_CASES)
def test_hidden_effect_many_seeds(tmp_path, effect, seed):
    check_one(tmp_path, effect, seed)


def test_clean_data_has_no_finding(tmp_path):
    case, diag = _run(tmp_path, [], CI_SEED)
    assert diag.findings == []
    assert not diag.unexplained
    # the replay reproduces the clean rig to the noise floor (measured 0.61 of it)
    assert diag.baseline_rms < 1.0 * diag.noise_floor


#: Two effects hidden together (CI_SEED): each main parameter's tolerance, a few times the error
#: measured (in brackets); one effect partly masks the other, so wider than alone
PAIRS: dict[tuple[str, str], dict[str, float]] = {
    ("cubic_stiffness", "sensor_gain"): {"cubic_stiffness": 0.004,  # 0.072 %
                                         "sensor_gain": 0.01},  # 0.26 %
    ("added_mass", "viscosity_drift"): {"added_mass": 0.002,  # 0.025 %
                                        "viscosity_drift": 0.10},  # 3.4 %
}


def check_pair(tmp_path, effects, seed):
    """The two effects ``effects`` hidden together at ``seed``: both found, each recovered
    within its `PAIRS` tolerance, with high confidence, and the error at the noise floor."""
    case, diag = _run(tmp_path, list(effects), seed)
    names = [f.effect for f in diag.findings]
    assert sorted(names) == sorted(effects), f"hidden {case.effects}, found {names}"
    for f in diag.findings:
        _check_recovered(f.effect, case.effects[f.effect], f, PAIRS[effects][f.effect])
        assert f.evidence["confidence"] == "high"
    # both together take the held-out error to the noise floor (measured 0.59-0.61 of it)
    assert diag.final_test.rms() <= 1.0 * diag.noise_floor
    assert not diag.unexplained


@pytest.mark.parametrize("effects", list(PAIRS))
def test_two_effects_are_both_found(tmp_path, effects):
    check_pair(tmp_path, effects, CI_SEED)


def test_effect_outside_the_library_is_not_named_with_confidence(tmp_path):
    """A y-stiffness error (not a library term) against the configured baseline: an honest
    "unexplained discrepancy" (the baseline replays the believed K_y, 15 % off, which no term
    of the library is: the y probes' 1X error stays tens of sd above the noise), any finding
    with low confidence. "No finding, nothing unexplained" would call a rig that is 15 % off
    explained. (Measured, seed 11: unexplained, one low-confidence cubic stiffness.)"""
    from analysis.diagnose.model import set_path

    case = make_case(tmp_path, [], CI_SEED)
    records = [load_run(p, i) for i, p in enumerate(case.paths)]
    # the configuration believed: K_y 15 % too high; the data are the true rig's
    from analysis.diagnose.model import Model

    wrong = set_path(Model(rig=records[0].rig), "structure.stiffness_y_n_per_m",
                     1.15 * records[0].rig.structure.stiffness_y_n_per_m).rig
    diag = diagnose(records, rig=wrong, seed=CI_SEED)
    assert diag.unexplained
    assert diag.verdict is not None
    assert diag.verdict.to_dict()["verdict"] == "unexplained discrepancy"
    assert all(f.evidence["confidence"] == "low" for f in diag.findings)


def test_several_run_files_are_diagnosed_together(tmp_path):
    """Two runs of the same rig (own dwell order and noise): dwells of both are held out."""
    case = make_case(tmp_path, ["added_mass"], CI_SEED, n_dwells=9, n_runs=2)
    records = [load_run(p, i) for i, p in enumerate(case.paths)]
    diag = diagnose(records, seed=CI_SEED)
    assert {s.run for s in diag.test} == {0, 1}
    assert [f.effect for f in diag.findings] == ["added_mass"]
    # measured 0.16 % off (alone, one run: 0.066 %)
    _check_recovered("added_mass", case.effects["added_mass"], diag.findings[0], 0.005)
