"""Fixtures for end-to-end tests: the daemon as a real process on random loopback ports.

Synchronisation is on messages only: the daemon's first stdout line names its endpoints (read
with a poll timeout), a subscriber is live once it receives a status heartbeat, and a run has
ended when its closing event (or a status reply) says so.
"""

from __future__ import annotations

import os
import selectors
import shlex
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]


@dataclass
class DaemonProcess:
    proc: subprocess.Popen[str]
    command: str
    data: str
    runs_dir: Path
    board: str = ""  # what the first line names the board ("simulated rig (in process)", ...)

    def terminate(self, sig: int = signal.SIGTERM, timeout_s: float = 30.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
            raise


def start_daemon(runs_dir: Path, *extra: str, fast: bool = True,
                 timeout_s: float = 60.0) -> DaemonProcess:
    """Start ``python -m sfdrig daemon`` and wait (poll, no sleep) for its endpoint line."""
    cmd = [sys.executable, "-m", "sfdrig", "daemon", "--runs-dir", str(runs_dir), *extra]
    if fast:
        cmd.append("--fast")
    runs_dir.mkdir(parents=True, exist_ok=True)
    stderr = open(runs_dir.parent / f"{runs_dir.name}.stderr", "w")  # noqa: SIM115
    proc = subprocess.Popen(cmd, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=stderr,
                            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    stderr.close()  # the child holds its own copy
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
    try:
        if not sel.select(timeout_s):
            proc.kill()
            proc.wait(10)
            raise RuntimeError(f"daemon printed no endpoints within {timeout_s} s")
        line = proc.stdout.readline()  # type: ignore[union-attr]
    finally:
        sel.close()
    if not line.startswith("command="):
        proc.kill()
        proc.communicate(timeout=10)
        err = (runs_dir.parent / f"{runs_dir.name}.stderr").read_text()
        raise RuntimeError(f"daemon did not start: {line!r}\n{err}")
    fields = dict(part.split("=", 1) for part in shlex.split(line))
    return DaemonProcess(proc, fields["command"], fields["data"], runs_dir, fields["board"])


@pytest.fixture
def daemon_factory(tmp_path: Path) -> Iterator:
    started: list[DaemonProcess] = []

    def factory(*extra: str, fast: bool = True) -> DaemonProcess:
        d = start_daemon(tmp_path / f"runs{len(started)}", *extra, fast=fast)
        started.append(d)
        return d

    yield factory
    for d in started:
        if d.proc.poll() is None:
            d.terminate()
        d.proc.communicate(timeout=10)
        err = (d.runs_dir.parent / f"{d.runs_dir.name}.stderr").read_text()
        if err:
            print(f"--- daemon stderr ({d.runs_dir.name}) ---\n{err}")
