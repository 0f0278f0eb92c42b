"""A daemon started again closes the runs its dead predecessor left "running", also while a
reader (the web server listing the runs) holds one open: HDF5 refuses the writer then, so the
recovery tries again with backoff instead of leaving the run unrecovered for good."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from control.run.files import recover_interrupted
from storage.reader import open_run
from tests.web.test_trips import write_incident_runs


@contextmanager
def _reader(path: Path) -> Iterator[subprocess.Popen[str]]:
    """Another process holding ``path`` open for reading (HDF5's shared lock) until a line on
    its stdin; yields once the file is open."""
    code = ("import sys, h5py; f = h5py.File(sys.argv[1], 'r'); print('open', flush=True); "
            "sys.stdin.readline(); f.close(); print('closed', flush=True)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "open"
    try:
        yield proc
    finally:
        let_go(proc)
        proc.wait(10)
        assert proc.stdout is not None
        proc.stdout.close()


def let_go(proc: subprocess.Popen[str]) -> None:
    """The reader closes its file; returns once it has."""
    if proc.poll() is None and proc.stdin is not None and not proc.stdin.closed:
        proc.stdin.write("\n")
        proc.stdin.close()
        assert proc.stdout is not None and proc.stdout.readline().strip() == "closed"


def _killed_run(tmp_path: Path) -> Path:
    runs = tmp_path / "runs"
    runs.mkdir()
    write_incident_runs(runs)  # I1.h5: left "running" by a writer that is gone
    return runs


def test_a_run_a_reader_holds_open_is_recovered_once_the_reader_lets_go(tmp_path: Path) -> None:
    runs = _killed_run(tmp_path)
    waits: list[float] = []
    with _reader(runs / "I1.h5") as reader:

        def wait(seconds: float) -> None:  # the reader lets go while the recovery waits
            waits.append(seconds)
            if len(waits) == 3:
                let_go(reader)

        out = recover_interrupted(runs, wait=wait)
    assert waits == [0.05, 0.1, 0.2]  # backoff, then the file was free
    assert {"path": str(runs / "I1.h5"), "status": "interrupted", "last_sample": 750} in out
    with open_run(runs / "I1.h5") as run:
        assert run.status == "interrupted"
        assert str(run.attrs["status_reason"]).endswith("recovered at the next daemon start")


def test_a_run_held_open_beyond_the_wait_is_listed_as_unrecovered_with_why(
        tmp_path: Path) -> None:
    runs = _killed_run(tmp_path)
    waits: list[float] = []
    with _reader(runs / "I1.h5"):
        out = recover_interrupted(runs, lock_wait_s=1.0, wait=waits.append)
    # 0.05 + 0.1 + 0.2 + 0.4 + 0.8: the wait passed 1 s, then the refusal is reported
    assert waits == [0.05, 0.1, 0.2, 0.4, 0.8]
    (row,) = [r for r in out if r["path"].endswith("I1.h5")]
    assert row["status"] == "unrecovered" and "lock" in row["error"]
    with open_run(runs / "I1.h5") as run:
        assert run.status == "running"  # left as it was, for the next start
