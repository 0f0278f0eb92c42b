"""One tool per board, and the board named everywhere, end to end: real processes, `sfdrig
sim-server` behind the real nidaqmx package. While a daemon holds the board (idle), `commission`,
`channels live` and `channels check` on the same gRPC target are refused in one line naming the
daemon's pid and command line, exit 2, and the daemon goes on undisturbed; while `channels live`
holds it, a daemon is refused naming that; once the holder has gone, they run. The daemon names
its board in its first line, `sfdrig status` (text and JSON) and daemon.json. Synchronisation on
messages (first lines, a table printed, exit codes), no sleeps."""

from __future__ import annotations

import json
import selectors
import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest

from tests.e2e.conftest import REPO_ROOT, start_daemon
from tests.e2e.test_board_safety_e2e import SimServer

pytestmark = pytest.mark.e2e

EXAMPLE = REPO_ROOT / "examples" / "channels_report_rig.toml"
BUSY = "stop it first (one tool at a time on a board)"


def sfdrig(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sfdrig", *args], capture_output=True,
                          text=True, timeout=120, cwd=REPO_ROOT)


@pytest.fixture(scope="module")
def server() -> Iterator[SimServer]:
    server = SimServer("--fast", "--channels", str(EXAMPLE))
    yield server
    server.stop()


@pytest.fixture(autouse=True)
def _own_locks(tmp_path, monkeypatch):
    """This test's board locks (start_daemon and `sfdrig` inherit the environment)."""
    monkeypatch.setenv("SFDRIG_RUNTIME_DIR", str(tmp_path / "locks"))


def test_a_daemon_idle_on_the_board_refuses_every_other_tool(server, tmp_path):
    addr = server.address
    board = f"nidaqmx device Dev1 via gRPC {addr}"  # as a tool names it before it connects
    named = f"simulated {board}"  # once connected: the sim-server's device says it is simulated
    runs = tmp_path / "runs"
    daemon = start_daemon(runs, "--backend", "nidaqmx", "--grpc-target", addr, "--channels",
                          str(EXAMPLE), "--watchdog-s", "0", fast=False)
    try:
        assert daemon.board == named  # its first line
        holder = (f"pid {daemon.proc.pid} (sfdrig daemon --runs-dir {runs} --backend nidaqmx "
                  f"--grpc-target {addr} --channels {EXAMPLE} --watchdog-s 0), "
                  f"command={daemon.command} data={daemon.data}, runs dir {runs}")
        host, port = addr.rsplit(":", 1)
        alias = f"{'localhost' if host == '127.0.0.1' else '127.0.0.1'}:{port}"
        for name, args in (
                ("commission", ["commission", str(EXAMPLE), "--backend", "nidaqmx", "--yes",
                                "--out", str(tmp_path / "commission")]),
                ("channels live", ["channels", "live", str(EXAMPLE), "--once"]),
                ("channels check", ["channels", "check", str(EXAMPLE)])):
            # one board, however its server is named
            for target in (addr, alias) if name == "channels check" else (addr,):
                out = sfdrig(*args, "--grpc-target", target)
                assert (out.returncode, out.stdout) == (2, ""), out
                assert out.stderr == (f"{name}: nidaqmx device Dev1 via gRPC {target} is in "
                                      f"use by {holder}: {BUSY}\n")
        assert not (tmp_path / "commission").exists()  # refused before it wrote anything
        # the daemon is undisturbed, and names its board
        status = sfdrig("status", "--runs-dir", str(runs), "--json")
        st = json.loads(status.stdout)
        assert (st["state"], st["pid"]) == ("idle", daemon.proc.pid)
        assert st["board"] == {"backend": "nidaqmx", "device": "Dev1", "grpc_target": addr,
                               "description": named}
        text = sfdrig("status", "--runs-dir", str(runs)).stdout.splitlines()
        assert text[0] == f"board      {named}"
        assert json.loads((runs / "daemon.json").read_text())["board"] == st["board"]
    finally:
        assert daemon.terminate() == 0
        daemon.proc.communicate(timeout=10)
    # once the daemon has gone, the board is free
    live = sfdrig("channels", "live", str(EXAMPLE), "--once", "--grpc-target", addr)
    assert live.returncode == 0, live
    assert [line.split()[0] for line in live.stdout.splitlines()[1:15]] == [
        "fx", "fy", "x1", "x2", "y1", "y2", "ax", "ay", "p_in", "p_rec", "q_in", "q_out",
        "t_oil", "hammer"]
    check = sfdrig("channels", "check", str(EXAMPLE), "--grpc-target", addr)
    assert (check.returncode, check.stdout.splitlines()[-1]) == (
        0, f"{EXAMPLE}: fits Dev1 on {addr}: 14 inputs, 2 drives, 1 relay, an emergency stop"), \
        check


def test_a_tool_that_is_not_a_daemon_holds_the_board_too(server, tmp_path):
    addr = server.address
    live = subprocess.Popen([sys.executable, "-m", "sfdrig", "channels", "live", str(EXAMPLE),
                             "--grpc-target", addr, "--period-s", "0.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=REPO_ROOT)
    try:
        sel = selectors.DefaultSelector()
        sel.register(live.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
        assert sel.select(60), "channels live printed nothing"
        assert live.stdout.readline().startswith("input")  # type: ignore[union-attr]
        sel.close()
        holder = f"pid {live.pid} (sfdrig channels live {EXAMPLE} --grpc-target {addr} " \
                 "--period-s 0.5)"
        out = sfdrig("channels", "check", str(EXAMPLE), "--grpc-target", addr)
        assert (out.returncode, out.stderr) == (
            2, f"channels check: nidaqmx device Dev1 via gRPC {addr} is in use by {holder}: "
               f"{BUSY}\n"), out
        out = subprocess.run([sys.executable, "-m", "sfdrig", "daemon", "--runs-dir",
                              str(tmp_path / "runs"), "--backend", "nidaqmx", "--grpc-target",
                              addr, "--watchdog-s", "0"], capture_output=True, text=True,
                             timeout=120, cwd=REPO_ROOT)
        assert (out.returncode, out.stdout) == (1, ""), out
        assert out.stderr == (f"daemon: nidaqmx device Dev1 via gRPC {addr} is in use by "
                              f"{holder}: stop it first\n")
    finally:
        live.send_signal(signal.SIGINT)
        _, err = live.communicate(timeout=30)
    assert (live.returncode, err) == (0, "channels live: stopped\n")
    # free again: the daemon starts, and names its board as the device says it is (the
    # sim-server's device answers DevIsSimulated yes: a rehearsal never reads as the rig)
    daemon = start_daemon(tmp_path / "runs2", "--backend", "nidaqmx", "--grpc-target", addr,
                          "--watchdog-s", "0", fast=False)
    assert daemon.board == f"simulated nidaqmx device Dev1 via gRPC {addr}"
    assert daemon.terminate() == 0
    daemon.proc.communicate(timeout=10)
