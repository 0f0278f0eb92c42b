"""Amplitude dependence (the linear model per level) and training on some runs, testing on others.

The level data are written here in closed form (the steady state of one mode whose equivalent
stiffness and damping depend on the level, as a micro-slipping joint's do), not by the code
under test; the CLI test uses the independent generator's linear rig.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from analysis.diagnose import DiagnoseError
from analysis.diagnose.amplitude import amplitude_dependence, contradictions
from analysis.diagnose.data import RunRecord, Segment, records_from_arrays, split_by_runs
from sfdrig.cli import main
from tests.analysis.independent_cases import RIG_TOML
from tests.independent_rig import Generator, RigSpec, Sensors, grid

FS = 5000.0
FREQS = (10.0, 14.0, 18.0, 22.0, 26.0, 30.0)
M = 20.0


def _level_run(name: str, run: int, force_n: float, k: float, c: float,
               rng: np.random.Generator) -> RunRecord:
    """Dwells of one mode (M, c, k) at one force amplitude, closed-form steady state + noise."""
    n = int(0.6 * FS)
    f_all, z_all, segs = [], [], []
    for j, f_hz in enumerate(FREQS):
        w = 2 * math.pi * f_hz
        t = (j * n + np.arange(n)) / FS
        h = 1.0 / (k - w**2 * M + 1j * w * c)
        f_all.append(force_n * np.cos(w * t))
        z_all.append(np.real(force_n * h * np.exp(1j * w * t)) + 2e-8 * rng.standard_normal(n))
        segs.append(Segment(run, j * n, (j + 1) * n, f"{name}#{j}", f_hz, "x"))
    rec = records_from_arrays(np.concatenate(f_all), {"x": np.concatenate(z_all)}, FS, name)
    rec.segments = segs
    return rec


def _runs(softening: bool) -> list[RunRecord]:
    rng = np.random.default_rng(4)
    out = []
    for i, level in enumerate((10.0, 30.0, 90.0)):
        k = 400e3 * (1 - 0.06 * i) if softening else 400e3
        c = 300.0 * (1 + 0.5 * i) if softening else 300.0
        out.append(_level_run(f"L{level:g}", i, level, k, c, rng))
    return out


def _all(records: list[RunRecord]) -> list[Segment]:
    return [s for r in records for s in r.segments]


def test_softening_joint_pattern_per_run():
    records = _runs(softening=True)
    dep = amplitude_dependence(records, _all(records))
    assert [lv.label for lv in dep.levels] == ["L10", "L30", "L90"]
    fn_true = [math.sqrt(400e3 * (1 - 0.06 * i) / M) / (2 * math.pi) for i in range(3)]
    # measured over the noise of rng seeds 4-9: natural frequency within 3.9e-7, damping ratio
    # 1.24e-5; the change over the levels +3.2 % at every seed (the bias of the fit over
    # log(level)); the linear structure's change within 3.7e-7 of zero
    for lv, f in zip(dep.levels, fn_true, strict=True):
        assert lv.natural_hz == pytest.approx(f, rel=2e-6)
        assert lv.force_n == pytest.approx(float(lv.label[1:]), rel=1e-3)
    zeta_true = [300.0 * (1 + 0.5 * i) / (2 * math.sqrt(400e3 * (1 - 0.06 * i) * M))
                 for i in range(3)]
    for lv, z in zip(dep.levels, zeta_true, strict=True):
        assert lv.damping_ratio == pytest.approx(z, rel=5e-5)
    assert dep.frequency["x"].verdict == "softening"
    assert dep.damping["x"].verdict == "rising"
    # fitted over log(level): the change from the lowest to the highest level
    assert dep.frequency["x"].change == pytest.approx(fn_true[2] / fn_true[0] - 1, rel=0.05)
    assert "joint_microslip" in dep.effects["x"]
    assert dep.nonlinear()
    # a level-independent term alone cannot carry the trend; beside a level term it may
    assert set(contradictions(dep, [("second_mode", {"frequency_hz": 25.0})])) == {
        "second_mode"}
    assert contradictions(dep, [("second_mode", {}), ("joint_microslip", {})]) == {}
    # a hardening cubic spring against softening levels; a softening one is consistent
    assert set(contradictions(dep, [("cubic_stiffness", {"k3_N_per_m3": 1e12})])) == {
        "cubic_stiffness"}
    assert contradictions(dep, [("cubic_stiffness", {"k3_N_per_m3": -1e12})]) == {}


def test_linear_structure_shows_no_trend():
    records = _runs(softening=False)
    dep = amplitude_dependence(records, _all(records))
    assert dep.frequency["x"].verdict == "none" and dep.damping["x"].verdict == "none"
    assert abs(dep.frequency["x"].change) < 2e-6  # measured 3.7e-7 (seeds 4-9)
    assert dep.effects["x"] == [] and not dep.nonlinear()
    assert contradictions(dep, [("second_mode", {})]) == {}


def test_levels_within_one_run_by_response_amplitude():
    """One run of displacement-held dwells: three amplitude groups are the levels."""
    rng = np.random.default_rng(5)
    n = int(0.6 * FS)
    f_all, z_all, segs = [], [], []
    j = 0
    for i, z_amp in enumerate((10e-6, 20e-6, 40e-6)):
        k, c = 400e3 * (1 - 0.05 * i), 300.0 * (1 + 0.4 * i)
        for f_hz in FREQS:
            w = 2 * math.pi * f_hz
            t = (j * n + np.arange(n)) / FS
            dyn = k - w**2 * M + 1j * w * c
            f_all.append(np.real(z_amp * dyn * np.exp(1j * w * t)))
            z_all.append(z_amp * np.cos(w * t) + 2e-8 * rng.standard_normal(n))
            segs.append(Segment(0, j * n, (j + 1) * n, f"#{j}", f_hz, "x"))
            j += 1
    rec = records_from_arrays(np.concatenate(f_all), {"x": np.concatenate(z_all)}, FS)
    rec.segments = segs
    dep = amplitude_dependence([rec], segs)
    assert [lv.level_by for lv in dep.levels] == ["response"] * 3
    assert [lv.response_m for lv in dep.levels] == pytest.approx([10e-6, 20e-6, 40e-6],
                                                                 rel=0.01)
    assert dep.frequency["x"].verdict == "softening"
    assert dep.damping["x"].verdict == "rising"


def test_one_level_gives_no_verdict_and_says_why():
    records = _runs(softening=True)[:1]
    dep = amplitude_dependence(records, _all(records))
    assert not dep.frequency and "two or more levels" in dep.text


def test_split_by_runs_and_its_errors():
    records = _runs(softening=False)
    train, test = split_by_runs(records, [0, 1])
    assert {s.run for s in train} == {0, 1} and {s.run for s in test} == {2}
    with pytest.raises(DiagnoseError, match="at least one run"):
        split_by_runs(records, [0, 1, 2])
    y_only = records_from_arrays(np.vstack([np.zeros(600), np.sin(np.arange(600) / 9)]),
                                 {"y": np.zeros(600)}, FS, "yonly.h5")
    with pytest.raises(DiagnoseError, match=r"yonly\.h5 drives the y axis"):
        split_by_runs([records[0], y_only], [0])


def _independent_run(tmp: Path, amp_m: float, seed: int) -> Path:
    """A lubricated X run of the independent generator's linear rig at one amplitude (y: the
    load cell's noise only)."""
    rec = Generator(RigSpec(), Sensors(seed=seed)).run(
        grid([20.0, 30.0, 40.0, 50.0, 60.0], [amp_m], "x", record_s=0.4))
    csv = rec.to_csv(tmp / f"a{amp_m * 1e6:.0f}.csv")
    out = tmp / f"a{amp_m * 1e6:.0f}.h5"
    rig = tmp / "rig.toml"
    rig.write_text(RIG_TOML)  # the rig described correctly (no seal, film without eq. 16's law)
    assert main(["import", str(csv), "--out", str(out), "--lubricated", "--motion", "x",
                 "--seal", "none", "--rig", str(rig), "--overwrite"]) == 0
    return out


