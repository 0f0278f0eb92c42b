"""The inputs that once ended in a traceback (issue 9) now end in one line or work."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from sfdrig.cli import main
from storage import RunWriter, open_run
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


# --- a newcomer's first import (issue 39) -------------------------------------------------------
def _columns(src: Path, dst: Path, names: dict[str, str], rows: slice | None = None,
             freq: float | None = None) -> Path:
    """``dst``: the columns ``names`` (source -> new name) of CSV ``src``, optionally only the
    rows at excitation frequency ``freq``."""
    data = np.genfromtxt(src, delimiter=",", names=True)
    if freq is not None:
        data = data[data["freq_hz"] == freq]
    with open(dst, "w") as fh:
        fh.write(",".join(names.values()) + "\n")
        np.savetxt(fh, np.column_stack([data[k] for k in names]), delimiter=",", fmt="%.9g")
    return dst


def test_import_refuses_data_it_cannot_make_steps_of(lub_csv: Path, tmp_path: Path,
                                                      capsys) -> None:
    """No frequency or step column: refused (once "0 steps", exit 0), naming the column and the
    ways to give it; --freq-hz gives it; --no-steps imports the record without steps, which
    identify refuses in one line."""
    src = _columns(lub_csv, tmp_path / "data.csv", {"fx_N": "F1", "x_m": "X1"}, freq=40.0)
    out = tmp_path / "run.h5"
    args = ["import", str(src), "--map", "fx_N=F1", "--map", "x_m=X1", "--fs", "5000",
            "--lubricated", "--seal", "none", "--out", str(out)]
    assert main(args) == 2
    line = _one_error_line(capsys, "data.csv", "no frequency column (freq_hz)",
                           "--map freq_hz=COLUMN", "--freq-hz HZ", "--no-steps")
    assert capsys.readouterr().out == "" and line.startswith("error: ")
    assert not out.exists()

    assert main([*args, "--freq-hz", "40"]) == 0
    said = capsys.readouterr().out
    with open_run(out) as run:
        assert len(run.steps) >= 1 and {s["freq_hz"] for s in run.steps} == {40.0}
        assert run.test_spec["freq_source"] == "--freq-hz 40"
    assert len(run.steps) == 1 and ", 1 step\n" in said  # (once "1 steps")

    assert main([*args, "--no-steps", "--freq-hz", "40", "--overwrite"]) == 2
    _one_error_line(capsys, "--no-steps and --freq-hz contradict each other")
    assert main([*args, "--no-steps", "--overwrite"]) == 0
    said = capsys.readouterr().out
    assert ", 0 steps" in said
    assert "\n  no steps: sfdrig diagnose judges the record in blocks" in said
    assert main(["identify", str(out), "--no-store"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1, captured.err
    assert captured.err.startswith("error: run.h5: no steps (dwells) to identify")
    assert "--freq-hz" in captured.err

    assert main(["import", str(lub_csv), "--freq-hz", "40", "--out", str(tmp_path / "b.h5"),
                 "--lubricated"]) == 2
    _one_error_line(capsys, "lub.csv", "--freq-hz 40: the file has a freq_hz column")


def test_identify_refuses_a_recorded_run_without_steps(tmp_path: Path, capsys) -> None:
    """A sweep aborted before its first step: one line naming the run, its kind and status (no
    advice on importing: it was never imported)."""
    w = RunWriter.create(tmp_path / "empty.h5", "e-1", "sweep",
                         [{"name": "fx", "units": "N", "kind": "load_cell"}], [], 1000.0,
                         swmr=False, flush_interval_s=0)
    w.on_block(0, np.zeros((1, 100)), None)
    w.close("aborted", "operator pressed abort")
    assert main(["identify", str(tmp_path / "empty.h5"), "--no-store"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == (
        "error: empty.h5: no steps (dwells) to identify: the runs recorded none (empty.h5: "
        "sweep, aborted)\n")


def test_identify_says_each_cause_once(lub_csv: Path, tmp_path: Path, capsys) -> None:
    """A run with fx and x only: one line for the five signals it lacks in its three dwells
    (once fifteen lines)."""
    src = _columns(lub_csv, tmp_path / "fx_x.csv",
                   {"time_s": "time_s", "freq_hz": "freq_hz", "fx_N": "fx_N", "x_m": "x_m"})
    out = tmp_path / "fx_x.h5"
    assert main(["import", str(src), "--out", str(out), "--lubricated", "--seal", "none"]) == 0
    capsys.readouterr()
    assert main(["identify", str(out), "--no-store"]) == 0
    skipped = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("skipped:")]
    assert len(skipped) == 1, skipped
    assert "channels ax, ay, fy, t_oil, y [lubricated]: signal not in the run (channels fx, " \
           "x) (15 items in steps 1-3)" in skipped[0]  # counted from 1


def test_an_aborted_run_is_said_once_as_used(lub_csv: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "ab.h5"
    assert main(["import", str(lub_csv), "--out", str(out), "--lubricated", "--seal",
                 "none"]) == 0
    with h5py.File(out, "r+") as f:
        f.attrs["status"] = "aborted"
        f.attrs["status_reason"] = "operator pressed abort"
        n_steps = len(f["steps"])
    capsys.readouterr()
    assert main(["identify", str(out), "--no-store", "--json", str(tmp_path / "i.json")]) == 0
    err = capsys.readouterr().err
    said = [ln for ln in err.splitlines() if "aborted" in ln]
    assert said == [f"note: run {json.loads((tmp_path / 'i.json').read_text())['runs'][0]['label']}"
                    f": aborted (operator pressed abort); the {n_steps} step(s) it recorded are "
                    "analysed"], err
    assert not [ln for ln in err.splitlines() if ln.startswith("skipped:")], err


@pytest.mark.parametrize("command", ["identify", "diagnose"])
def test_a_defect_is_exit_70(lub_csv: Path, tmp_path: Path, capsys, monkeypatch,
                             command: str) -> None:
    """An error no command expected is named as a defect (exit 70, the traceback in a file), not
    passed off as bad input (once "error: run.h5: KeyError: 'parameters'", exit 2)."""
    out = tmp_path / "run.h5"
    assert main(["import", str(lub_csv), "--out", str(out), "--lubricated", "--seal",
                 "none"]) == 0
    capsys.readouterr()

    def defect(*args, **kwargs):
        raise KeyError("parameters")

    if command == "identify":
        monkeypatch.setattr("sfdrig.commands.identify.identify", defect)
    else:
        monkeypatch.setattr("analysis.diagnose.diagnose", defect)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert main([command, str(out), "--quiet"] if command == "diagnose"
                else [command, str(out)]) == 70
    _one_error_line(capsys, f"sfdrig {command}: unexpected error: KeyError",
                    "a defect: please report it with")
    assert "Traceback" in next(tmp_path.glob(f"sfdrig-{command}-*.traceback")).read_text()
