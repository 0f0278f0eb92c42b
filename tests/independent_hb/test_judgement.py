"""Diagnose on the harmonic-balance generator's data, as an operator has it (issue 24, 6).

Each case is recorded (``cases.generate``), imported with the minimal conditions
(``--lubricated --motion x --seal none``, no rig description) and diagnosed with
``sfdrig diagnose --baseline fitted``. The right answer is written in ``cases.judge`` (named
with its size within a tolerance from the noise, an honest "unexplained" outside the library,
never a confident wrong cause, nothing on clean data) and is what diagnose should say, not what
it says today: where today's diagnose is wrong the case is ``xfail(strict=True)`` with what it
said (seed 1, 2026-11-26).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.independent_hb.cases import cases, generate, judge, signature_of
from tests.independent_hb.generate import import_run

SEED = 1
#: run in CI (each is one diagnose of 16 dwells)
FAST = ("clean", "friction_large")
#: what today's diagnose says where it is wrong (seed 1)
WRONG_TODAY: dict[str, str] = {}


def _params() -> list:
    out = []
    for name in cases(SEED):
        marks = [] if name in FAST else [pytest.mark.slow]
        if name in WRONG_TODAY:
            marks.append(pytest.mark.xfail(strict=True, reason=f"issue 24: {WRONG_TODAY[name]}"))
        out.append(pytest.param(name, marks=marks, id=name))
    return out


@pytest.mark.parametrize("name", _params())
def test_diagnose_names_what_the_hb_generator_hid(name: str, tmp_path: Path) -> None:
    from sfdrig.cli import main

    case = cases(SEED)[name]
    rec = generate(case, SEED)
    total = signature_of(rec.dwells, rec.sensors).total
    run = import_run(rec, tmp_path, name)
    out = tmp_path / "diagnose.json"
    rc = main(["diagnose", str(run), "--baseline", "fitted", "--json", str(out), "--quiet"])
    assert rc == 0, f"diagnose exit {rc} on {name}"
    ok, said = judge(case, json.loads(out.read_text()), total)
    assert ok, f"{name} (signature {total:.0f} sigma over the run): {said}"
