"""One daemon per runs directory and per board (issue 21): a second `sfdrig daemon` is refused
with the first one's pid and endpoints, leaves the first reachable and its daemon.json in place;
the state of a killed daemon is taken over. Real daemon processes, random ports, no sleeps."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from control.wire.client import CommandClient
from tests.e2e.conftest import REPO_ROOT, start_daemon
from tests.e2e.test_board_safety_e2e import SimServer

pytestmark = pytest.mark.e2e


def daemon_cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sfdrig", "daemon", *args], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})


def test_a_second_daemon_on_the_same_runs_directory_is_refused(tmp_path):
    runs = tmp_path / "runs"
    first = start_daemon(runs)
    try:
        state_before = (runs / "daemon.json").read_text()
        out = daemon_cli("--runs-dir", str(runs), "--fast")
        assert out.returncode == 1, out
        assert out.stdout == ""
        lines = out.stderr.splitlines()
        assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
        assert lines[0] == (f"daemon: runs directory {runs} is in use by pid {first.proc.pid} "
                            f"(sfdrig daemon --runs-dir {runs} --fast), command={first.command} "
                            f"data={first.data}: stop it first, or give another --runs-dir")
        # the first daemon is untouched: its state file, its sockets
        assert (runs / "daemon.json").read_text() == state_before
        with CommandClient(first.command, timeout_s=10) as c:
            assert c.status()["pid"] == first.proc.pid
        status = subprocess.run([sys.executable, "-m", "sfdrig", "status", "--runs-dir",
                                 str(runs)], capture_output=True, text=True, timeout=60)
        assert status.returncode == 0 and f"command={first.command}" in status.stdout
    finally:
        assert first.terminate() == 0
        first.proc.communicate(timeout=10)
    assert not (runs / "daemon.json").exists()  # the first removes its own on the way out


def test_the_state_of_a_killed_daemon_is_taken_over(tmp_path):
    runs = tmp_path / "runs"
    dead = start_daemon(runs)
    dead.proc.send_signal(signal.SIGKILL)
    dead.proc.wait(10)
    dead.proc.communicate(timeout=10)
    assert json.loads((runs / "daemon.json").read_text())["pid"] == dead.proc.pid  # left behind
    status = subprocess.run([sys.executable, "-m", "sfdrig", "status", "--runs-dir", str(runs)],
                            capture_output=True, text=True, timeout=60)
    assert status.returncode == 1 and status.stdout == ""
    assert status.stderr == (f"the daemon that wrote {runs / 'daemon.json'} (pid "
                             f"{dead.proc.pid}) is not running: start `sfdrig daemon --runs-dir "
                             f"{runs}` (it takes the stale file over)\n")
    second = start_daemon(runs)
    try:
        state = json.loads((runs / "daemon.json").read_text())
        assert (state["pid"], state["command"]) == (second.proc.pid, second.command)
        with CommandClient(state["command"], timeout_s=10) as c:
            assert c.status()["state"] == "idle"
    finally:
        assert second.terminate() == 0
        second.proc.communicate(timeout=10)


def test_two_daemons_on_one_board_are_refused(tmp_path, monkeypatch):
    env = {"SFDRIG_RUNTIME_DIR": str(tmp_path / "locks")}  # the device locks of this test
    monkeypatch.setenv("SFDRIG_RUNTIME_DIR", env["SFDRIG_RUNTIME_DIR"])  # start_daemon's too
    server = SimServer("--fast")
    try:
        first = start_daemon(tmp_path / "runs_a", "--backend", "nidaqmx", "--grpc-target",
                             server.address, "--watchdog-s", "0", fast=False)
        try:
            host, port = server.address.rsplit(":", 1)
            other = {"localhost": "127.0.0.1", "127.0.0.1": "localhost"}.get(host, host)
            for target in (server.address, f"{other}:{port}"):  # one board, however named
                out = daemon_cli("--runs-dir", str(tmp_path / "runs_b"), "--backend",
                                 "nidaqmx", "--grpc-target", target, "--watchdog-s", "0",
                                 env=env)
                assert out.returncode == 1, out
                assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr
                assert out.stderr.startswith(
                    f"daemon: nidaqmx device Dev1 via gRPC {target} is in use by pid "
                    f"{first.proc.pid} (sfdrig daemon --runs-dir {tmp_path / 'runs_a'} "
                    f"--backend nidaqmx --grpc-target {server.address} --watchdog-s 0), "
                    f"command={first.command} data={first.data}, runs dir "
                    f"{tmp_path / 'runs_a'}: stop it first"), out.stderr
            assert not (tmp_path / "runs_b" / "daemon.json").exists()
            with CommandClient(first.command, timeout_s=10) as c:
                assert c.status()["state"] == "idle"
        finally:
            assert first.terminate() == 0
            first.proc.communicate(timeout=10)
        # the board is free again once the first has gone
        second = start_daemon(tmp_path / "runs_b", "--backend", "nidaqmx", "--grpc-target",
                              server.address, "--watchdog-s", "0", fast=False)
        assert second.terminate() == 0
        second.proc.communicate(timeout=10)
    finally:
        server.stop()


def _ni_driver_missing() -> bool:
    import nidaqmx.system

    try:
        _ = nidaqmx.system.System.local().driver_version
    except Exception:  # noqa: BLE001 - DaqNotFoundError, or no driver library at all
        return True
    return False


@pytest.mark.skipif(not _ni_driver_missing(), reason="NI-DAQmx is installed here")
def test_the_nidaqmx_backend_without_the_driver_is_one_line(tmp_path):
    out = daemon_cli("--runs-dir", str(tmp_path / "runs"), "--backend", "nidaqmx",
                     env={"SFDRIG_RUNTIME_DIR": str(tmp_path / "locks")})
    assert out.returncode == 2, out
    assert out.stdout == "" and "Traceback" not in out.stderr
    assert out.stderr.count("\n") == 1, out.stderr
    assert out.stderr.startswith("daemon: creating the AI task ")
    assert "NI-DAQmx driver not available: Could not find an installation of NI-DAQmx" \
        in out.stderr
    assert out.stderr.endswith("(install NI-DAQmx, give --grpc-target HOST:PORT of an NI gRPC "
                               "device server, or use --backend sim)\n")
