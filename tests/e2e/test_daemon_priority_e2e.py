"""`sfdrig daemon --priority`: real-time scheduling where the OS allows it, a clear refusal (one
line, exit 2, nothing started) where it does not."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.e2e.conftest import REPO_ROOT, start_daemon

pytestmark = pytest.mark.e2e

def _may_use_fifo() -> bool:
    """Whether this test process may ask for SCHED_FIFO (checked in a child, not here)."""
    probe = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no SCHED_FIFO on this OS")
def test_realtime_priority_where_the_os_allows_it(tmp_path: Path) -> None:
    if not _may_use_fifo():
        pytest.skip("this user may not use SCHED_FIFO (see the refusal test)")
    d = start_daemon(tmp_path / "runs", "--priority", "realtime")
    try:
        assert os.sched_getscheduler(d.proc.pid) == os.SCHED_FIFO
        assert os.sched_getparam(d.proc.pid).sched_priority == 10
    finally:
        assert d.terminate() == 0
        d.proc.communicate(timeout=10)


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no SCHED_FIFO on this OS")
def test_realtime_priority_refused_with_the_reason(tmp_path: Path) -> None:
    """Without the privilege (root: CAP_SYS_NICE dropped with setpriv): refused, saying what to
    change."""
    prefix: list[str] = []
    if _may_use_fifo():
        setpriv = shutil.which("setpriv")
        if os.geteuid() != 0 or setpriv is None:
            pytest.skip("this user may use SCHED_FIFO and cannot drop the privilege")
        prefix = [setpriv, "--bounding-set=-sys_nice", "--inh-caps=-sys_nice"]
    out = subprocess.run(
        [*prefix, sys.executable, "-m", "sfdrig", "daemon", "--runs-dir",
         str(tmp_path / "runs"), "--priority", "realtime", "--fast"],
        cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out
    assert out.stdout == ""  # no endpoints: it did not start
    (line,) = out.stderr.strip().splitlines()
    assert line.startswith("daemon: --priority realtime: the OS refused SCHED_FIFO")
    assert "rtprio" in line and "CAP_SYS_NICE" in line
    assert not (tmp_path / "runs").exists()  # nothing was created
