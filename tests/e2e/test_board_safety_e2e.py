"""End to end, real processes: the daemon on `--backend nidaqmx` against `sfdrig sim-server`.
Between runs the daemon's command loop feeds the board's watchdog (during a run `read_ai` does:
tests/daq/test_safe_states.py); when the daemon hangs (SIGSTOP) or dies (SIGKILL) the board
itself turns the pump relay off and holds the drives at 0 V, and says so in its log."""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from tests.e2e.conftest import start_daemon

pytestmark = pytest.mark.e2e

EXPIRED = "watchdog on Dev1 expired: AO {'Dev1/ao0': 0.0, 'Dev1/ao1': 0.0}, lines " \
          "{'Dev1/port0/line0': False}"


def sfdrig(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sfdrig", *args], capture_output=True,
                          text=True, timeout=120)


class SimServer:
    """`sfdrig sim-server` (paced) with its log lines collected as they come."""

    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "2"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        first = self.proc.stdout.readline().strip()  # type: ignore[union-attr]
        assert first.startswith("listening on "), first
        self.address = first.removeprefix("listening on ")
        self.log: queue.Queue[str] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:  # type: ignore[union-attr]
            self.log.put(line.rstrip())

    def next_line(self, containing: str, timeout_s: float) -> str:
        """The next log line containing ``containing`` (skipping others)."""
        while True:
            line = self.log.get(timeout=timeout_s)
            if containing in line:
                return line

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(10)
        self._reader.join(10)
        for pipe in (self.proc.stdout, self.proc.stderr):
            pipe.close()  # type: ignore[union-attr]


@pytest.fixture
def sim_server() -> Iterator[SimServer]:
    server = SimServer()
    yield server
    server.stop()


def test_the_board_stops_what_a_hung_or_dead_daemon_left_running(sim_server, tmp_path):
    d = start_daemon(tmp_path / "runs", "--backend", "nidaqmx", "--grpc-target",
                     sim_server.address, "--watchdog-s", "0.5", "--priority", "realtime",
                     fast=False)
    conn = ["--runs-dir", str(d.runs_dir)]
    try:
        assert sfdrig("pump", "on", *conn).returncode == 0
        assert "pump       on" in sfdrig("status", *conn).stdout  # idle, fed by heartbeats
        assert sim_server.log.empty(), list(sim_server.log.queue)  # never expired so far

        d.proc.send_signal(signal.SIGSTOP)  # the daemon hangs
        assert EXPIRED in sim_server.next_line("expired", timeout_s=10)
        d.proc.send_signal(signal.SIGCONT)
        out = sfdrig("pump", "on", *conn)  # the operator switches it on again: clears it
        assert out.returncode == 0, out
        assert "pump       on" in sfdrig("status", *conn).stdout

        d.proc.kill()  # the daemon dies
        d.proc.wait(10)
        assert EXPIRED in sim_server.next_line("expired", timeout_s=10)
    finally:
        if d.proc.poll() is None:
            d.terminate()
        d.proc.communicate(timeout=10)
