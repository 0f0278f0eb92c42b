"""One step numbering for people (issue 39): `sweep`'s table counted steps from 1, its abort
line and `watch` from 0. Every line a person reads says "step 2/5" for the run file's index 1."""

from __future__ import annotations

from typing import Any

from control.wire.sweep_spec import SweepSpec
from sfdrig.cli import main
from tests.fake_daemon import FakeDaemon

PROGRESS = {"state": "running", "step_index": 1, "steps_total": 2, "freq_hz": 80.0,
            "target_value": 40.0, "updates": 3, "sample": 9000, "steps_done": 1,
            "dwell": "converge", "max_updates": 10}


class RunningDaemon(FakeDaemon):
    """A stand-in daemon in the second of two steps."""

    def status(self) -> dict[str, Any]:
        return {"state": "running", "run_id": "R1", "run_path": "runs/R1.h5", "pump_on": False,
                "samples": 9000, "sample_rate_hz": 10000.0, "progress": PROGRESS,
                "endpoints": {"command": self.command, "data": self.data}}


def test_a_steps_description_counts_from_one_of_the_total():
    steps = SweepSpec(motion="circular_forward", load_n=[40.0],
                      freq_hz=[20.0, 80.0]).steps()
    assert [s.index for s in steps] == [0, 1]  # the file's and the wire's index
    assert steps[1].describe() == "step 2/2 (circular_forward, 40 N load, 80 Hz)"


def test_watch_and_status_show_the_step_counted_from_one(capsys):
    daemon = RunningDaemon("A")
    try:
        conn = ["--command-endpoint", daemon.command]
        assert main(["watch", "--data-endpoint", daemon.data, *conn, "--count", "1",
                     "--interval", "0.1"]) == 0
        head = capsys.readouterr().out.splitlines()[0]
        assert "| step 2: " in head and "80.0 Hz" in head and "step_index" not in head, head
        assert main(["status", *conn]) == 0
        progress = [ln for ln in capsys.readouterr().out.splitlines()
                    if ln.startswith("progress")]
        assert progress == ["progress   sweep [##########..........] 1/2 steps done | step 2: "
                            "  80.0 Hz updates [##......] 3/10 | running"], progress
    finally:
        daemon.stop()
