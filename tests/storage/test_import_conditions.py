"""Imported runs carry their test conditions; identify works on them (issue 9).

Data from the independent generator (`tests.independent_rig`), through the real CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sfdrig.cli import main
from storage import open_run
from tests.independent_rig import Dwell, Generator, RigSpec, Sensors, grid

FREQS = [20.0, 30.0, 40.0, 50.0, 60.0]
AMPS = [13e-6, 25e-6, 38e-6]


@pytest.fixture(scope="module")
def lub_csv(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RigSpec]:
    rig = RigSpec()  # lubricated, no seal
    rec = Generator(rig, Sensors(seed=11)).run(grid(FREQS, AMPS, "x"))
    path = tmp_path_factory.mktemp("lub") / "lub.csv"
    rec.to_csv(path)
    return path, rig


def test_conditions_are_stored_and_motion_inferred(lub_csv, tmp_path: Path, capsys) -> None:
    src, _ = lub_csv
    out = tmp_path / "lub.h5"
    assert main(["import", str(src), "--out", str(out), "--lubricated", "--seal", "none"]) == 0
    printed = capsys.readouterr().out
    assert "motion inferred from the x/y phase (stored as inferred): x for 15 dwell(s)" in printed
    with open_run(out) as run:
        assert bool(run.attrs["lubricated"]) is True
        assert len(run.steps) == 15  # (20 Hz, 13 um) then (20 Hz, 25 um)... are separate dwells
        assert {s["motion"] for s in run.steps} == {"x"}
        cond = run.test_spec["conditions"]
        assert cond["seal"] == "none" and cond["sources"]["seal"] == "given"
        assert all(m["source"].startswith("inferred from the x/y phase")
                   for m in cond["motion_per_step"])


def test_identify_on_imported_run_meets_the_acceptance(lub_csv, tmp_path: Path) -> None:
    src, rig = lub_csv
    out = tmp_path / "lub.h5"
    assert main(["import", str(src), "--out", str(out), "--lubricated", "--seal", "none",
                 "--motion", "x"]) == 0
    report = tmp_path / "r.json"
    assert main(["identify", str(out), "--json", str(report)]) == 0
    lub = json.loads(report.read_text())["lubricated"]
    assert lub["seal_friction_N"] == 0.0
    truth_d, truth_c = rig.added_mass_kg, rig.film_damping_ns_per_m
    fits = [f for f in lub["table6_and_appendix_E"] if f["method"] == "eq9"]
    assert len(fits) == 3
    for f in fits:
        assert f["k_n_per_m"] == pytest.approx(788e3, rel=0.03)
        assert f["u_k_n_per_m"] > 0
        assert f["added_mass_kg"] == pytest.approx(truth_d, rel=0.05)
        assert 0 < f["u_added_mass_kg"] < 0.1 * truth_d
    for g in lub["sfd_damping_by_amplitude"]:
        c = g["eq9"]
        assert c["C_sfd_mean_Ns_per_m"] == pytest.approx(truth_c, rel=0.05)
        assert 0 < c["U_C_sfd_Ns_per_m"] < 0.05 * truth_c


def test_rig_file_is_stored_as_rig_config_and_gives_the_seal(lub_csv, tmp_path: Path,
                                                            capsys) -> None:
    src, _ = lub_csv
    rig_toml = tmp_path / "rig.toml"
    rig_toml.write_text("[seal]\nenabled = false\n")
    out = tmp_path / "lub.h5"
    assert main(["import", str(src), "--out", str(out), "--conditions", str(_cond(tmp_path))
                 , "--rig", str(rig_toml)]) == 0
    assert "seal: none [rig file" in capsys.readouterr().out
    with open_run(out) as run:
        assert run.rig_config["seal"]["enabled"] is False
        assert bool(run.attrs["lubricated"]) is True  # from the conditions file


def _cond(tmp_path: Path) -> Path:
    p = tmp_path / "c.toml"
    p.write_text('lubricated = true\nmotion = "x"\n')
    return p


def test_conditions_file_beside_the_data_and_bad_keys(tmp_path: Path, capsys) -> None:
    rec = Generator(RigSpec(), Sensors(seed=2)).run(
        [Dwell(30.0, 20e-6, "circular_forward", 0.3), Dwell(30.0, 20e-6, "x", 0.3),
         Dwell(30.0, 30e-6, "elliptical", 0.3)])
    data = rec.to_csv(tmp_path / "a.csv")
    (tmp_path / "conditions.toml").write_text('lubricated = true\nseal = 0\n')
    assert main(["import", str(data), "--out", str(tmp_path / "a.h5")]) == 0
    with open_run(tmp_path / "a.h5") as run:
        assert [s["motion"] for s in run.steps] == ["circular_forward", "x", "elliptical"]
        assert run.test_spec["conditions"]["sources"]["lubricated"].startswith(
            "conditions file")
    (tmp_path / "conditions.toml").write_text('lubricated = "yes"\n')
    assert main(["import", str(data), "--out", str(tmp_path / "b.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "conditions.toml" in err[0] and "lubricated" in err[0]
    assert not (tmp_path / "b.h5").exists()


def test_acceleration_only_response_is_accepted(tmp_path: Path) -> None:
    rec = Generator(RigSpec(), Sensors(seed=4)).run(grid([20.0, 40.0], [25e-6], "x", 0.4))
    data = rec.to_csv(tmp_path / "acc.csv",
                      columns=("time_s", "freq_hz", "fx_N", "fy_N", "ax_mps2", "ay_mps2"))
    out = tmp_path / "acc.h5"
    assert main(["import", str(data), "--out", str(out), "--lubricated"]) == 0
    with open_run(out) as run:
        for st, seg in zip(run.steps, rec.segments, strict=True):
            x = run.signal("x", st["first_sample"], st["last_sample"])
            truth = seg.z(run.time_s(st["first_sample"], st["last_sample"]))[0]
            # accelerometer noise 0.05 m/s^2 against w^2 A = 0.39 m/s^2 at 20 Hz: about 0.4 %
            # per harmonic over 8 cycles, five harmonics kept
            assert np.max(np.abs(x - truth)) < 0.03 * 25e-6
        assert "derived from" in run.channel_attrs("x")["sensor"]


def test_sine_sweep_is_a_sweep_not_dwells(tmp_path: Path) -> None:
    from tests.independent_rig import Sweep
    rec = Generator(RigSpec(), Sensors(seed=5)).run(
        [Dwell(20.0, 13e-6, "x", 0.3), Sweep(20.0, 60.0, 1.0, 30.0)])
    data = rec.to_csv(tmp_path / "sw.csv")
    out = tmp_path / "sw.h5"
    assert main(["import", str(data), "--out", str(out), "--dry"]) == 0
    with open_run(out) as run:
        assert len(run.steps) == 1
        sweeps = run.test_spec["sweeps"]
        assert len(sweeps) == 1
        assert sweeps[0]["f_start_hz"] == pytest.approx(20.0, abs=0.1)
        assert sweeps[0]["f_stop_hz"] == pytest.approx(60.0, abs=0.1)


def test_mat_sample_rate_variable_is_used(tmp_path: Path) -> None:
    import scipy.io
    rec = Generator(RigSpec(), Sensors(seed=6)).run([Dwell(25.0, 20e-6, "x", 0.4)])
    path = tmp_path / "m.mat"
    scipy.io.savemat(path, {"fx_N": rec.columns["fx_N"], "x_m": rec.columns["x_m"],
                            "freq_hz": rec.columns["freq_hz"], "Fs": 5000.0})
    out = tmp_path / "m.h5"
    assert main(["import", str(path), "--out", str(out), "--lubricated"]) == 0
    with open_run(out) as run:
        assert run.sample_rate_hz == 5000.0
    assert main(["import", str(path), "--out", str(tmp_path / "n.h5"), "--fs", "4000"]) == 2


@pytest.fixture(scope="module")
def sealed_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Lubricated X dwells with the report's 26 N seal (solve_ivp path, about 90 s)."""
    rec = Generator(RigSpec(seal_friction_n=26.0), Sensors(seed=31)).run(
        grid(FREQS, [25e-6, 38e-6], "x", record_s=0.3))
    return rec.to_csv(tmp_path_factory.mktemp("seal") / "seal.csv")


