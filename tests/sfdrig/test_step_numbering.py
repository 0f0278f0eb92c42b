"""One step numbering for people (issue 39): `sweep`'s table counted steps from 1, its abort
line and `watch` from 0. Every line a person reads says "step 2/5" for the run file's index 1."""

from __future__ import annotations

from typing import Any

import pytest

from control.wire.sweep_spec import SweepSpec
from sfdrig.cli import main
from tests.fake_daemon import FakeDaemon, heartbeat

PROGRESS = {"state": "running", "step_index": 1, "steps_total": 2, "freq_hz": 80.0,
            "target_value": 40.0, "updates": 3, "sample": 9000, "steps_done": 1,
            "dwell": "converge", "max_updates": 10}


class RunningDaemon(FakeDaemon):
    """A stand-in daemon in the second of two steps."""

    def status(self) -> dict[str, Any]:
        return heartbeat(state="running", run_id="R1", run_path="runs/R1.h5", samples=9000,
                         progress=PROGRESS,
                         endpoints={"command": self.command, "data": self.data})


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


def test_identify_skip_lines_and_export_steps_count_from_one():
    """`identify`'s skip lines and `export --steps` once counted from 0: the file's index 0 is
    "step 1" to a person, and `--steps 2-3` the file's steps 1 and 2."""
    from analysis.errors import Skipped, summarise_skipped
    from storage.exporters.common import ExportError, parse_steps

    one = Skipped("R", "lubricated", "only 2 whole cycle(s)", step=0, channel="fx")
    assert one.message == "run R, step 1, channel fx [lubricated]: only 2 whole cycle(s)"
    assert one.to_dict()["step"] == 0  # the JSON keeps the file's index beside the message
    many = [Skipped("R", "dry", f"signal 'ay' missing in {i}", i, "ay", cause="no ay")
            for i in (0, 1, 2, 5)]
    assert summarise_skipped(many) == ["run R, channel ay [dry]: no ay (4 items in steps "
                                       "1-3, 6)"]
    assert parse_steps("1", 3, "r.h5") == (0, 0) and parse_steps("2-3", 3, "r.h5") == (1, 2)
    for bad in ("0", "3-4"):
        with pytest.raises(ExportError) as err:
            parse_steps(bad, 3, "r.h5")
        assert str(err.value) == f"r.h5: --steps {bad}: the run has steps 1-3 (counted from 1)"
