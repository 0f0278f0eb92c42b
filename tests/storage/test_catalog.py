"""Run catalog and the `sfdrig runs` / `sfdrig import` commands."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from sfdrig.cli import main
from storage import RunWriter
from storage.catalog import STALE_AFTER_S, format_table, scan_runs
from storage.records import StepRecord


def _run(path: Path, run_id: str, kind: str, start: str, n: int, steps: int,
         status: str | None = "completed", reason: str = "") -> RunWriter:
    w = RunWriter.create(path, run_id, kind, ["fx", "x1"], ["shaker_x"], 1000.0,
                         start_time=start, flush_interval_s=0)
    w.on_block(0, np.zeros((2, n)), np.zeros((1, n)))
    for i in range(steps):
        w.on_step(StepRecord.from_wire({"index": i, "freq_hz": 10.0 * (i + 1)}))
    if status is not None:
        w.close(status, reason)
    return w


@pytest.fixture
def runs_dir(tmp_path: Path) -> Path:
    d = tmp_path / "runs"
    (d / "2026-01").mkdir(parents=True)
    _run(d / "b.h5", "sweep-b", "sweep", "2026-01-02T10:00:00.000+00:00", 2500, 3)
    _run(d / "2026-01" / "a.h5", "static-a", "static", "2026-01-01T09:00:00.000+00:00", 500, 0,
         "aborted", "operator")
    killed = _run(d / "c.h5", "sweep-c", "sweep", "2026-01-03T08:00:00.000+00:00", 100, 1, None)
    killed._file.close()  # the writer vanished without closing the run (as after kill -9)
    killed._closed = True
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    with h5py.File(d / "c.h5", "r+") as f:  # the writer's process is gone
        f.attrs["writer_pid"] = int(dead.stdout)
    old = time.time() - 2 * STALE_AFTER_S
    os.utime(d / "c.h5", (old, old))
    (d / "junk.h5").write_text("not hdf5")
    (d / "readme.txt").write_text("ignored")
    (d / ".x.h5.abc.tmp").write_text("import in progress")
    return d


def test_scan_rows(runs_dir: Path) -> None:
    rows = scan_runs(runs_dir)
    got = [(r.id, r.kind, r.steps, r.status, r.duration_s, Path(r.file).name) for r in rows]
    assert got == [
        ("static-a", "static", 0, "aborted", 0.5, "a.h5"),
        ("sweep-b", "sweep", 3, "completed", 2.5, "b.h5"),
        ("sweep-c", "sweep", 1, "interrupted", 0.1, "c.h5"),
        ("", "", 0, "unreadable", 0.0, "junk.h5"),
    ]
    assert rows[0].date == "2026-01-01T09:00:00.000+00:00"
    assert "junk.h5: not an HDF5 file" in rows[3].error
    table = format_table(rows)
    assert table.splitlines()[0].split() == ["id", "date", "kind", "steps", "status",
                                             "duration", "conditions", "file"]
    assert "2026-01-02 10:00:00" in table and "unreadable: " in table


def test_live_run_is_running_not_interrupted(tmp_path: Path) -> None:
    w = _run(tmp_path / "live.h5", "live", "sweep", "2026-01-01T00:00:00.000+00:00", 10, 0, None)
    try:
        assert [r.status for r in scan_runs(tmp_path)] == ["running"]
    finally:
        w.close()
    assert [r.status for r in scan_runs(tmp_path)] == ["completed"]


def test_runs_command_json_and_env(runs_dir: Path, monkeypatch, capsys) -> None:
    assert main(["runs", "--runs-dir", str(runs_dir), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["id"] for r in rows] == ["static-a", "sweep-b", "sweep-c", ""]
    assert set(rows[0]) == {"id", "date", "kind", "steps", "status", "duration_s", "file",
                            "error", "lubricated", "seal", "motion", "stop_time", "n_samples",
                            "status_reason"}
    monkeypatch.setenv("SFDRIG_RUNS_DIR", str(runs_dir))
    assert main(["runs"]) == 0
    out = capsys.readouterr().out
    assert "sweep-b" in out and "interrupted" in out
    monkeypatch.delenv("SFDRIG_RUNS_DIR")
    monkeypatch.chdir(runs_dir)
    (runs_dir / "runs").mkdir()
    assert main(["runs"]) == 0
    assert "no run files in runs" in capsys.readouterr().out


def test_runs_command_missing_dir(tmp_path: Path, capsys) -> None:
    assert main(["runs", "--dir", str(tmp_path / "nope")]) == 2
    assert "runs directory does not exist" in capsys.readouterr().err


def test_import_command_reports_errors(tmp_path: Path, capsys) -> None:
    src = tmp_path / "m.csv"
    src.write_text("a,b\n1,2\n1,x\n")
    out = tmp_path / "m.h5"
    assert main(["import", str(src), "--out", str(out), "--map", "fx_N=a", "--map", "x_m=b",
                 "--fs", "10"]) == 2
    assert "line 3, column 'b': 'x' is not a number" in capsys.readouterr().err
    assert main(["import", str(src), "--out", str(out), "--map", "fx=a"]) == 2
    assert "'fx' is not a canonical name" in capsys.readouterr().err
    assert not out.exists()
    src.write_text("a,b\n1,2\n1,3\n")
    assert main(["import", str(src), "--out", str(out), "--map", "fx_N=a", "--map", "x_m=b",
                 "--fs", "10", "--notes", "rig B", "--scale", "x_m=1e-6", "--no-steps"]) == 0
    assert "2 samples at 10 Hz" in capsys.readouterr().out
