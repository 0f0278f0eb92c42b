"""The page's run history through the real server (raw HTTP on a random loopback port) over run
files written here with `storage.RunWriter`: the list with every status (interrupted
included), a run opened with its step table in numbers, its downloads (HDF5 byte for byte, the
exports `sfdrig export` makes), the operator's notes beside the file (the file's bytes never
change), and no way out of the runs directory."""

from __future__ import annotations

import asyncio
import hashlib
import io
import json
import logging
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
import scipy.io
from aiohttp.test_utils import TestServer

from storage import RunWriter
from storage.reader import open_run
from storage.records import StepRecord
from tests.web.test_server_security import _Daemon, _get, _post, _raw
from web.history import MAX_NOTE_CHARS
from web.server import WebApp, WebConfig

FS = 1000.0


def _write(path: Path, run_id: str, start: str, status: str | None, amps_um: list[float],
           seed: int) -> RunWriter:
    """A run of X displacement steps whose x1 1X is ``amps_um`` against a 20 um target."""
    rng = np.random.default_rng(seed)
    w = RunWriter.create(path, run_id, "sweep", ["fx", "x1"], ["shaker_x"], FS,
                         start_time=start, flush_interval_s=0,
                         test_spec={"tolerance_amplitude_pct": 2.0, "tolerance_phase_deg": 1.0})
    n = 500
    w.on_block(0, rng.normal(size=(2, n * len(amps_um))), rng.normal(size=(1, n * len(amps_um))))
    for i, a in enumerate(amps_um):
        w.on_step(StepRecord.from_wire({
            "index": i, "freq_hz": 20.0 + 10 * i, "target_kind": "amplitude",
                   "target_value": 20e-6, "motion": "x", "first_sample": i * n,
                   "last_sample": (i + 1) * n - 1, "updates": 3, "converged": True,
                   "harmonics": {"x1": [[a * 1e-6, 0.0]] + [[0.0, 0.0]] * 4,
                                 "fx": [[0.0, -40.0]] + [[0.0, 0.0]] * 4}}))
    if status is not None:
        w.close(status, "operator abort" if status == "aborted" else "")
    return w


@pytest.fixture
def runs_dir(tmp_path: Path) -> Path:
    d = tmp_path / "runs"
    d.mkdir()
    _write(d / "R1.h5", "R1", "2026-11-25T10:00:00.000+00:00", "completed", [20.0, 20.2], 1)
    _write(d / "R2.h5", "R2", "2026-11-25T11:00:00.000+00:00", "aborted", [19.0], 2)
    killed = _write(d / "R3.h5", "R3", "2026-11-25T12:00:00.000+00:00", None, [20.1], 3)
    killed._file.close()  # the writer vanished without closing the run (kill -9)
    killed._closed = True
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    with h5py.File(d / "R3.h5", "r+") as f:
        f.attrs["writer_pid"] = int(dead.stdout)
    (d / "junk.h5").write_text("not hdf5")
    (d / "secret.txt").write_text("outside any run")
    return d


def _serve(app: WebApp, test: Callable[[int], Awaitable[Any]]) -> Any:
    async def main() -> Any:
        server = TestServer(app.app)
        await server.start_server(**app.runner_options())
        async with server:
            assert server.port is not None
            return await test(server.port)
    return asyncio.run(main())


def _json(answer: tuple[int, dict[str, str], bytes]) -> tuple[int, Any]:
    return answer[0], json.loads(answer[2])


def test_the_runs_with_their_status_newest_first(runs_dir):
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]

    async def test(port: int) -> Any:
        return _json(await _raw(port, _get("/api/runs", f"127.0.0.1:{port}")))

    status, body = _serve(app, test)
    assert status == 200
    got = [(r["id"], r["status"], r["steps"], r["file"]) for r in body["runs"]]
    assert got == [("", "unreadable", 0, "junk.h5"), ("R3", "interrupted", 1, "R3.h5"),
                   ("R2", "aborted", 1, "R2.h5"), ("R1", "completed", 2, "R1.h5")]
    assert body["runs"][-1]["duration_s"] == 1.0  # 1,000 samples at 1 kS/s


