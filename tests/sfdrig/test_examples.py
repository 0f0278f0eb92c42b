"""The example files shipped in examples/ stay valid as the models change."""

from __future__ import annotations

from pathlib import Path

from control.run.sweep.engine import load_sweep_spec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_example_sweeps_load():
    lub = load_sweep_spec(EXAMPLES / "lubricated_x.toml")
    assert lub.lubricated and lub.motion == "x"
    assert list(lub.amplitude_m or []) == [13e-6, 19e-6, 25e-6, 32e-6, 38e-6]
    dry = load_sweep_spec(EXAMPLES / "dry_circular.toml")
    assert not dry.lubricated and list(dry.load_n or []) == [40.0, 33.0]
