"""Suite-wide fixtures: seeded hypothesis, and a guard that fails a test leaking threads or
child processes (the daemon, servers and subscribers must all be shut down by their tests)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

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
        if os.environ.get("CI", "").lower() in ("true", "1"):
            pytest.fail(f"{why} (CI=true: required on CI)", pytrace=False)
        pytest.skip(why)
    return SHARED
