"""Trips, e-stops, watchdogs and interrupted runs across runs, read from run files written here
with `storage.RunWriter` (`web.trips`, `/api/trips`): what, when, where and the peak in numbers,
the filters, the CSV export, and the refusals of bad parameters (raw HTTP)."""

from __future__ import annotations

import asyncio
import csv
import io
import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from aiohttp.test_utils import TestServer

from storage import RunWriter
from storage.records import StepRecord
from tests.web.test_server_security import _Daemon, _get, _raw
from web.server import WebApp, WebConfig
from web.trips import incident_of, where_of

FS = 1000.0
N_STEP = 500  # samples per recorded step
NAMES = ["fx", "fy", "x1", "x2", "y1", "y2"]


def _run(path: Path, run_id: str, day_time: str, steps: int,
         events: list[tuple[str, str, int]], status: str | None,
         spike: tuple[int, float, float] | None = None) -> None:
    """A sweep at 50, 60, 70 Hz of which ``steps`` were recorded (plus half a step more), its
    ``events`` (kind, message, sample) stamped ``day_time`` (+ 1 s each) and ``status``; a
    ``spike`` (sample, orbit [m], load [N]) puts the run's peak there."""
    n = N_STEP * steps + N_STEP // 2
    rng = np.random.default_rng(len(run_id))
    ai = np.zeros((6, n))
    ai[:2] = rng.normal(0, 5.0, (2, n))  # a few N of load
    ai[2:] = rng.normal(0, 1e-6, (4, n))  # a few um of orbit
    if spike is not None:
        k, orbit, load = spike
        ai[2:4, k] = orbit  # x probes: the orbit's radius is the x displacement
        ai[4:6, k] = 0.0
        ai[0, k + 3] = load
    w = RunWriter.create(path, run_id, "sweep", NAMES, ["shaker_x"], FS,
                         start_time=f"2026-11-25T{day_time}.000+00:00", flush_interval_s=0,
                         test_spec={"motion": "x", "load_n": [40.0],
                                    "freq_hz": [50.0, 60.0, 70.0]})
    w.on_block(0, ai, np.zeros((1, n)))
    for i in range(steps):
        w.on_step(StepRecord.from_wire({"index": i, "freq_hz": 50.0 + 10 * i, "target_kind": "load",
                   "target_value": 40.0, "motion": "x", "first_sample": i * N_STEP,
                   "last_sample": (i + 1) * N_STEP, "updates": 2, "converged": True,
                   "harmonics": {"fx": [[40.0, 0.0]] + [[0.0, 0.0]] * 4}}))
    for kind, message, sample in events:
        w.on_event(kind, message, sample)
    if status is None:  # killed: the writer vanished without closing the file
        w._file.close()
        w._closed = True
        dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)
        with h5py.File(path, "r+") as f:
            f.attrs["writer_pid"] = int(dead.stdout)
            f.attrs["stop_time"] = f"2026-11-25T{day_time}.000Z"
    else:
        w.close(status, events[-1][1] if events else "")
    with h5py.File(path, "r+") as f:  # the events' times as on that day
        ev = f["events"][()]
        h, m, s = (int(v) for v in day_time.split(":"))
        for i in range(len(ev)):
            ev["time"][i] = f"2026-11-25T{h:02d}:{m:02d}:{s + i:02d}.000+00:00".encode()
        f["events"][...] = ev


TRIP = "displacement limit: orbit 70.1 um > 63.5 um"
ESTOP = "EmergencyStopError: the emergency stop input reads pressed"
WATCHDOG = "DaqWatchdogExpiredError: the board's watchdog expired (-200678)"


def write_incident_runs(d: Path) -> None:
    """A test day's runs in ``d``: a trip, an e-stop, a watchdog, an operator abort, a completed
    run, a killed one (interrupted) and a file that is not a run."""
    # tripped during the third step (70 Hz), after two were recorded: 70 um and 310 N there
    _run(d / "T1.h5", "T1", "09:00:00", 2, [("limit_trip", TRIP, 1200)], "aborted",
         spike=(1150, 70e-6, 310.0))
    _run(d / "E1.h5", "E1", "10:00:00", 1, [("error", ESTOP, 300)], "failed",
         spike=(290, 20e-6, 120.0))
    _run(d / "W1.h5", "W1", "11:00:00", 1, [("error", WATCHDOG, 700)], "failed")
    _run(d / "A1.h5", "A1", "12:00:00", 1, [("abort", "operator abort from sfdrig web", 600)],
         "aborted")
    _run(d / "C1.h5", "C1", "13:00:00", 2, [], "completed")
    _run(d / "I1.h5", "I1", "14:00:00", 1, [("info", "=cmd|' /C calc'!A0", 100)], None)
    (d / "junk.h5").write_text("not hdf5")


@pytest.fixture
def runs_dir(tmp_path: Path) -> Path:
    d = tmp_path / "runs"
    d.mkdir()
    write_incident_runs(d)
    return d


