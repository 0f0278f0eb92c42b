"""The inputs that once ended in a traceback (issue 9) now end in one line or work."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sfdrig.cli import main
from tests.independent_rig import Generator, RigSpec, Sensors, grid


@pytest.fixture(scope="module")
def lub_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rec = Generator(RigSpec(), Sensors(seed=21)).run(grid([20.0, 40.0, 60.0], [25e-6], "x"))
    return rec.to_csv(tmp_path_factory.mktemp("d") / "lub.csv")


def _one_error_line(capsys: pytest.CaptureFixture[str], *must: str) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err, "no error message"
    assert "Traceback" not in "\n".join(err)
    for word in must:
        assert word in err[-1], err[-1]
    return err[-1]


def test_driving_point_accelerometer_mapped_as_displacement(lub_csv: Path, tmp_path: Path,
                                                           capsys) -> None:
    out = tmp_path / "dp.h5"
    assert main(["import", str(lub_csv), "--map", "x_m=ax_mps2", "--out", str(out),
                 "--lubricated"]) == 2
    line = _one_error_line(capsys, "lub.csv", "ax_mps2", "x_m spans")
    assert "--scale" in line
    assert not out.exists()


def test_train_and_test_halves_of_one_record(lub_csv: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "lub.h5"
    assert main(["import", str(lub_csv), "--out", str(out), "--lubricated", "--seal",
                 "none"]) == 0
    capsys.readouterr()
    rc = main(["diagnose", str(out), "--train", "0:3750", "--test", "3750:7500", "--quiet",
               "--json", str(tmp_path / "d.json")])
    # the two halves of one record work (once a traceback): one segment fitted, one held out
    assert rc == 0, capsys.readouterr().err
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["segments"] == {"train": 1, "test": 1}
    assert doc["train_runs"] == doc["test_runs"] == ["lub.h5"]


@pytest.mark.needs_shared
def test_emps_with_a_fitted_baseline(shared_dir: Path, tmp_path: Path, capsys) -> None:
    """EMPS (a drive with no spring) cannot start the fitted baseline: refused in one line
    naming the file and why (once a traceback), exit 2."""
    out = tmp_path / "emps.h5"
    emps = shared_dir / "data" / "emps" / "DATA_EMPS.mat"  # read in place
    assert main(["import", str(emps), "--map", "time_s=t", "--map", "fx_N=vir", "--scale",
                 "fx_N=35.15065188", "--map", "x_m=qm", "--out", str(out), "--dry",
                 "--no-steps"]) == 0
    capsys.readouterr()
    rc = main(["diagnose", str(out), "--baseline", "fitted", "--quiet"])
    assert rc == 2
    _one_error_line(capsys, "emps.h5", "fitted baseline", "second-order")
