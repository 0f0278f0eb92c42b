"""Suite-wide fixtures: seeded hypothesis, and a guard that fails a test leaking threads or
child processes (the daemon, servers and subscribers must all be shut down by their tests).

Tests against the wall clock, and the pytest-xdist workers (`./dev test` runs one per core):

- a test marked ``paced`` (it runs against the wall clock: a paced rig, board or watchdog, a
  timing bound) runs at normal priority beside the other workers' tests: the product's promise
  (issue 21) is that a busy PC makes the host late, never the AO underflow (the regenerating
  ring), so these tests check it on a machine whose both cores are busy. The paced tests form
  one group (one worker, one after the other), so no two of them compete with each other.
- a test marked ``busy_pc`` loads the machine on purpose (busy loops beside a paced daemon): it
  is marked ``paced`` too, so it runs in that group's sequence, never beside a paced test
  whose wall clock its busy loops would take.
- the tests of a module that use a module-scoped fixture form one group, so that fixture is
  built once (by one worker), not once per worker.

Markers tell the truth: collection fails on a test under tests/e2e without ``e2e`` or on a test
reading ../shared (``shared_dir``) without ``needs_shared`` or on a ``busy_pc`` test without
``paced``; ``held_out`` tests run only when the ``-m`` expression names them.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings
from threadpoolctl import threadpool_limits

from tests.ci import on_ci

# A shell without job control starts a background command (`./dev test &`, `nohup ... &` in a
# script) with SIGINT ignored, and every child inherits that: the tests' `sfdrig` processes
# would then shrug off the Ctrl-C the tests send them as an operator's keyboard would (a
# sweep ran to its end, `channels live` never stopped). Ctrl-C is what those tests check, so
# the suite's processes take it as a terminal's user would.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# One BLAS thread in the test process and the processes it starts (as the daemon, `sfdrig web`
# and diagnose already limit themselves): the workers already fill the cores, and OpenBLAS's
# threads spin-wait for a core on a busy machine.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
threadpool_limits(limits=1, user_api="blas")

# fixtures shared across folders: the stand-in daemon for clients' tests (`fakes`)
pytest_plugins = ["tests.fake_daemon"]

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


def _deselect_held_out(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Drop the ``held_out`` tests (diagnose's held-out seeds) unless the ``-m`` expression names
    them: they run before a diagnose change lands (``./dev test -m held_out``), never in the
    default run nor with ``-m slow``, so nobody tunes diagnose against them."""
    if "held_out" in (config.getoption("markexpr", "") or ""):
        return
    held = [item for item in items if item.get_closest_marker("held_out") is not None]
    if held:
        config.hook.pytest_deselected(items=held)
        items[:] = [item for item in items if item.get_closest_marker("held_out") is None]


def _untruthful_markers(items: list[pytest.Item]) -> list[str]:
    """Tests whose markers do not say what they do: one under tests/e2e (real processes and
    sockets) without ``e2e``, one reading ../shared (``shared_dir``) without ``needs_shared``,
    a ``busy_pc`` one without ``paced``."""
    wrong = []
    for item in items:
        parts = Path(str(item.path)).parts
        if "e2e" in parts and "tests" in parts and item.get_closest_marker("e2e") is None:
            wrong.append(f"{item.nodeid}: under tests/e2e without the e2e marker")
        if item.get_closest_marker("busy_pc") and item.get_closest_marker("paced") is None:
            wrong.append(f"{item.nodeid}: busy_pc without paced (it would run beside the "
                         "paced tests)")
        uses_shared = "shared_dir" in getattr(item, "fixturenames", ())
        if uses_shared != (item.get_closest_marker("needs_shared") is not None):
            wrong.append(f"{item.nodeid}: the shared_dir fixture and the needs_shared marker "
                         "go together")
    return wrong


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Markers checked (`_untruthful_markers`: a collection error); the held-out tests dropped
    (`_deselect_held_out`); each worker writes the groups of what it collected (the same for
    all) for the controller's scheduler (`_GroupScheduling`)."""
    if wrong := _untruthful_markers(items):
        raise pytest.UsageError("markers that do not tell the truth:\n  " + "\n  ".join(wrong))
    _deselect_held_out(config, items)
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
    """../shared beside the repository (real measured data); skip clearly where it is absent,
    but fail on CI (CI=true), where a missing ../shared is a broken set-up, not a reason to skip."""
    if not SHARED.is_dir():
        why = f"{SHARED} is absent: the measured-data tests need ../shared beside the repo"
        if on_ci():
            pytest.fail(f"{why} (CI=true: required on CI)", pytrace=False)
        pytest.skip(why)
    return SHARED