def _serve(app: WebApp, paths: list[str]) -> list[tuple[int, dict[str, str], bytes]]:
    async def main() -> list[tuple[int, dict[str, str], bytes]]:
        server = TestServer(app.app)
        await server.start_server(**app.runner_options())
        async with server:
            host = f"127.0.0.1:{server.port}"
            return [await _raw(server.port, _get(p, host))  # type: ignore[arg-type]
                    for p in paths]
    return asyncio.run(main())


def test_every_incident_with_when_what_where_and_the_peak(runs_dir):
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir,  # type: ignore[arg-type]
                                      anonymous_role="viewer"))  # viewers read it too
    [(status, _, body)] = _serve(app, ["/api/trips"])
    assert status == 200
    out = json.loads(body)
    got = [(r["run_id"], r["incident"], r["time_utc"][:19], r["where"], r["run_status"])
           for r in out["incidents"]]
    assert got == [  # newest first; the operator's abort and the completed run are not here
        ("I1", "interrupted", "2026-11-25T14:00:00",
         "step 2/3 at 60.0 Hz, 0.749 s into the run", "interrupted"),
        ("W1", "watchdog", "2026-11-25T11:00:00", "step 2/3 at 60.0 Hz, 0.700 s into the run",
         "failed"),
        ("E1", "e-stop", "2026-11-25T10:00:00", "step 1/3 at 50.0 Hz, 0.300 s into the run",
         "failed"),
        ("T1", "trip", "2026-11-25T09:00:00", "step 3/3 at 70.0 Hz, 1.200 s into the run",
         "aborted"),
    ]
    rows = {r["run_id"]: r for r in out["incidents"]}
    assert rows["T1"]["what"] == TRIP and rows["E1"]["what"] == ESTOP
    # the peaks in the second before and 0.2 s after: the spikes put there
    assert rows["T1"]["peak_orbit_um"] == pytest.approx(70.0)
    assert rows["T1"]["peak_load_n"] == pytest.approx(310.0)
    assert rows["E1"]["peak_orbit_um"] == pytest.approx(20.0)
    assert rows["E1"]["peak_load_n"] == pytest.approx(120.0)
    assert rows["W1"]["peak_orbit_um"] < 10.0 and rows["W1"]["peak_load_n"] < 40.0  # noise only
    assert out["total"] == 4 and out["unreadable"] == 0


def test_filtered_and_exported_as_csv(runs_dir):
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]
    trips, since, both, csv_all = _serve(app, [
        "/api/trips?incident=trip", "/api/trips?since=2026-11-25T10:30",
        "/api/trips?incident=e-stop,watchdog&since=2026-11-25",
        "/api/trips?format=csv"])
    assert [r["run_id"] for r in json.loads(trips[2])["incidents"]] == ["T1"]
    assert [r["run_id"] for r in json.loads(since[2])["incidents"]] == ["I1", "W1"]
    assert [r["run_id"] for r in json.loads(both[2])["incidents"]] == ["W1", "E1"]
    status, headers, body = csv_all
    assert status == 200 and headers["content-type"].startswith("text/csv")
    assert 'filename="sfdrig-incidents.csv"' in headers["content-disposition"]
    table = list(csv.reader(io.StringIO(body.decode())))
    assert table[0] == ["time_utc", "run_id", "incident", "what", "where", "run_time_s",
                        "peak_orbit_um", "peak_load_n", "run_status", "file"]
    assert [r[1] for r in table[1:]] == ["I1", "W1", "E1", "T1"]
    trip = table[-1]
    assert trip[3] == TRIP and float(trip[5]) == 1.2 and float(trip[6]) == pytest.approx(70.0)
    assert trip[9] == "T1.h5"


def test_incidents_between_runs_come_from_the_daemons_log(runs_dir):
    """An e-stop pressed and released between runs (in no run file) is in the daemon's
    incident log: listed among the runs' incidents by its time, filtered and exported alike."""
    from datetime import UTC, datetime

    from storage.incident_log import append_incident
    from web.trips import IDLE_WHERE

    for hh_mm, what in (("10:30", "emergency stop pressed while idle (no run)"),
                        ("10:31", "emergency stop released")):
        append_incident(runs_dir, "e-stop", what,
                        when=datetime.fromisoformat(f"2026-11-25T{hh_mm}:00+00:00"))
    append_incident(runs_dir, "watchdog", "the board's watchdog expired while idle",
                    when=datetime(2026, 11, 25, 12, 30, tzinfo=UTC))
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]
    every, estops, csv_all = _serve(app, [
        "/api/trips", "/api/trips?incident=e-stop&since=2026-11-25T10:15", "/api/trips?format=csv"])
    out = json.loads(every[2])
    assert [(r["run_id"], r["incident"], r["time_utc"][11:16]) for r in out["incidents"]] == [
        ("I1", "interrupted", "14:00"), ("", "watchdog", "12:30"), ("W1", "watchdog", "11:00"),
        ("", "e-stop", "10:31"), ("", "e-stop", "10:30"), ("E1", "e-stop", "10:00"),
        ("T1", "trip", "09:00")]
    assert out["total"] == 7 and out["log_lines_skipped"] == 0
    idle = [r for r in out["incidents"] if not r["run_id"]]
    assert all(r["where"] == IDLE_WHERE and r["file"] == "incidents.jsonl"
               and r["peak_orbit_um"] is None for r in idle)
    assert [r["what"] for r in json.loads(estops[2])["incidents"]] == [
        "emergency stop released", "emergency stop pressed while idle (no run)"]
    table = list(csv.reader(io.StringIO(csv_all[2].decode())))
    assert table[4][1:5] == ["", "e-stop", "emergency stop released", IDLE_WHERE]


