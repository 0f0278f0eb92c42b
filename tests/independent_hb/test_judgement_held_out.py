"""The harmonic-balance generator's cases at held-out seeds: plans, noise and the threshold
friction's size that no development run has used (the development seed is 1, in
``test_judgement.py``; these are above 5000, apart from the independent rig's held-out
4101-4103).

Marked ``held_out``: not run by ``./dev test`` nor by ``-m slow`` (``tests/conftest.py``
deselects them unless the ``-m`` expression names ``held_out``). Run them once before a change
to ``analysis/diagnose`` lands, not while making it::

    ./dev test -m held_out tests/independent_hb

and report how many are judged right with the change. The judgement is the development
seed's (``cases.judge``), with no xfail: a case wrong here is a finding about diagnose, never a
reason to adjust a tolerance or a seed until it passes; the seeds are changed only for a fresh
set (then to seeds nobody has run, and the old ones become development seeds).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.independent_hb.cases import cases
from tests.independent_hb.test_judgement import check_case

pytestmark = pytest.mark.held_out

#: the held-out seeds (never used in development; keep it that way)
HELD_OUT_SEEDS = (5101, 5102)


@pytest.mark.parametrize("seed", HELD_OUT_SEEDS)
@pytest.mark.parametrize("name", list(cases()))
def test_diagnose_names_what_the_hb_generator_hid_held_out(
        name: str, seed: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    check_case(name, seed, tmp_path, capsys)
