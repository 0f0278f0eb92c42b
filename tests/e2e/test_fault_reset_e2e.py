"""After a fault, `sfdrig status --reset` returns the daemon to idle and the next sweep runs
(issue 21's report: every later start refused until a restart). Real processes: the simulated
board's server with an emergency-stop input, the daemon on it, the CLI; no sleeps."""

from __future__ import annotations

import signal

import pytest

from control.wire.client import Subscriber
from storage.reader import open_run
from tests.e2e.test_board_safety_e2e import (
    LONGER_X,
    _wait_for_event,
    _wait_for_step,
    estop_rig,
    sfdrig,
)

pytestmark = pytest.mark.e2e


def test_status_reset_after_a_fault_and_the_next_sweep_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("SFDRIG_RUNTIME_DIR", str(tmp_path / "locks"))
    server, d = estop_rig(tmp_path)
    conn = ["--runs-dir", str(d.runs_dir)]
    try:
        with Subscriber(d.data, rcvhwm=0) as sub:
            sub.wait_connected()
            out = sfdrig("sweep", "--no-follow", "--set", f"freq_hz={LONGER_X['freq_hz']}",
                         *[a for k in ("motion", "load_n", "settle_cycles", "record_cycles")
                           for a in ("--set", f"{k}={LONGER_X[k]!r}")], *conn)
            assert out.returncode == 0, out
            run_id = out.stdout.split()[1]
            _wait_for_step(sub, run_id)  # a whole step recorded: the drives are up
            server.proc.send_signal(signal.SIGUSR1)  # the emergency stop
            ended = _wait_for_event(sub, f"run {run_id} ")
            assert f"run {run_id} failed" in ended, ended

        out = sfdrig("status", *conn)
        assert "state      fault" in out.stdout
        assert ("reset it with `sfdrig status --reset`" in out.stdout), out.stdout
        out = sfdrig("sweep", "--no-follow", "--set", "motion='x'", "--set", "load_n=[30.0]",
                     "--set", "freq_hz=[40.0]", *conn)
        assert out.returncode == 1 and "Traceback" not in out.stderr
        assert "(allowed now: reset, pump, status, list_runs); reset the fault with " \
               "`sfdrig status --reset`" in out.stdout, out.stdout
        out = sfdrig("status", "--reset", *conn)  # still pressed: refused, says why
        assert out.returncode == 1 and "emergency stop is still pressed" in out.stdout

        server.proc.send_signal(signal.SIGUSR2)
        server.next_line("emergency stop released", timeout_s=10)
        out = sfdrig("status", "--reset", *conn)
        assert out.returncode == 0, out
        assert out.stdout.startswith("fault acknowledged\nboard      simulated nidaqmx device "
                                     "Dev1 via gRPC "), out.stdout
        assert "\nstate      idle\n" in out.stdout, out.stdout
        for freq in (40.0, 50.0):  # every later sweep runs, not only the first
            out = sfdrig("sweep", "--set", "motion='x'", "--set", "load_n=[30.0]", "--set",
                         f"freq_hz=[{freq}]", "--set", "settle_cycles=5", "--set",
                         "record_cycles=10", *conn)
            assert out.returncode == 0, out.stdout + out.stderr
            assert out.stdout.splitlines()[-1].endswith(" completed (1 steps)"), out.stdout
            with open_run(d.runs_dir / f"{out.stdout.split()[1]}.h5") as run:
                assert run.status == "completed" and [s["freq_hz"] for s in run.steps] == [freq]
    finally:
        d.terminate()
        d.proc.communicate(timeout=10)
        server.stop()