def test_a_runs_incidents_are_kept_in_the_run_index(runs_dir, monkeypatch):
    """The next web process (a new `RunHistory`) answers the trips table from the run index:
    it opens only the killed run (its file may still change when a daemon closes it) and a run
    whose file changed since; the answer is the same."""
    import os

    import storage.reader
    from web.history import RunHistory

    for p in runs_dir.glob("*.h5"):  # written an hour ago: past the index's racy window
        t = p.stat().st_mtime_ns - 3600 * 10**9
        os.utime(p, ns=(t, t))
    first = RunHistory(runs_dir).trips()
    opened: list[str] = []
    real = storage.reader.open_run

    def counted(path):
        opened.append(Path(path).name)
        return real(path)

    monkeypatch.setattr(storage.reader, "open_run", counted)
    assert RunHistory(runs_dir).trips() == first
    assert opened == ["I1.h5"]
    with h5py.File(runs_dir / "W1.h5", "r+") as f:
        f.attrs["status_reason"] = "the watchdog, as the operator noted"
    t = (runs_dir / "W1.h5").stat().st_mtime_ns - 600 * 10**9
    os.utime(runs_dir / "W1.h5", ns=(t, t))
    opened.clear()
    again = RunHistory(runs_dir).trips()
    assert sorted(opened) == ["I1.h5", "W1.h5"] and again["total"] == first["total"]


def test_bad_parameters_are_refused_with_the_reason(runs_dir):
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]
    none = WebApp(_Daemon(), WebConfig())  # type: ignore[arg-type]
    answers = _serve(app, [
        "/api/trips?incident=bogus", "/api/trips?incident=trip,../../etc",
        "/api/trips?format=xml", "/api/trips?since=yesterday", "/api/trips?since=2026-13-45",
        "/api/trips?path=/etc/passwd", "/api/trips?since=%00"])
    errors = [json.loads(b)["error"] for _, _, b in answers]
    assert [s for s, _, _ in answers] == [400] * 7
    assert errors[0] == ("incident 'bogus' is not one of trip, e-stop, watchdog, contact, "
                         "interrupted, failed (or all)")
    assert errors[1].startswith("incident '../../etc' is not one of")
    assert errors[2] == "format='xml': json or csv"
    assert errors[3].startswith("since='yesterday' is not an ISO 8601 date or time")
    assert errors[4].startswith("since='2026-13-45' is not")
    assert errors[5] == "unknown parameter 'path': incident, since, format"
    [(status, _, body)] = _serve(none, ["/api/trips"])
    assert status == 404 and b"--runs-dir" in body


def test_a_spreadsheet_formula_in_a_message_stays_text():
    from web.trips import to_csv

    text = to_csv([{"time_utc": "t", "run_id": "R", "incident": "failed",
                    "what": "=cmd|' /C calc'!A0", "where": "", "run_time_s": 1.5,
                    "peak_orbit_um": None, "peak_load_n": -3.0, "run_status": "failed",
                    "file": "R.h5"}])
    row = list(csv.reader(io.StringIO(text)))[1]
    assert row[3] == "'=cmd|' /C calc'!A0" and row[6] == "" and row[7] == "-3.0"


def test_what_an_event_is():
    assert incident_of("limit_trip", "load limit: 450 N > 448 N") == "trip"
    assert incident_of("error", ESTOP) == "e-stop"
    assert incident_of("error", WATCHDOG) == "watchdog"
    assert incident_of("fault", "journal-housing contact at 120.0 Hz") == "contact"
    assert incident_of("abort", "operator abort from sfdrig web") is None
    assert incident_of("info", "watchdog fed") is None
    steps = [StepRecord(index=0, freq_hz=50.0, target_kind="displacement", target_value=2e-5,
                        motion="x", first_sample=0, last_sample=500)]
    assert where_of(250, steps, [50.0, 60.0], FS) == "step 1/2 at 50.0 Hz, 0.250 s into the run"
    assert where_of(900, steps, [], FS) == "step 2, 0.900 s into the run"  # no plan known
    assert where_of(100, steps, [], 0.0) == "step 1 at 50.0 Hz"