def test_the_history_pages_and_filters(runs_dir):
    """Pages of the list, newest first, from the run index; filters as `sfdrig runs` takes
    them; a bad filter or page is a 400 naming it, never a 500."""
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]
    asks = ["/api/runs?limit=2", "/api/runs?limit=2&offset=2", "/api/runs?offset=3",
            "/api/runs?status=aborted,interrupted", "/api/runs?kind=sweep&until=2026-11-25T11:30",
            "/api/runs?motion=x&lubricated=no", "/api/runs?kind=swep", "/api/runs?limit=x",
            "/api/runs?limit=5000", "/api/runs?since=%00", "/api/runs?nope=1",
            "/api/runs?seal=" + "w" * 5000]

    async def test(port: int) -> list[tuple[int, Any]]:
        return [_json(await _raw(port, _get(a, f"127.0.0.1:{port}"))) for a in asks]

    out = _serve(app, test)
    assert [s for s, _ in out] == [200] * 6 + [400] * 6
    pages = [([r["file"] for r in b["runs"]], b["total"], b["offset"]) for _, b in out[:6]]
    assert pages == [(["junk.h5", "R3.h5"], 4, 0), (["R2.h5", "R1.h5"], 4, 2),
                     (["R1.h5"], 4, 3), (["R3.h5", "R2.h5"], 2, 0), (["R2.h5", "R1.h5"], 2, 0),
                     (["R3.h5", "R2.h5", "R1.h5"], 3, 0)]
    errors = [b["error"] for _, b in out[6:]]
    assert errors[:5] == [
        "kind='swep' is not one of sweep, static, impact, probe_calibration, flow, imported, "
        "commissioning (did you mean 'sweep'?)",
        "limit='x': a whole number above 0",
        "limit='5000': at most 1000 runs a page",
        "since='\\x00' is not an ISO 8601 date or time (e.g. 2026-03-01 or 2026-03-01T08:00)",
        "unknown filter 'nope': the filters are kind, status, since, until, lubricated, seal, "
        "motion, limit, offset"]
    assert errors[5].startswith("seal='wwww") and len(errors[5]) < 200


def test_a_run_opened_with_its_step_table(runs_dir):
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]

    async def test(port: int) -> Any:
        return _json(await _raw(port, _get("/api/runs/R1", f"127.0.0.1:{port}")))

    status, run = _serve(app, test)
    assert status == 200 and run["status"] == "completed" and run["kind"] == "sweep"
    rows = [(s["freq_hz"], s["unit"], s["target"], s["achieved"], s["band_pct"])
            for s in run["steps"]]
    assert rows == [(20.0, "um", pytest.approx(20.0), pytest.approx(20.0), 2.0),
                    (30.0, "um", pytest.approx(20.0), pytest.approx(20.2), 2.0)]
    assert run["steps"][1]["error_pct"] == pytest.approx(1.0)
    # the displacement lags the load by 90 degrees (x real, fx -40j)
    assert run["steps"][0]["phase_deg"] == pytest.approx(90.0)


def test_downloads_are_the_file_and_the_exports(runs_dir, tmp_path, monkeypatch, caplog):
    """Each download is whole, nothing is logged as an error while it is served (the export's
    folder lives until the answer is sent), and no folder is left behind."""
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))  # where the exports are made
    caplog.set_level(logging.WARNING)

    async def test(port: int) -> dict[str, tuple[int, dict[str, str], bytes]]:
        host = f"127.0.0.1:{port}"
        return {fmt: await _raw(port, _get(f"/api/runs/R2/download?format={fmt}", host))
                for fmt in ("h5", "mat", "csv", "tdms", "exe")}

    got = _serve(app, test)
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR] == []
    assert list(temp.iterdir()) == []
    assert got["h5"][0] == 200 and got["h5"][2] == (runs_dir / "R2.h5").read_bytes()
    assert got["h5"][1]["content-disposition"] == 'attachment; filename="R2.h5"'
    assert got["mat"][0] == 200 and "R2.mat" in got["mat"][1]["content-disposition"]
    mat = scipy.io.loadmat(io.BytesIO(got["mat"][2]))
    with open_run(runs_dir / "R2.h5") as run:
        fx = run.signal("fx")
    assert len(fx) == 500 and np.array_equal(np.ravel(mat["fx"]), fx)  # sample for sample
    assert got["csv"][0] == 200
    names = zipfile.ZipFile(io.BytesIO(got["csv"][2])).namelist()
    assert "R2.csv" in names and len(names) >= 2  # the samples and the tables beside them
    assert got["tdms"][0] == 200 and got["tdms"][2][:4] == b"TDSm"
    assert got["exe"][0] == 400 and "one of h5, mat, csv, tdms" in json.loads(got["exe"][2])[
        "error"]


