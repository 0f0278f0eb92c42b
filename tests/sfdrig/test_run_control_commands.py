"""`sfdrig pause`, `sfdrig resume` and `sfdrig status --reset` against the daemon in process
(its scripted engine: `tests.control.daemon.test_daemon`), through the CLI's own `main`."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from control.daemon.daemon import Daemon, DaemonConfig
from control.wire.client import CommandClient, Subscriber
from daq.channels import default_channel_map
from sfdrig.cli import main
from simulated_hw.backend import SimulatedBackend
from tests.control.daemon.test_daemon import ScriptEngine, ScriptSpec, wait_state


@pytest.fixture
def daemon(tmp_path: Path):
    cfg = DaemonConfig(runs_dir=tmp_path / "runs", sndhwm=0, lossless_publish=True,
                       heartbeat_s=0.05)
    d = Daemon(SimulatedBackend(seed=3), default_channel_map(), cfg,
               engine_factory=ScriptEngine, spec_parser=ScriptSpec.model_validate)
    t = threading.Thread(target=d.serve, name="test-daemon-serve")
    t.start()
    yield d
    d.stop("test over")
    t.join(30)


def test_pause_and_resume_from_the_command_line(daemon: Daemon, capsys):
    """Issue 39: refusals offered `pause`, but `sfdrig pause` was an invalid choice."""
    ep = ["--command-endpoint", daemon.endpoints["command"]]
    with CommandClient(daemon.endpoints["command"]) as c, \
            Subscriber(daemon.endpoints["data"], rcvhwm=0) as sub:
        sub.wait_connected()
        assert main(["pause", *ep]) == 1  # nothing to pause: refused, says what is allowed
        out = capsys.readouterr().out
        assert "'pause' is not allowed while idle (allowed now: start" in out
        # ... and which commands send that (`start` and `list_runs` are the wire's words)
        assert out.rstrip().endswith("; from the command line: sfdrig sweep, sfdrig structure, "
                                     "sfdrig pump on|off, sfdrig status, sfdrig runs"), out
        c.start_sweep({"blocks": 10, "hold_after": 3})
        assert ScriptEngine.last.held.wait(10)
        assert main(["pause", *ep]) == 0
        assert capsys.readouterr().out.startswith("paused (daemon state paused)")
        assert c.status()["state"] == "paused"
        assert main(["resume", *ep]) == 0
        assert capsys.readouterr().out.startswith("resumed (daemon state running)")
        assert c.status()["state"] == "running"
        assert main(["abort", *ep]) == 0
        wait_state(c, sub, "idle")


def test_reset_while_idle_is_a_no_op_not_a_refusal(daemon: Daemon, capsys):
    """Issue 39: `sfdrig status --reset` while idle said "reset refused (forbidden)", exit 1."""
    assert main(["status", "--reset", "--command-endpoint", daemon.endpoints["command"]]) == 0
    out = capsys.readouterr().out
    assert out.startswith("nothing to reset: the daemon is idle\n"
                          "board      simulated rig (in process)\nstate      idle\n"), out
