"""The daemon's status on the wire, key by key, against ``tests/storage/golden/heartbeat.json``,
written once (by the commit that added this test) from the daemon before the heartbeat was
typed for its readers (issue 42): a status reply's data, a heartbeat's ``status`` header, and
their nested objects keep their keys, idle and after a run. Values that move (pid, endpoints,
sequence numbers) are not compared."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from control.daemon.daemon import Daemon
from control.wire.client import CommandClient, Subscriber
from tests.control.daemon.test_daemon import daemon as daemon_in_process  # noqa: F401

GOLDEN = Path(__file__).parents[2] / "storage" / "golden" / "heartbeat.json"
NESTED = ("safety", "last_run", "board")


def _keys(status: dict[str, Any]) -> dict[str, Any]:
    return {"keys": list(status), **{k: list(status[k]) for k in NESTED}}


def _statuses(d: Daemon) -> dict[str, Any]:
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


def test_the_status_keeps_its_keys_on_the_wire(daemon_in_process: Daemon) -> None:  # noqa: F811
    """``daemon_in_process``: test_daemon's fixture (a daemon with a scripted engine)."""
    got = _statuses(daemon_in_process)
    want = json.loads(GOLDEN.read_text())
    assert got == want


def test_the_asked_question_has_the_questions_fields() -> None:
    """The daemon sends a `Question` as its JSON dump, typed `AskedQuestion` for the readers."""
    from control.run.programs.operator import Entry, Question
    from control.wire.heartbeat import AskedEntry, AskedQuestion

    assert list(AskedQuestion.__annotations__) == list(Question.model_fields)
    assert list(AskedEntry.__annotations__) == list(Entry.model_fields)
