"""The daemon's status on the wire, key by key, against ``tests/storage/golden/heartbeat.json``
written from the daemon before the heartbeat was typed for its readers (issue 42): a status
reply's data, a heartbeat's ``status`` header, and their nested objects keep their keys, idle
and after a run. Values that move (pid, endpoints, sequence numbers) are not compared."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

from control.daemon.daemon import Daemon, DaemonConfig
from control.wire.client import CommandClient, Subscriber
from daq.channels import default_channel_map
from simulated_hw.backend import SimulatedBackend
from tests.control.daemon.test_daemon import ScriptEngine, ScriptSpec

GOLDEN = Path(__file__).parents[2] / "storage" / "golden" / "heartbeat.json"
NESTED = ("safety", "last_run", "board")


def _keys(status: dict[str, Any]) -> dict[str, Any]:
    return {"keys": list(status), **{k: list(status[k]) for k in NESTED}}


def _statuses(tmp_path: Path) -> dict[str, Any]:
    cfg = DaemonConfig(runs_dir=tmp_path / "runs", sndhwm=0, lossless_publish=True,
                       heartbeat_s=0.05)
    d = Daemon(SimulatedBackend(seed=3), default_channel_map(), cfg,
               engine_factory=ScriptEngine, spec_parser=ScriptSpec.model_validate)
    t = threading.Thread(target=d.serve, name="test-daemon-serve")
    t.start()
    try:
        with CommandClient(d.endpoints["command"]) as c, \
                Subscriber(d.endpoints["data"], topics=["status"]) as sub:
            sub.wait_connected()
            beat = sub.recv(timeout_s=10)
            assert beat is not None and beat.topic == "status"
            got = {"header": list(beat.header), "idle_reply": _keys(dict(c.status())),
                   "idle_heartbeat": _keys(beat.header["status"])}
            run_id = c.start_sweep({"blocks": 2, "block_size": 100}).data["run_id"]
            while (msg := sub.recv(timeout_s=10)) is not None:  # until the run's end is shown
                if msg.header["status"]["last_run"].get("run_id") == run_id:
                    got["after_run_heartbeat"] = _keys(msg.header["status"])
                    break
            got["after_run_reply"] = _keys(dict(c.status()))
            return got
    finally:
        d.stop("test over")
        t.join(30)


def test_the_status_keeps_its_keys_on_the_wire(tmp_path: Path) -> None:
    got = _statuses(tmp_path)
    want = json.loads(GOLDEN.read_text())
    assert got == want


if __name__ == "__main__":  # writes the golden description (once, from the untyped status)
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        GOLDEN.write_text(json.dumps(_statuses(Path(tmp)), indent=1) + "\n")


def test_the_asked_question_has_the_questions_fields() -> None:
    """The daemon sends a `Question` as its JSON dump, typed `AskedQuestion` for the readers."""
    from control.run.programs.operator import Entry, Question
    from control.wire.heartbeat import AskedEntry, AskedQuestion

    assert list(AskedQuestion.__annotations__) == list(Question.model_fields)
    assert list(AskedEntry.__annotations__) == list(Entry.model_fields)
