"""Suite-wide fixtures: seeded hypothesis, and a guard that fails a test leaking threads or
child processes (the daemon, servers and subscribers must all be shut down by their tests).

Tests against the wall clock, and the pytest-xdist workers (`./dev test` runs one per core):

- a test marked ``paced`` (it runs against the wall clock: a paced rig, board or watchdog, a
  timing bound) runs at real-time priority (SCHED_FIFO 10, the scheduling of `sfdrig daemon
  --priority realtime`, which the README gives for a loaded PC), inherited by the threads and
  processes it starts (daemon, sim-server, clients), where the OS allows it (root, as on CI).
  The suite runs on shared machines (load 5-9 on 2 cores while others work), where a paced loop
  at normal priority falls behind its 30-40 ms AO lead and underflows (-200290): the README's
  documented limit of a loaded PC, not what these tests check. Seen before this: the daemon of
  test_kill_9_mid_run at load 4-5 in a serial run; test_paced_backend_keeps_up_with_the_clock
  (in-process) at load 6 with the other worker waiting.
- the paced tests form one group (one worker, one after the other), so no two paced tests
  compete. At SCHED_FIFO a paced test preempts the other worker's test (at normal priority).
  Where the OS refuses SCHED_FIFO, a file lock shared by the workers of a run is held
  exclusively around the paced block and shared around every other test instead: the other
  worker waits while it runs.
- the tests of a module that use a module-scoped fixture form one group, so that fixture is
  built once (by one worker), not once per worker.
"""

from __future__ import annotations

import fcntl
import functools
import json
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

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


def _xdist_group(item: pytest.Item) -> str | None:
    """The group ``item`` runs in (on one worker, one test after the other), if any: ``paced``,
    or its module's path where it uses a module- or class-scoped fixture."""
    if item.get_closest_marker("paced") is not None:
        return "paced"
    info = getattr(item, "_fixtureinfo", None)
    defs = info.name2fixturedefs.values() if info is not None else []
    if any(d and d[-1].scope in ("module", "class", "package") for d in defs):
        return item.nodeid.split("::")[0]
    return None


def _run_root(config: pytest.Config) -> Path:
    """The directory of this run's temporary directories (a worker's basetemp is in it)."""
    base: Path = config._tmp_path_factory.getbasetemp()  # type: ignore[attr-defined]
    return base.parent if _xdist_worker() else base


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Each worker writes the groups of what it collected (the same for all) for the
    controller's scheduler (`_GroupScheduling`)."""
    if not _xdist_worker():
        return
    groups = {item.nodeid: g for item in items if (g := _xdist_group(item)) is not None}
    root = _run_root(config)
    tmp = root / f"xdist-groups.{os.environ['PYTEST_XDIST_WORKER']}.json"
    tmp.write_text(json.dumps(groups))
    tmp.replace(root / "xdist-groups.json")


class _XdistGroups:
    """``--dist loadgroup`` with the groups of `_xdist_group` (pytest-xdist 3.8's own loadgroup
    marks the group in ``item._nodeid``, which pytest 9.2 no longer reads)."""

    @pytest.hookimpl
    def pytest_xdist_make_scheduler(self, config: pytest.Config, log: Any) -> Any:
        if config.getvalue("dist") != "loadgroup":
            return None
        from xdist.scheduler import LoadScopeScheduling

        root = _run_root(config)

        class _GroupScheduling(LoadScopeScheduling):  # type: ignore[misc]
            groups: dict[str, str] | None = None

            def _split_scope(self, nodeid: str) -> str:
                if self.groups is None:  # called once every worker has collected
                    self.groups = json.loads((root / "xdist-groups.json").read_text())
                return self.groups.get(nodeid, nodeid)

        return _GroupScheduling(config, log)


def pytest_configure(config: pytest.Config) -> None:
    if config.pluginmanager.hasplugin("xdist"):
        config.pluginmanager.register(_XdistGroups(), "sfdrig-xdist-groups")


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


def _realtime() -> bool:
    """SCHED_FIFO (priority 10, as `sfdrig daemon --priority realtime`) for this thread, and so
    for the threads and processes it starts; False where the OS refuses it."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    except (AttributeError, OSError):
        return False
    return True


def _normal() -> None:
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


@functools.cache
def _realtime_allowed() -> bool:
    if not _realtime():
        return False
    _normal()
    return True


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Around the whole protocol of a test (its fixtures' set-up and tear-down included):
    real-time scheduling for a paced test; where the OS refuses it, under xdist, the paced lock
    instead (a paced test at SCHED_FIFO preempts every normal process, the other worker's too)."""
    global _paced_lock
    paced = item.get_closest_marker("paced") is not None
    if _xdist_worker() and not _realtime_allowed():
        if _paced_lock is None:
            _paced_lock = _PacedLock(_run_root(item.config))
        _paced_lock.acquire(fcntl.LOCK_EX if paced else fcntl.LOCK_SH)
    realtime = paced and _realtime()
    try:
        yield
    finally:
        if realtime:
            _normal()
        if _paced_lock is not None and not (
                paced and nextitem is not None and nextitem.get_closest_marker("paced")):
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