def test_no_request_leaves_the_runs_directory(runs_dir):
    app = WebApp(_Daemon(), WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]
    attempts = ["/api/runs/..%2Fsecret.txt/download?format=h5",
                "/api/runs/%2e%2e%2f%2e%2e%2fetc%2fpasswd/download?format=h5",
                "/api/runs/../../etc/passwd", "/api/runs/secret.txt/download?format=h5",
                "/api/runs/R1.notes/download?format=h5", "/api/runs/junk/download?format=h5",
                "/api/runs/%2Fetc%2Fpasswd", "/api/runs/R1%00/download?format=h5"]

    async def test(port: int) -> list[tuple[int, bytes]]:
        host = f"127.0.0.1:{port}"
        return [(s, b) for a in attempts for s, _, b in [await _raw(port, _get(a, host))]]

    for (status, body), attempt in zip(_serve(app, test), attempts, strict=True):
        assert status in (400, 404), (attempt, status)
        assert b"outside any run" not in body and b"root:" not in body, attempt


def test_notes_are_kept_beside_the_run_and_the_file_is_never_touched(runs_dir):
    daemon = _Daemon()
    app = WebApp(daemon, WebConfig(runs_dir=runs_dir))  # type: ignore[arg-type]
    viewer = WebApp(daemon, WebConfig(runs_dir=runs_dir,  # type: ignore[arg-type]
                                      anonymous_role="viewer"))
    before = hashlib.sha256((runs_dir / "R3.h5").read_bytes()).hexdigest()

    async def test(port: int) -> list[tuple[int, Any]]:
        host = f"127.0.0.1:{port}"
        url = "/api/runs/R3/notes"
        return [_json(await _raw(port, _post(url, json.dumps({"text": t}).encode(), host)))
                for t in ("seal leaked at 40 Hz", "  <script>x</script>  ", "",
                          "x" * (MAX_NOTE_CHARS + 1))] + [
            _json(await _raw(port, _post(url, b"[1,2,3]", host))),
            _json(await _raw(port, _post("/api/runs/R9/notes", b'{"text": "a"}', host))),
            _json(await _raw(port, _get("/api/runs/R3", host)))]

    out = _serve(app, test)
    assert [s for s, _ in out] == [200, 200, 400, 400, 400, 404, 200]
    notes = out[1][1]["notes"]
    assert [(n["author"], n["text"]) for n in notes] == [
        ("local", "seal leaked at 40 Hz"), ("local", "<script>x</script>")]
    assert out[-1][1]["notes"] == notes and out[-1][1]["status"] == "interrupted"
    assert json.loads((runs_dir / "R3.notes.json").read_text()) == notes
    assert hashlib.sha256((runs_dir / "R3.h5").read_bytes()).hexdigest() == before

    async def as_viewer(port: int) -> int:
        return (await _raw(port, _post("/api/runs/R3/notes", b'{"text": "mine"}',
                                       f"127.0.0.1:{port}")))[0]

    assert _serve(viewer, as_viewer) == 403
    assert len(json.loads((runs_dir / "R3.notes.json").read_text())) == 2


