"""Diagnose on data it did not generate: hidden-effect cases of the independent generator.

The runs come from ``tests.independent_rig`` (no code shared with ``simulated_hw``), through the
canonical CSV and ``sfdrig import --lubricated --rig`` (see ``independent_cases.py``). What
"judged right" means is ``independent_cases.judged_right``. CI runs the clean case and one
library case with a seed that rotates by the day (printed on failure); every case with five
seeds and the clean case with twenty are ``slow``. Cases still judged wrong are marked xfail
(strict) with what was measured, so that fixing one shows.
"""

from __future__ import annotations

import datetime

import pytest

from analysis.diagnose import diagnose, load_run
from analysis.diagnose.report import diagnosis_json
from tests.analysis.independent_cases import CASES, judged_right, make_independent_case

ROTATING_SEED = datetime.date.today().toordinal() % 1000
#: cases judged wrong today, with what diagnose does instead (measured). None at present:
#: second_mode came right at seeds 1-5 once simulated_hw put the film's added mass on the
#: housing-journal relative acceleration (as the generator does): the frame at 0.001-0.004 Hz
#: and 100.00-100.09 kg (truth 100 kg), 1.04x the noise floor left.
KNOWN_WRONG: dict[str, str] = {}


def _judge(tmp_path, effect: str, seed: int) -> None:
    case = make_independent_case(tmp_path, effect, seed)
    diag = diagnose([load_run(case.run)], seed=seed)
    ok, why = judged_right(effect, diagnosis_json(diag, None))
    assert ok, f"{effect} (seed {seed}, truth {case.truth}): {why}"


def _maybe_xfail(effect: str) -> list:
    if effect in KNOWN_WRONG:
        return [pytest.mark.xfail(reason=KNOWN_WRONG[effect], strict=False)]
    return []


def test_clean_independent_data_gives_no_finding(tmp_path):
    _judge(tmp_path, "clean", ROTATING_SEED)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(100, 120))
def test_clean_independent_data_many_seeds(tmp_path, seed):
    _judge(tmp_path, "clean", seed)


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "seed"), [
    pytest.param(e, s, marks=_maybe_xfail(e)) for e in CASES if e != "clean"
    for s in (1, 2, 3, 4, 5)])
def test_independent_case_is_judged_right(tmp_path, effect, seed):
    _judge(tmp_path, effect, seed)