def _identify(csv: Path, tmp_path: Path, seal: str) -> dict:
    out = tmp_path / f"seal-{seal}.h5"
    assert main(["import", str(csv), "--out", str(out), "--lubricated", "--seal", seal]) == 0
    report = tmp_path / f"seal-{seal}.json"
    assert main(["identify", str(out), "--json", str(report)]) == 0
    return json.loads(report.read_text())["lubricated"]


@pytest.mark.slow
def test_unknown_seal_friction_is_fitted_and_said(sealed_csv: Path, tmp_path: Path) -> None:
    lub = _identify(sealed_csv, tmp_path, "unknown")
    assert lub["seal_friction_N"] == pytest.approx(26.0, rel=0.10)
    assert "fitted to 10 lubricated dwells" in lub["seal_friction_source"]
    truth_c = RigSpec().film_damping_ns_per_m
    for g in lub["sfd_damping_by_amplitude"]:
        assert g["eq9"]["C_sfd_mean_Ns_per_m"] == pytest.approx(truth_c, rel=0.05)


@pytest.mark.slow
def test_stated_seal_friction_is_used(sealed_csv: Path, tmp_path: Path) -> None:
    lub = _identify(sealed_csv, tmp_path, "26")
    assert lub["seal_friction_N"] == 26.0
    truth_c = RigSpec().film_damping_ns_per_m
    for g in lub["sfd_damping_by_amplitude"]:  # the stick-slip removal of the seal
        assert g["stick_slip"]["C_sfd_mean_Ns_per_m"] == pytest.approx(truth_c, rel=0.02)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="finding: with the 26 N seal sticking part of each cycle, "
                   "the stick-slip K at 25 um is 844 +/- 39 kN/m (truth 788): 7 % high, outside "
                   "its stated uncertainty (38 um: 811 +/- 45)")
