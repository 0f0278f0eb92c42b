"""The harmonic-balance generator shares no code with what it tests (as tests/independent_rig):
none of its modules imports the rig model, the simulator, the analysis, the controller or the
daemon's packages. Only its tests (``test_*.py``) call diagnose, and ``generate.import_run``
hands the recording to ``sfdrig import`` as an operator does (inside the function)."""

from __future__ import annotations

import ast
from pathlib import Path

#: the project's packages a generator must not read its physics or its judgement from
PRODUCTION = ("analysis", "rig_model", "simulated_hw", "control", "daq", "storage", "web")


def production_imports(source: str, top_level_only: bool = False) -> list[str]:
    """The production modules ``source`` imports (anywhere, or only at module level)."""
    tree = ast.parse(source)
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    out = []
    for node in nodes:
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
        out += [n for n in names if n.split(".")[0] in PRODUCTION]
    return out


def test_the_guard_sees_an_import_anywhere() -> None:
    assert production_imports("import numpy\nfrom analysis.diagnose import diagnose\n") == [
        "analysis.diagnose"]
    assert production_imports("def f():\n    import rig_model.physics as p\n") == [
        "rig_model.physics"]
    assert production_imports("from tests.independent_hb.rig import Rig\n") == []


def test_the_generator_imports_no_production_code() -> None:
    modules = [p for p in Path(__file__).parent.glob("*.py") if not p.name.startswith("test_")]
    assert {p.name for p in modules} >= {"balance.py", "cases.py", "generate.py", "rig.py",
                                         "sensors.py", "record_cases.py"}
    for path in modules:
        assert not production_imports(path.read_text()), \
            f"{path.name} imports {production_imports(path.read_text())}"