@pytest.fixture(scope="module")
def level_runs(tmp_path_factory) -> list[Path]:
    tmp = tmp_path_factory.mktemp("levels")
    return [_independent_run(tmp, a, 11 + i) for i, a in enumerate((13e-6, 25e-6, 38e-6))]


def test_cli_train_runs_test_runs(level_runs, tmp_path, capsys):
    a, b, c = level_runs
    out = tmp_path / "d.json"
    rep = tmp_path / "rep"
    rc = main(["diagnose", "--train-runs", str(a), str(b), "--test-runs", str(c), "--json",
               str(out), "--report", str(rep), "--quiet", "--effects",
               "cubic_stiffness,coulomb_friction", "--max-effects", "1"])
    assert rc == 0, capsys.readouterr().err
    doc = json.loads(out.read_text())
    assert doc["train_runs"] == [a.name, b.name] and doc["test_runs"] == [c.name]
    assert doc["segments"] == {"train": 10, "test": 5}
    assert doc["findings"] == []
    # nothing found: the nearest candidate is reported with its size, its gain insignificant
    best = doc["best_candidate"]
    assert best["effect"] in ("cubic_stiffness", "coulomb_friction")
    assert best["gain"] == pytest.approx(doc["baseline"]["rms_error"] / best["held_out_error"])
    assert best["gain"] < 1.05
    dep = doc["amplitude_dependence"]
    assert [lv["level"] for lv in dep["levels"]] == [a.name, b.name, c.name]
    # the independent rig is linear: 17.9 kg, 788 kN/m -> 33.4 Hz at every level
    for lv in dep["levels"]:
        assert lv["natural_frequency_hz"] == pytest.approx(33.40, rel=0.01)
    assert dep["natural_frequency_trend"]["x"]["verdict"] == "none"
    assert dep["damping_trend"]["x"]["verdict"] == "none"
    # the modal fit: one mode per level (5 dwell frequencies cannot carry two), the same mode
    modes = doc["modes"]
    assert modes["modes_per_axis"] == {"x": 1} == doc["baseline"]["modes_in_band_per_axis"]
    assert [lv["level"] for lv in modes["levels"]] == [a.name, b.name, c.name]
    for lv in modes["levels"]:
        assert lv["modes"][0]["natural_frequency_hz"] == pytest.approx(33.40, rel=0.01)
    assert modes["tracks"][0]["natural_frequency_trend"]["verdict"] == "none"
    page = (rep / "index.html").read_text()
    assert "Amplitude dependence" in page and "amplitude.png" in page
    assert "Modes in the band" in page
    assert (rep / "amplitude.png").read_bytes()[:4] == b"\x89PNG"
    out_text = capsys.readouterr().out
    assert "amplitude dependence: x: natural frequency level-independent" in out_text
    # 33.4 Hz at a damping ratio of 72 % (5.43 kN.s/m over 2 sqrt(788 kN/m x 17.9 kg)): the
    # pole no longer pinned on a bound at 70 %
    said = re.search(r"modes in the band: x: 1 mode \(([\d.]+)[^(]*\(damping (\d+) ", out_text)
    assert said and float(said[1]) == pytest.approx(33.40, rel=0.01), out_text
    assert int(said[2]) == 72, out_text
    # a gain that rounds to 1 lowers nothing: then no candidate is called best
    lead = ("best candidate" if round(best["gain"], 3) > 1.0
            else "no candidate lowers the held-out error; the nearest")
    assert f"  {lead}: {best['effect']} (" in out_text


@pytest.mark.parametrize(("args", "message"), [
    (["A", "--train-runs", "B", "--test-runs", "C"], "one way"),
    (["--train-runs", "A"], "--train-runs needs --test-runs"),
    (["--test-runs", "A"], "--test-runs needs --train-runs"),
    (["--train-runs", "A", "--test-runs", "A"], "in both --train-runs and --test-runs"),
    (["--train-runs", "A", "A", "--test-runs", "B"], "twice in --train-runs"),
    (["--train-runs", "A", "--test-runs", "B", "--train", "0:10", "--test", "10:20"],
     "cannot be combined"),
    (["--train-runs", "A", "--test-runs", "B", "--judge", "force"], "--judge response only"),
    ([], "no run files"),
])
def test_cli_bad_run_combinations_exit_2(level_runs, args, message, capsys):
    paths = {"A": str(level_runs[0]), "B": str(level_runs[1]), "C": str(level_runs[2])}
    rc = main(["diagnose", *[paths.get(x, x) for x in args], "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
