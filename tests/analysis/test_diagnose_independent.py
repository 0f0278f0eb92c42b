"""Diagnose on data it did not generate: hidden-effect cases of the independent generator.

The runs come from ``tests.independent_rig`` (no code shared with ``simulated_hw``), through the
canonical CSV and ``sfdrig import --lubricated --rig`` (see ``independent_cases.py``). What
"judged right" means is ``independent_cases.judged_right`` (the main parameter held to the
tolerance written in ``independent_cases.TOLERANCE``). CI runs every case at one fixed seed
(``CI_SEED``, one of the development seeds the tolerances were measured on); the other
development seeds (every case at seeds 2-5, the clean case at twenty more) are ``slow``. Cases
still judged wrong are marked xfail (strict) with what was measured, so that fixing one shows.
Seeds and cases nobody looks at while changing ``analysis/diagnose`` are in
``test_diagnose_held_out.py`` (marker ``held_out``, run before a diagnose change lands).

Imported without the rig description (the baseline fitted, its order chosen on held-out data):
the rods' cross stiffness (``coupled_axes``) is taken into the baseline, within 0.5 %, and no
cause is named with confidence (not the film's ``cross_coupling``); the film's cross terms are
not taken for a structural coupling and are still named; clean data moving both axes get an
uncoupled baseline. CI at ``CI_SEED``, seeds 2-5 ``slow``.
"""

from __future__ import annotations

import pytest

from analysis.diagnose import diagnose, load_run
from analysis.diagnose.report import diagnosis_json
from tests.analysis.independent_cases import (
    CASES,
    coupling_chosen,
    coupling_judged_right,
    judged_right,
    make_independent_case,
    order_summary,
)

#: CI's seed for every case (fixed: a failure in CI is the code's, not the day's seed);
#: ``DEV_SEEDS`` are the development seeds the tolerances were sized on, the others ``slow``
CI_SEED = 1
DEV_SEEDS = (1, 2, 3, 4, 5)
SLOW_SEEDS = tuple(s for s in DEV_SEEDS if s != CI_SEED)
#: the cases judged without the rig description (the fitted baseline's order)
WITHOUT_RIG = ("coupled_axes", "cross_coupling", "clean")
#: cases judged wrong today, per (effect, seed), with what diagnose does instead (measured);
#: strict, so that a fix shows. (second_mode came right at seeds 1-5 once simulated_hw put the
#: film's added mass on the housing-journal relative acceleration, as the generator does.)
KNOWN_WRONG: dict[tuple[str, int], str] = {}


def judge(tmp_path, effect: str, seed: int) -> None:
    """Case ``effect`` at ``seed``, imported with the rig description: judged right?"""
    case = make_independent_case(tmp_path, effect, seed)
    diag = diagnose([load_run(case.run)], seed=seed)
    ok, why = judged_right(effect, diagnosis_json(diag, None), case.truth)
    assert ok, f"{effect} (seed {seed}, truth {case.truth}): {why}"


def _maybe_xfail(effect: str, seed: int) -> list:
    if (effect, seed) in KNOWN_WRONG:
        return [pytest.mark.xfail(reason=KNOWN_WRONG[effect, seed], strict=True)]
    return []


@pytest.mark.parametrize("effect", [
    pytest.param(e, marks=_maybe_xfail(e, CI_SEED)) for e in CASES])
def test_independent_case_at_the_ci_seed(tmp_path, effect):
    judge(tmp_path, effect, CI_SEED)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(100, 120))
def test_clean_independent_data_many_seeds(tmp_path, seed):
    judge(tmp_path, "clean", seed)


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "seed"), [
    pytest.param(e, s, marks=_maybe_xfail(e, s)) for e in CASES if e != "clean"
    for s in SLOW_SEEDS])
def test_independent_case_is_judged_right(tmp_path, effect, seed):
    judge(tmp_path, effect, seed)


def judge_without_rig(tmp_path, effect: str, seed: int) -> None:
    """Case ``effect`` imported without the rig description, moving both axes in turn."""
    case = make_independent_case(tmp_path, effect, seed, rig_described=False, both_axes=True)
    doc = diagnosis_json(diagnose([load_run(case.run)], seed=seed), None)
    k_xy = coupling_chosen(doc)
    if effect == "coupled_axes":
        ok, why = coupling_judged_right(doc, case.truth)
    else:  # no structural coupling: an uncoupled baseline, and the case judged as ever
        ok, why = judged_right(effect, doc, case.truth)
        ok, why = ok and k_xy is None, f"{why}; order {order_summary(doc)}"
    print(f"{effect} without the rig, seed {seed}, truth {case.truth}: {why}")  # -s shows it
    assert ok, f"{effect} without the rig (seed {seed}, truth {case.truth}): {why}"


@pytest.mark.parametrize("effect", WITHOUT_RIG)
def test_without_the_rig_at_the_ci_seed(tmp_path, effect):
    judge_without_rig(tmp_path, effect, CI_SEED)


@pytest.mark.slow
@pytest.mark.parametrize("effect", WITHOUT_RIG)
@pytest.mark.parametrize("seed", SLOW_SEEDS)
def test_without_the_rig_is_judged_right(tmp_path, effect, seed):
    judge_without_rig(tmp_path, effect, seed)
