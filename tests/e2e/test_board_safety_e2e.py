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
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from control.wire.client import CommandClient, CommandRefused, Subscriber
from daq.channels import default_channel_map, load_channel_map
from daq.config_files import to_toml
from storage.reader import open_run
from tests.e2e.conftest import DaemonProcess, start_daemon
from tests.e2e.test_stream_e2e import LONG_X

#: long enough that the press (after the first step) always comes before its end; above the
#: dry rig's resonance, where 40 N converges
LONGER_X = {**LONG_X, "freq_hz": [80.0 + 5.0 * k for k in range(30)], "record_cycles": 200}

pytestmark = pytest.mark.e2e

# (a 2 s watchdog: fed every 0.25 s, it leaves room for a loaded machine's stalls)
EXPIRED = "watchdog on Dev1 expired: AO {'Dev1/ao0': 0.0, 'Dev1/ao1': 0.0}, lines " \
          "{'Dev1/port0/line0': False}"


def sfdrig(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sfdrig", *args], capture_output=True,
                          text=True, timeout=120)


class SimServer:
    """`sfdrig sim-server` (paced) with its log lines collected as they come."""

    def __init__(self, *extra: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "2", *extra],
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


@pytest.mark.paced
def test_the_board_stops_what_a_hung_or_dead_daemon_left_running(sim_server, tmp_path):
    d = start_daemon(tmp_path / "runs", "--backend", "nidaqmx", "--grpc-target",
                     sim_server.address, "--watchdog-s", "2", "--priority", "realtime",
                     fast=False)
    conn = ["--runs-dir", str(d.runs_dir)]
    try:
        assert sfdrig("pump", "on", *conn).returncode == 0
        assert "pump       on" in sfdrig("status", *conn).stdout  # idle, fed by heartbeats
        assert sim_server.log.empty(), list(sim_server.log.queue)  # never expired so far

        with Subscriber(d.data, rcvhwm=0) as sub, CommandClient(d.command, timeout_s=10) as c:
            sub.wait_connected()
            d.proc.send_signal(signal.SIGSTOP)  # the daemon hangs
            assert EXPIRED in sim_server.next_line("expired", timeout_s=10)
            d.proc.send_signal(signal.SIGCONT)
            # the daemon learns it from its next feed: the board has the pump off, so has it
            # (it said "on" until then, and refused a dry start as "pump on")
            event = _wait_for_event(sub, "pump off")
            assert event.startswith("pump off: the board's watchdog expired while idle"), event
            status = c.status()
            assert status["pump_on"] is False and status["film_drains_for_s"] > 20
            with pytest.raises(CommandRefused, match="the film is still draining"):
                c.start_sweep(LONGER_X)
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


def _wait_for_event(sub: Subscriber, containing: str, timeout_s: float = 30.0) -> str:
    while True:
        msg = sub.recv(timeout_s=timeout_s)
        assert msg is not None, f"no event containing {containing!r}"
        if msg.topic == "event" and containing in msg.header["message"]:
            return msg.header["message"]


def _wait_for_step(sub: Subscriber, run_id: str, timeout_s: float = 60.0) -> None:
    """Until run ``run_id`` has recorded a whole step (its drives are up). A run that ends
    first, or no step within ``timeout_s`` while other messages (heartbeats) keep coming, fails
    here with what came instead; the loop once waited for ever on heartbeats."""
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        msg = sub.recv(timeout_s=left)
        assert msg is not None, f"run {run_id}: nothing published for {left:.0f} s"
        if msg.topic == "step" and msg.header["run_id"] == run_id:
            return
        if msg.topic == "event" and f"run {run_id} " in msg.header["message"]:
            raise AssertionError(f"run {run_id} ended before a step: {msg.header['message']}")
    raise AssertionError(f"run {run_id}: no step within {timeout_s:g} s")


def estop_rig(tmp_path: Path) -> tuple[SimServer, DaemonProcess]:
    """The sim-server with an emergency stop wired to Dev1/port0/line1, and a paced daemon on
    it through nidaqmx with the production AO design: the board's 1 s watchdog and the 2 s
    regenerating ring (without the watchdog the daemon falls back to the non-regenerating
    stream, which underflowed (-200290) 2.4 s into a sweep at load 5: issue 27)."""
    data = default_channel_map().model_dump(mode="json")
    data["estop"] = {"physical_channel": "Dev1/port0/line1"}
    channels = tmp_path / "channels.toml"
    channels.write_text(to_toml(data))
    assert load_channel_map(channels).estop is not None
    server = SimServer("--fast", "--channels", str(channels))
    d = start_daemon(tmp_path / "runs", "--backend", "nidaqmx", "--grpc-target",
                     server.address, "--channels", str(channels), fast=False)
    return server, d


@pytest.mark.paced
def test_the_emergency_stop_ramps_down_and_latches_a_fault_until_released_and_reset(tmp_path):
    server, d = estop_rig(tmp_path)
    try:
        with CommandClient(d.command, timeout_s=10) as c, Subscriber(d.data, rcvhwm=0) as sub:
            sub.wait_connected()
            # pressed while idle: a fault, latched while it stays pressed
            server.proc.send_signal(signal.SIGUSR1)
            # the board logs "released" once at start-up too: wait past it to "pressed", so
            # that the "released" awaited below is the one SIGUSR2 makes
            server.next_line("emergency stop pressed", timeout_s=10)
            _wait_for_event(sub, "idle -> fault")
            assert c.status()["fault_reason"] == "emergency stop pressed"
            with pytest.raises(CommandRefused, match="emergency stop is still pressed"):
                c.reset()
            server.proc.send_signal(signal.SIGUSR2)
            server.next_line("emergency stop released", timeout_s=10)
            assert c.reset().ok
            assert c.status()["state"] == "idle"
            # pressed during a run: the drives ramp down, the run fails, the fault latches
            run_id = c.start_sweep(LONGER_X).data["run_id"]
            _wait_for_step(sub, run_id)  # a whole step recorded: the drives are well up
            server.proc.send_signal(signal.SIGUSR1)
            ended = _wait_for_event(sub, f"run {run_id} ")  # however it ended
            assert f"run {run_id} failed" in ended, ended
            assert "emergency stop pressed (input estop on Dev1/port0/line1)" in ended
            status = c.status()
            assert status["state"] == "fault" and "emergency stop" in status["fault_reason"]
            with pytest.raises(CommandRefused, match="fault"):
                c.start_sweep(LONGER_X)  # latched until released and reset
    finally:
        d.terminate()
        d.proc.communicate(timeout=10)
        server.stop()
    with open_run(d.runs_dir / f"{run_id}.h5") as run:
        drive = np.vstack([run.channel("shaker_x"), run.channel("shaker_y")])  # [V]
        assert np.abs(drive[:, -100:]).max() == 0.0  # ended at 0 V
        assert np.abs(drive[:, :drive.shape[1] // 2]).max() > 0.2  # it was driving
