"""`sfdrig sweep --check FILE`: a sweep checked offline, no daemon (issue 39: a typo such as
`recrod_cycles` was "Extra inputs are not permitted" with no "did you mean", and only a running
daemon checked a file at all)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sfdrig.cli import main

GOOD = """
motion = "x"
amplitude_m = [13e-6, 25e-6]
freq_hz = [20.0, 40.0]
record_cycles = 40
"""
NO_DAEMON = ["--runs-dir", "/nonexistent/runs"]  # a check that asked a daemon would fail here


@pytest.fixture
def good(tmp_path: Path) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(GOOD)
    return path


def test_a_valid_file_passes_offline(good: Path, capsys):
    assert main(["sweep", "--check", str(good), *NO_DAEMON]) == 0
    assert capsys.readouterr().out == (
        f"{good}: valid: 4 steps, x, displacement 13, 25 um at 2 frequencies 20-40 Hz; checked "
        "against the daemon's default limits: displacement 63.5 um, load 448 N, 5-500 Hz and "
        "the default channel map\n")


def test_typos_in_the_file_and_in_set_are_named_with_what_they_probably_mean(good, capsys):
    good.write_text(GOOD.replace("record_cycles", "recrod_cycles") + "[control]\nblok_s = 0.01\n")
    assert main(["sweep", "--check", str(good), "--set", "setle_cycles=5", *NO_DAEMON]) == 2
    assert capsys.readouterr().out.splitlines() == [
        f"{good}: control.blok_s = 0.01: Extra inputs are not permitted; did you mean 'block_s'?",
        f"{good}: recrod_cycles = 40: Extra inputs are not permitted; did you mean "
        "'record_cycles'?",
        "--set: setle_cycles = 5: Extra inputs are not permitted; did you mean "
        "'settle_cycles'?",
    ]


def test_an_unreachable_target_fails_the_check_with_the_largest_accepted(good, capsys):
    args = ["sweep", "--check", str(good), "--set", "amplitude_m=[60e-6]", *NO_DAEMON]
    assert main(args) == 2
    out = capsys.readouterr().out
    assert out.startswith("--set: amplitude_m = 6e-05 (60 um) (x, 2 steps from step 1/2): "), out
    assert out.rstrip().endswith("the largest amplitude_m accepted is 5.08e-05 (50.8 um)"), out
