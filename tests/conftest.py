"""Suite-wide fixtures: seeded hypothesis, and a guard that fails a test leaking threads or
child processes (the daemon, servers and subscribers must all be shut down by their tests).

Under pytest-xdist (`./dev test` runs two workers) two rules keep the suite what it is serially:

- a test marked ``paced`` (it runs against the wall clock: a paced rig, board or watchdog) never
  runs beside another test of the suite. All paced tests form one xdist group (one worker, one
  after the other), and a file lock shared by the workers of a run is held exclusively around
  that block and shared around every other test, so the other worker waits while it runs. The
  machine's other load is still there, as it is for a serial run.
- the tests of a module that uses a module-scoped fixture form one xdist group, so that fixture
  is built once (by one worker), not once per worker.
"""

from __future__ import annotations

import fcntl
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import pytest
from hypothesis import HealthCheck, settings
from threadpoolctl import threadpool_limits

# One BLAS thread in the test process and the processes it starts (as the daemon, `sfdrig web`
# and diagnose already limit themselves): the workers already fill the cores, and OpenBLAS's
# threads spin-wait for a core on a busy machine.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
threadpool_limits(limits=1, user_api="blas")

settings.register_profile(
    "ci", derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("ci")

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED = REPO_ROOT.parent / "shared"


def _children() -> set[int]:
    """Live (not zombie-reaped) child process ids of this process, from /proc."""
    pids: set[int] = set()
    task_dir = Path(f"/proc/{os.getpid()}/task")
    for task in task_dir.iterdir() if task_dir.exists() else []:
        try:
            pids.update(int(p) for p in (task / "children").read_text().split())
        except OSError:
            continue
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(pid)
    return alive


def _xdist_worker() -> bool:
    return "PYTEST_XDIST_WORKER" in os.environ


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the xdist_group marks
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("paced") is not None:
            item.add_marker(pytest.mark.xdist_group("paced"))
            continue
        info = getattr(item, "_fixtureinfo", None)
        defs = info.name2fixturedefs.values() if info is not None else []
        if any(d and d[-1].scope in ("module", "class", "package") for d in defs):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))


class _PacedLock:
    """Readers-writer lock across the workers of one run (flock on two files beside the
    workers' temporary directories): shared for ordinary tests, exclusive for paced ones. A
    worker waiting for the exclusive lock holds the turnstile, so no new shared holder slips in
    before it; consecutive paced tests keep the exclusive lock."""

    def __init__(self, root: Path) -> None:
        self._turnstile: IO[str] = open(root / "paced.turnstile", "a")  # noqa: SIM115
        self._lock: IO[str] = open(root / "paced.lock", "a")  # noqa: SIM115
        self.held: int | None = None

    def acquire(self, mode: int) -> None:
        if self.held == mode:
            return
        self.release()
        fcntl.flock(self._turnstile, fcntl.LOCK_EX)
        try:
            fcntl.flock(self._lock, mode)
        finally:
            fcntl.flock(self._turnstile, fcntl.LOCK_UN)
        self.held = mode

    def release(self) -> None:
        if self.held is not None:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self.held = None


_paced_lock: _PacedLock | None = None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Around the whole protocol of a test (its fixtures' set-up and tear-down included)."""
    global _paced_lock
    if not _xdist_worker():
        yield
        return
    if _paced_lock is None:
        # every worker's basetemp is <run's root>/popen-gwN: the lock files go in that root
        factory = item.config._tmp_path_factory  # type: ignore[attr-defined]
        _paced_lock = _PacedLock(factory.getbasetemp().parent)
    paced = item.get_closest_marker("paced") is not None
    _paced_lock.acquire(fcntl.LOCK_EX if paced else fcntl.LOCK_SH)
    try:
        yield
    finally:
        if not (paced and nextitem is not None and nextitem.get_closest_marker("paced")):
            _paced_lock.release()


@pytest.fixture(autouse=True)
def no_leaked_threads_or_processes():
    threads_before = set(threading.enumerate())
    children_before = _children()
    yield
    # A thread told to stop may still be finishing its last lines: join it, bounded.
    deadline = time.monotonic() + 5.0
    for t in threading.enumerate():
        if t not in threads_before:
            t.join(max(0.0, deadline - time.monotonic()))
    leaked = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    extra = _children() - children_before
    if not leaked and not extra:
        return
    msg = []
    if leaked:
        msg.append(f"leaked threads: {[t.name for t in leaked]}")
    if extra:
        msg.append(f"leaked child processes: {sorted(extra)}")
    pytest.fail("; ".join(msg))


@pytest.fixture
def shared_dir() -> Path:
    """../shared beside the repository (real measured data); skip clearly where it is absent."""
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} is absent: the measured-data tests need ../shared beside the repo")
    return SHARED
