"""The run index (`storage.run_index`) behind `sfdrig runs` and the page's history: it matches
the files, notices every file added, deleted or changed (reading only those), is made again
when damaged, is kept by the run writer, is shared with a writing process, and filters and
pages as the catalog's filters say."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

import storage.run_index as run_index
from sfdrig.cli import main
from storage import RunWriter
from storage.catalog import INDEX_NAME, parse_filter, read_row, scan_runs, select_runs
from storage.records import StepRecord

HOUR_NS = 3600 * 10**9


def _run(path: Path, run_id: str, kind: str, start: str, *, status: str = "completed",
         lubricated: bool = False, seal_n: float | None = None, motion: str = "x",
         steps: int = 2) -> None:
    rig = None if seal_n is None else {"seal": {"enabled": seal_n > 0,
                                                "friction_force_n": seal_n}}
    w = RunWriter.create(path, run_id, kind, ["fx", "x"], ["shaker_x"], 1000.0,
                         start_time=start, flush_interval_s=0, lubricated=lubricated,
                         rig_config=rig, test_spec={"motion": motion})
    w.on_block(0, np.zeros((2, 100 * steps)), np.zeros((1, 100 * steps)))
    for i in range(steps):
        w.on_step(StepRecord.from_wire({"index": i, "freq_hz": 20.0 + i, "motion": motion,
                                        "first_sample": 100 * i, "last_sample": 100 * (i + 1)}))
    w.close(status, "" if status == "completed" else "test")


def _age(path: Path, hours: float = 1.0) -> None:
    """The file last changed ``hours`` ago (older than the index's racy window)."""
    st = path.stat()
    t = st.st_mtime_ns - int(hours * HOUR_NS)
    os.utime(path, ns=(t, t))


@pytest.fixture
def lab(tmp_path: Path) -> Path:
    """Six runs over three days: sweeps, a static test, an import; dry and lubricated, three
    seals, x, y and circular."""
    d = tmp_path / "runs"
    d.mkdir()
    _run(d / "a.h5", "A", "sweep", "2026-03-01T08:00:00.000Z", lubricated=True, seal_n=0.0)
    _run(d / "b.h5", "B", "sweep", "2026-03-01T12:00:00.000Z", status="aborted", seal_n=26.0,
         motion="y")
    _run(d / "c.h5", "C", "static", "2026-03-02T09:00:00.000Z", steps=0, motion="x")
    _run(d / "d.h5", "D", "sweep", "2026-03-02T23:30:00.000+00:00", lubricated=True,
         seal_n=26.0, motion="circular_forward")
    _run(d / "e.h5", "E", "imported", "2026-03-03T10:00:00.000Z", status="failed",
         lubricated=True)
    _run(d / "f.h5", "F", "sweep", "2026-03-03T11:00:00.000Z", seal_n=0.0)
    for p in d.glob("*.h5"):
        _age(p)
    return d


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the run files the index reads (their headers opened)."""
    seen: list[str] = []

    def counted(path: Path, now: float | None = None):  # type: ignore[no-untyped-def]
        seen.append(path.name)
        return read_row(path, now)

    monkeypatch.setattr(run_index, "read_row", counted)
    return seen


def _truth(d: Path) -> list[tuple[object, ...]]:
    """What the files themselves say, every header read."""
    rows = [read_row(p) for p in sorted(d.rglob("*.h5")) if not p.name.startswith(".")]
    return sorted((r.id, r.date, r.kind, r.steps, r.status, r.duration_s, r.lubricated,
                   r.seal, r.motion, r.file) for r in rows)


def _got(d: Path) -> list[tuple[object, ...]]:
    return sorted((r.id, r.date, r.kind, r.steps, r.status, r.duration_s, r.lubricated,
                   r.seal, r.motion, r.file) for r in scan_runs(d))


def test_the_index_matches_the_files_and_a_second_look_reads_none(lab: Path,
                                                                  reads: list[str]) -> None:
    assert _got(lab) == _truth(lab)
    assert sorted(reads) == ["a.h5", "b.h5", "c.h5", "d.h5", "e.h5", "f.h5"]
    assert (lab / INDEX_NAME).is_file()
    rows = {r.id: r for r in scan_runs(lab)}
    assert len(reads) == 6  # the second look read none
    assert (rows["A"].lubricated, rows["A"].seal, rows["A"].motion) == (True, "none", "x")
    assert (rows["B"].status, rows["B"].seal, rows["B"].motion) == ("aborted", "26.0", "y")
    assert (rows["C"].steps, rows["C"].motion, rows["E"].seal) == (0, "x", "")
    assert rows["D"].duration_s == 0.2


def test_added_deleted_and_changed_files_are_noticed(lab: Path, reads: list[str]) -> None:
    scan_runs(lab)
    reads.clear()
    (lab / "a.h5").unlink()
    _run(lab / "g.h5", "G", "flow", "2026-03-04T10:00:00.000Z")  # a writer with an index:
    with h5py.File(lab / "b.h5", "r+") as f:                       # its row is in already
        f.attrs["status"] = "completed"
    _age(lab / "b.h5", 0.5)  # changed, its time stamp older than the racy window
    sub = lab / "2026-03"
    sub.mkdir()
    (lab / "f.h5").rename(sub / "f.h5")  # moved into a subfolder
    assert _got(lab) == _truth(lab)
    assert sorted(reads[:2]) == ["b.h5", "f.h5"]  # and not a, c, d, e, g
    ids = {r.id: r for r in scan_runs(lab)}
    assert "A" not in ids and ids["B"].status == "completed" and ids["G"].kind == "flow"
    assert [r.id for r in scan_runs(lab, recursive=False)] == ["B", "C", "D", "E", "G"]


def test_a_change_inside_the_same_time_stamp_is_still_noticed(tmp_path: Path,
                                                              reads: list[str]) -> None:
    """A row read right after its file changed is not trusted until read once more: a change
    a moment later may keep the same size and time stamp on a coarse file-system clock (here
    the file is replaced by another run of the same size, its time stamp kept)."""
    _run(tmp_path / "r.h5", "R1", "sweep", "2026-03-01T08:00:00.000Z", status="aborted")
    _run(tmp_path / ".s.h5", "R2", "sweep", "2026-03-01T08:00:00.000Z", status="aborted")
    assert [r.id for r in scan_runs(tmp_path)] == ["R1"]
    st = (tmp_path / "r.h5").stat()
    assert (tmp_path / ".s.h5").stat().st_size == st.st_size
    os.utime(tmp_path / ".s.h5", ns=(st.st_atime_ns, st.st_mtime_ns))
    os.replace(tmp_path / ".s.h5", tmp_path / "r.h5")
    reads.clear()
    assert [r.id for r in scan_runs(tmp_path)] == ["R2"]
    assert reads == ["r.h5"]
    _age(tmp_path / "r.h5")
    scan_runs(tmp_path)
    reads.clear()
    scan_runs(tmp_path)
    assert reads == []  # old enough: trusted while its size and time stamp stay


def test_the_writer_records_its_run_when_it_starts_and_ends(tmp_path: Path,
                                                            reads: list[str]) -> None:
    assert scan_runs(tmp_path) == []  # the directory now has an index
    w = RunWriter.create(tmp_path / "live.h5", "LIVE", "sweep", ["fx", "x"], ["shaker_x"],
                         1000.0, start_time="2026-03-05T10:00:00.000Z", flush_interval_s=0,
                         lubricated=True, test_spec={"motion": "y"})
    with sqlite3.connect(tmp_path / INDEX_NAME) as db:
        assert db.execute("SELECT id, status, lubricated, motion FROM runs").fetchall() == [
            ("LIVE", "running", 1, "y")]
    w.on_block(0, np.zeros((2, 500)), np.zeros((1, 500)))
    w.on_step(StepRecord.from_wire({"index": 0, "freq_hz": 30.0, "motion": "y", "first_sample": 0,
               "last_sample": 500}))
    w.close("aborted", "operator")
    rows = scan_runs(tmp_path)
    assert reads == []  # the writer's row at the end: no file read
    assert [(r.id, r.status, r.steps, r.duration_s, r.motion) for r in rows] == [
        ("LIVE", "aborted", 1, 0.5, "y")]
    assert _got(tmp_path) == _truth(tmp_path)


def test_a_run_written_without_an_index_entry_is_picked_up(lab: Path, tmp_path: Path) -> None:
    """Runs written by an older version (or elsewhere, then copied in) have no row."""
    scan_runs(lab)
    other = tmp_path / "other"
    other.mkdir()
    _run(other / "old.h5", "OLD", "sweep", "2025-12-31T10:00:00.000Z")
    assert not (other / INDEX_NAME).exists()  # no index there: the writer made none
    os.replace(other / "old.h5", lab / "old.h5")
    assert [r.id for r in scan_runs(lab)][0] == "OLD"


@pytest.mark.parametrize("damage", [b"garbage, not a database" * 100, b""])
def test_a_damaged_index_is_made_again_with_a_one_line_notice(lab: Path, damage: bytes) -> None:
    scan_runs(lab)
    (lab / INDEX_NAME).write_bytes(damage)
    notices: list[str] = []
    assert _got(lab) == _truth(lab)  # (an empty file is a fresh database to SQLite)
    scan_runs(lab, notice=notices.append)
    if damage:
        (lab / INDEX_NAME).write_bytes(damage)
        scan_runs(lab, notice=notices.append)
        assert len(notices) == 1 and "\n" not in notices[0]
        assert notices[0].startswith(f"run index {lab / INDEX_NAME} is not a database")
        assert notices[0].endswith("deleted, made again from the run files")
    else:
        assert notices == []
    with sqlite3.connect(lab / INDEX_NAME) as db:
        assert db.execute("SELECT count(*) FROM runs").fetchone() == (6,)


def test_an_index_of_another_layout_is_made_again(lab: Path) -> None:
    scan_runs(lab)
    with sqlite3.connect(lab / INDEX_NAME) as db:
        db.execute("UPDATE meta SET value = '0' WHERE key = 'schema'")
        db.execute("DELETE FROM runs")
    notices: list[str] = []
    assert len(scan_runs(lab, notice=notices.append)) == 6
    assert notices == [f"run index {lab / INDEX_NAME} has layout '0', not "
                       f"'{run_index.SCHEMA}': deleted, made again from the run files"]


def test_an_index_that_cannot_be_written_leaves_the_files_listed(lab: Path) -> None:
    (lab / INDEX_NAME).mkdir()  # in its place: nothing SQLite can open
    notices: list[str] = []
    assert _got(lab) == _truth(lab)
    scan_runs(lab, notice=notices.append)
    assert len(notices) == 1 and "every run file is read at each look" in notices[0]


def test_a_writing_process_and_a_reading_one_share_the_index(tmp_path: Path) -> None:
    """A real second process writes 12 runs while this one looks again and again: every look
    succeeds, and the last one holds every run as its file says."""
    scan_runs(tmp_path)
    script = textwrap.dedent(f"""
        import numpy as np
        from storage import RunWriter
        for i in range(12):
            w = RunWriter.create({str(tmp_path)!r} + f"/w{{i:02d}}.h5", f"W{{i:02d}}",
                                 "sweep", ["fx", "x"], ["shaker_x"], 1000.0,
                                 flush_interval_s=0)
            w.on_block(0, np.zeros((2, 100)), np.zeros((1, 100)))
            w.close("completed")
    """)
    writer = subprocess.Popen([sys.executable, "-c", script])
    looks = 0
    try:
        while writer.poll() is None:
            rows = scan_runs(tmp_path)
            # (a file being created, or its end written, is locked by HDF5 for a moment: a
            # look then sees it unreadable, and reads it again at the next)
            assert {r.status for r in rows} <= {"running", "completed", "unreadable"}, rows
            looks += 1
    finally:
        writer.wait()
    assert writer.returncode == 0 and looks >= 1
    assert [(r.id, r.status) for r in sorted(scan_runs(tmp_path), key=lambda r: r.id)] == [
        (f"W{i:02d}", "completed") for i in range(12)]
    assert _got(tmp_path) == _truth(tmp_path)


@pytest.mark.parametrize(("query", "ids", "total"), [
    ({}, ["A", "B", "C", "D", "E", "F"], 6),
    ({"kind": "sweep"}, ["A", "B", "D", "F"], 4),
    ({"kind": "static,imported"}, ["C", "E"], 2),
    ({"status": "aborted,failed"}, ["B", "E"], 2),
    ({"since": "2026-03-02"}, ["C", "D", "E", "F"], 4),
    ({"until": "2026-03-02"}, ["A", "B", "C", "D"], 4),  # through that day
    ({"since": "2026-03-01T10:00", "until": "2026-03-02T23:30:00+00:00"}, ["B", "C"], 2),
    ({"since": "2026-03-02T01:00+02:00"}, ["C", "D", "E", "F"], 4),  # 23:00 UTC the day before
    ({"lubricated": "yes"}, ["A", "D", "E"], 3),
    ({"lubricated": "no", "kind": "sweep"}, ["B", "F"], 2),
    ({"seal": "none"}, ["A", "F"], 2),
    ({"seal": "sealed"}, ["B", "D"], 2),
    ({"seal": "26"}, ["B", "D"], 2),
    ({"seal": "unstated"}, ["C", "E"], 2),
    ({"motion": "circular_forward"}, ["D"], 1),
    ({"motion": "x", "lubricated": "yes", "seal": "none"}, ["A"], 1),
    ({"limit": "2"}, ["A", "B"], 6),
    ({"limit": "2", "offset": "4"}, ["E", "F"], 6),
    ({"offset": "5"}, ["F"], 6),
    ({"kind": "sweep", "limit": "3", "offset": "3"}, ["F"], 4),
])
def test_filters_and_pages(lab: Path, query: dict[str, str], ids: list[str],
                           total: int) -> None:
    page = select_runs(lab, parse_filter(query))
    assert ([r.id for r in page.rows], page.total) == (ids, total)
    newest = select_runs(lab, parse_filter(query, newest_first=True))
    if "limit" not in query and "offset" not in query:
        assert [r.id for r in newest.rows] == ids[::-1]


@pytest.mark.parametrize(("query", "message"), [
    ({"kind": "swep"}, "kind='swep' is not one of sweep, static, impact, probe_calibration, "
                       "flow, imported, commissioning (did you mean 'sweep'?)"),
    ({"status": "done"}, "status='done' is not one of running, completed, aborted, failed, "
                         "interrupted, unreadable"),
    ({"since": "last week"}, "since='last week' is not an ISO 8601 date or time (e.g. "
                             "2026-03-01 or 2026-03-01T08:00)"),
    ({"until": "2026-13-01"}, "until='2026-13-01' is not an ISO 8601 date or time"),
    ({"lubricated": "maybe"}, "lubricated='maybe': yes or no"),
    ({"seal": "-3"}, "seal='-3': none, sealed, unknown, unstated, or the seal's friction "
                     "force F_mu in N"),
    ({"seal": "nan"}, "seal='nan': none"),
    ({"motion": "x,y"}, "motion='x,y': one of x, y, circular_forward"),
    ({"motion": "z"}, "motion='z' is not one of x, y"),
    ({"limit": "0"}, "limit='0': a whole number above 0"),
    ({"offset": "-1"}, "offset='-1': a whole number (0 or more)"),
    ({"knd": "sweep"}, "unknown filter 'knd': did you mean 'kind'? the filters are kind, "
                       "status, since"),
])
def test_bad_filters_are_refused_in_one_line(query: dict[str, str], message: str) -> None:
    with pytest.raises(ValueError) as err:
        parse_filter(query)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_the_runs_command_filters_and_pages(lab: Path, capsys: pytest.CaptureFixture[str]
                                            ) -> None:
    assert main(["runs", "--runs-dir", str(lab), "--kind", "sweep", "--lubricated",
                 "--limit", "1"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["id", "date", "kind", "steps", "status", "duration",
                              "conditions", "file"]
    assert out[1].split()[:8] == ["A", "2026-03-01", "08:00:00", "sweep", "2", "completed",
                                  "0.2", "s"]
    assert "lubricated x no seal" in out[1]
    assert out[2:] == ["rows 1-1 of 2 (--offset 1 for the next)"]
    assert main(["runs", "--runs-dir", str(lab), "--seal", "26", "--dry", "--json"]) == 0
    assert '"id": "B"' in capsys.readouterr().out
    assert main(["runs", "--runs-dir", str(lab), "--motion", "elliptical"]) == 0
    assert capsys.readouterr().out == f"no runs in {lab} match\n"
    assert main(["runs", "--runs-dir", str(lab), "--since", "tomorrow"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: sfdrig runs: since='tomorrow' is not an ISO 8601 date")
    assert err.count("\n") == 1


def test_the_runs_command_says_in_one_line_that_it_made_a_damaged_index_again(
        lab: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scan_runs(lab)
    (lab / INDEX_NAME).write_bytes(b"\x00" * 4096)
    assert main(["runs", "--runs-dir", str(lab), "--json"]) == 0
    captured = capsys.readouterr()
    assert len(captured.out.split('"id"')) == 7  # six runs
    assert captured.err == (f"run index {lab / INDEX_NAME} is not a database this version "
                            "reads (file is not a database): deleted, made again from the run "
                            "files\n")