def test_a_run_being_written_is_not_downloaded(tmp_path):
    w = _write(tmp_path / "L.h5", "L", "2026-11-25T10:00:00.000+00:00", None, [20.0], 4)
    app = WebApp(_Daemon(), WebConfig(runs_dir=tmp_path))  # type: ignore[arg-type]

    async def test(port: int) -> list[tuple[int, Any]]:
        host = f"127.0.0.1:{port}"
        return [_json(await _raw(port, _get("/api/runs", host))),
                _json(await _raw(port, _get("/api/runs/L/download?format=mat", host)))]

    try:
        (s1, listing), (s2, refused) = _serve(app, test)
    finally:
        w.close("completed", "")
    assert s1 == 200 and listing["runs"][0]["status"] == "running"
    assert s2 == 409 and "still being written" in refused["error"]


FAKE_IDENTIFY = '''
import sys
from pathlib import Path
run, out = Path(sys.argv[1]), Path(sys.argv[sys.argv.index("--report") + 1])
assert "--no-store" in sys.argv  # the run file is never written
if run.stem == "R2":
    print("error: nothing identified (1 item(s) skipped, reasons above)")
    sys.exit(1)
(out / "figures").mkdir(parents=True)
(out / "index.html").write_text("<html><style>b{}</style><b>K 788 kN/m</b></html>")
(out / "figures" / "k.png").write_bytes(b"PNG-of-" + run.stem.encode())
print(f"report: {out / 'index.html'}")
'''


def test_the_identification_report_made_on_request_and_served(runs_dir, tmp_path):
    fake = tmp_path / "fake_identify.py"
    fake.write_text(FAKE_IDENTIFY)
    cfg = {"runs_dir": runs_dir, "identify_command": (sys.executable, str(fake))}
    app = WebApp(_Daemon(), WebConfig(**cfg))  # type: ignore[arg-type]
    viewer = WebApp(_Daemon(), WebConfig(anonymous_role="viewer", **cfg))  # type: ignore[arg-type]
    before = hashlib.sha256((runs_dir / "R1.h5").read_bytes()).hexdigest()

    async def test(port: int) -> dict[str, Any]:
        host = f"127.0.0.1:{port}"
        base = "/api/runs/R1/report/"
        return {"made": _json(await _raw(port, _post("/api/runs/R1/report", b"{}", host))),
                "failed": _json(await _raw(port, _post("/api/runs/R2/report", b"{}", host))),
                "page": await _raw(port, _get(base + "index.html", host)),
                "figure": await _raw(port, _get(base + "figures/k.png", host)),
                "escape": [(await _raw(port, _get(base + p, host)))[0] for p in (
                    "../../R1.h5", "..%2F..%2FR1.h5", "%2e%2e/%2e%2e/secret.txt", "figures")],
                "details": _json(await _raw(port, _get("/api/runs/R1", host)))}

    async def as_viewer(port: int) -> int:
        return (await _raw(port, _post("/api/runs/R1/report", b"{}", f"127.0.0.1:{port}")))[0]

    assert _serve(viewer, as_viewer) == 403
    out = _serve(app, test)
    status, made = out["made"]
    assert status == 200 and made["ok"] and made["data"]["lines"][-1].endswith("index.html")
    status, failed = out["failed"]
    assert not failed["ok"] and failed["error"] == ("identify R2: error: nothing identified "
                                                    "(1 item(s) skipped, reasons above)")
    status, headers, body = out["page"]
    assert status == 200 and b"K 788 kN/m" in body
    csp = [d.strip() for d in headers["content-security-policy"].split(";")]
    assert "frame-ancestors 'none'" in csp and "style-src 'unsafe-inline'" in csp
    assert "default-src 'none'" in csp  # no script of any origin
    assert out["figure"][0] == 200 and out["figure"][2] == b"PNG-of-R1"
    assert all(s in (400, 404) for s in out["escape"]), out["escape"]
    assert out["details"][1]["report"] is True
    assert (runs_dir / "reports" / "R1" / "index.html").is_file()
    assert hashlib.sha256((runs_dir / "R1.h5").read_bytes()).hexdigest() == before