def test_sealed_stiffness_within_its_uncertainty(sealed_csv: Path, tmp_path: Path) -> None:
    lub = _identify(sealed_csv, tmp_path, "26")
    fits = [f for f in lub["table6_and_appendix_E"] if f["method"] == "stick_slip"]
    assert len(fits) == 2
    for f in fits:
        assert abs(f["k_n_per_m"] - 788e3) <= f["u_k_n_per_m"]


def test_velocity_only_response_is_accepted(tmp_path: Path) -> None:
    rec = Generator(RigSpec(), Sensors(noise={})).run(grid([30.0, 50.0], [20e-6], "y", 0.3))
    t = rec.columns["time_s"]
    vy = np.concatenate([seg.v(t[seg.first_sample:seg.last_sample])[1] for seg in rec.segments])
    data = rec.to_csv(tmp_path / "vel.csv", columns=("time_s", "freq_hz", "fy_N"),
                      extra={"vy_mps": vy})
    out = tmp_path / "vel.h5"
    assert main(["import", str(data), "--out", str(out), "--dry", "--motion", "y"]) == 0
    with open_run(out) as run:
        assert "vy" in run.channel_names and "y" in run.channel_names
        for st, seg in zip(run.steps, rec.segments, strict=True):
            y = run.signal("y", st["first_sample"], st["last_sample"])
            truth = seg.z(run.time_s(st["first_sample"], st["last_sample"]))[1]
            assert np.max(np.abs(y - truth)) < 1e-3 * 20e-6  # noise-free: printing precision


def test_batch_import_into_a_folder_with_one_conditions_file(tmp_path: Path, capsys) -> None:
    data = tmp_path / "old"
    data.mkdir()
    for k, f in enumerate((20.0, 40.0)):
        Generator(RigSpec(), Sensors(seed=k)).run([Dwell(f, 25e-6, "y", 0.3)]).to_csv(
            data / f"run{k}.csv")
    (data / "conditions.toml").write_text('lubricated = true\nseal = "none"\n')
    (data / "bad.csv").write_text("fx_N,x_m\n1,2e-6\n")  # no time base: refused, others kept
    out = tmp_path / "runs"
    out.mkdir()
    rc = main(["import", *(str(p) for p in sorted(data.glob("*.csv"))), "--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.csv" in err[0]
    assert sorted(p.name for p in out.iterdir()) == ["run0.h5", "run1.h5"]
    for name in ("run0.h5", "run1.h5"):
        with open_run(out / name) as run:
            assert bool(run.attrs["lubricated"]) and run.steps[0]["motion"] == "y"
