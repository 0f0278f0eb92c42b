"""Hidden-effect tests: diagnose must name the effect hidden in simulated runs and recover it.

The generator (`hidden_effects.py`) hides one effect (or two, or none) in the true rig, records
sine dwells through the simulator with sensor noise, writes run files, and diagnose gets only the
files. Each effect's main parameter must come back within the tolerance documented in
`analysis.diagnose.effects.LIBRARY`. CI runs one seed per effect (seeds rotate over the
effects); the other seeds of each effect are `slow`.
"""

from __future__ import annotations

import math

import pytest

from analysis.diagnose import LIBRARY, diagnose, load_run
from tests.analysis.hidden_effects import make_case

CI_SEED = 11  # clean, pairs, out-of-library, several runs
SEEDS = (11, 21, 32, 43, 54)
#: one seed per effect in CI (rotating through SEEDS); the others behind the `slow` marker
CI_SEEDS = {e: SEEDS[i % 4] for i, e in enumerate(LIBRARY)}
SLOW_CASES = [(e, s) for e in LIBRARY for s in SEEDS if s != CI_SEEDS[e]]


def _run(tmp_path, effects, seed):
    case = make_case(tmp_path, effects, seed)
    records = [load_run(p, i) for i, p in enumerate(case.paths)]
    return case, diagnose(records, seed=seed)


def _check_recovered(effect, truth, finding):
    lib = LIBRARY[effect]
    true_v = truth[lib.main]
    got = finding.parameters[lib.main]
    assert math.isclose(got, true_v, rel_tol=lib.tolerance), (
        f"{effect}: {lib.main} = {got:.6g}, true {true_v:.6g} (tolerance {lib.tolerance:.0%})")
    if "channel" in truth:
        assert finding.parameters["channel"] == truth["channel"]


def _check_one(tmp_path, effect, seed):
    case, diag = _run(tmp_path, [effect], seed)
    names = [f.effect for f in diag.findings]
    assert names and names[0] == effect, f"hidden {case.effects}, found {names}"
    assert len(names) == 1, f"hidden {case.effects}, found {names} (spurious second finding)"
    f = diag.findings[0]
    _check_recovered(effect, case.effects[effect], f)
    assert f.gain > 1.05 and f.gain_interval[0] >= 0.999
    assert f.gain_interval[0] <= f.gain <= f.gain_interval[1]
    assert f.error_after < f.error_before
    assert not diag.unexplained
    assert f.evidence["confidence"] == "high"


@pytest.mark.parametrize("effect", list(LIBRARY))
def test_hidden_effect_is_named_and_recovered(tmp_path, effect):
    _check_one(tmp_path, effect, CI_SEEDS[effect])


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "seed"), SLOW_CASES)
def test_hidden_effect_many_seeds(tmp_path, effect, seed):
    _check_one(tmp_path, effect, seed)


def test_clean_data_has_no_finding(tmp_path):
    case, diag = _run(tmp_path, [], CI_SEED)
    assert diag.findings == []
    assert not diag.unexplained
    # the replay reproduces the clean rig to the noise floor
    assert diag.baseline_rms < 1.5 * diag.noise_floor


@pytest.mark.parametrize("effects", [("cubic_stiffness", "sensor_gain"),
                                     ("added_mass", "viscosity_drift")])
def test_two_effects_are_both_found(tmp_path, effects):
    case, diag = _run(tmp_path, list(effects), CI_SEED)
    names = [f.effect for f in diag.findings]
    assert sorted(names) == sorted(effects), f"hidden {case.effects}, found {names}"
    for f in diag.findings:
        _check_recovered(f.effect, case.effects[f.effect], f)
        assert f.evidence["confidence"] == "high"
    assert diag.final_test.rms() < diag.findings[0].error_before
    assert not diag.unexplained


def test_effect_outside_the_library_is_not_named_with_confidence(tmp_path):
    """A y-stiffness error (not a library term) must end unexplained or low-confidence."""
    from analysis.diagnose.model import set_path

    case = make_case(tmp_path, [], CI_SEED)
    records = [load_run(p, i) for i, p in enumerate(case.paths)]
    # the configuration believed: K_y 15 % too high; the data are the true rig's
    from analysis.diagnose.model import Model

    wrong = set_path(Model(rig=records[0].rig), "structure.stiffness_y_n_per_m",
                     1.15 * records[0].rig.structure.stiffness_y_n_per_m).rig
    diag = diagnose(records, rig=wrong, seed=CI_SEED)
    assert diag.unexplained or not diag.findings
    assert all(f.evidence["confidence"] == "low" for f in diag.findings)


def test_several_run_files_are_diagnosed_together(tmp_path):
    """Two runs of the same rig (own dwell order and noise): dwells of both are held out."""
    case = make_case(tmp_path, ["added_mass"], CI_SEED, n_dwells=9, n_runs=2)
    records = [load_run(p, i) for i, p in enumerate(case.paths)]
    diag = diagnose(records, seed=CI_SEED)
    assert {s.run for s in diag.test} == {0, 1}
    assert [f.effect for f in diag.findings] == ["added_mass"]
    _check_recovered("added_mass", case.effects["added_mass"], diag.findings[0])
