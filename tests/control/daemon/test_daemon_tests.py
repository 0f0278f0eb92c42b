"""The daemon runs the structure tests with the operator in the loop: `start_test`, the pending
question in the status, `answer` checked by the daemon, pause refused, abort the safe way."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from control.daemon.daemon import Daemon, DaemonConfig
from control.wire.client import CommandClient
from daq.channels import default_channel_map
from sfdrig.simulated_operator import SimulatedHands
from simulated_hw.backend import SimulatedBackend
from storage.reader import open_run


@pytest.fixture
def daemon(tmp_path: Path):
    backend = SimulatedBackend(seed=3)
    cfg = DaemonConfig(runs_dir=tmp_path / "runs", sndhwm=0, lossless_publish=True,
                       heartbeat_s=0.05)
    d = Daemon(backend, default_channel_map(), cfg, hands=SimulatedHands(backend))
    t = threading.Thread(target=d.serve, name="test-daemon-serve")
    t.start()
    yield d
    d.stop("test over")
    t.join(30)


def until(client: CommandClient, what, timeout_s: float = 60.0) -> dict:  # noqa: ANN001
    """The first status reply for which ``what(status)`` holds (polled on the socket)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        st = client.status()
        if what(st):
            return st
    raise TimeoutError("the daemon never got there")


def test_refusals_name_what_is_wrong(daemon: Daemon) -> None:
    with CommandClient(daemon.endpoints["command"]) as c:
        r = c.request("answer", check=False, question_id=1, choice="ok")
        assert not r.ok and r.error == "answer: no test is asking anything"
        r = c.request("start_test", check=False, test="static", spec={"repeats": 0})
        assert not r.ok and r.error_kind == "invalid"
        assert r.error.startswith("start_test.spec.repeats: Input should be greater than")
        r = c.request("start_test", check=False, test="shake")
        assert not r.ok and "start_test.test" in r.error
        c.pump(True)
        r = c.request("start_test", check=False, test="impact")
        assert not r.ok and r.error == ("start_test: the impact test is dry (no journal, no "
                                        "oil): switch the pump off first")
        c.pump(False)
        assert list(daemon.cfg.runs_dir.glob("*.h5")) == []


def test_a_test_asks_through_the_status_and_stops_safely_on_abort(daemon: Daemon) -> None:
    with CommandClient(daemon.endpoints["command"]) as c:
        r = c.request("start_test", test="static", spec={"axes": ["x"], "repeats": 1},
                      operator="tester")
        run_id = r.data["run_id"]
        st = until(c, lambda s: s["question"] is not None)
        q = st["question"]
        assert q["where"] == "static setup" and q["choices"] == ["ok", "abort"]
        r = c.request("pause", check=False)
        assert not r.ok and "does not pause" in r.error
        r = c.request("answer", check=False, question_id=q["id"] + 1, choice="ok")
        assert not r.ok and f"#{q['id']} is" in r.error
        c.request("answer", question_id=q["id"], choice="ok")
        st = until(c, lambda s: s["question"] is not None and s["question"]["id"] > q["id"])
        assert "accept this point?" in st["question"]["prompt"]
        params = daemon.backend.rig.params
        assert not params.journal_in  # the journal is out: no seal, no wall, no film
        c.request("answer", question_id=st["question"]["id"], choice="ok")
        st = until(c, lambda s: s["question"] is not None
                   and s["question"]["where"].startswith("static x -40 N"))
        c.abort("enough")
        st = until(c, lambda s: s["state"] == "idle")
    last = st["last_run"]
    assert last["run_id"] == run_id and last["status"] == "aborted"
    params = daemon.backend.rig.params
    assert params.journal_in and params.seal.enabled  # the journal is back, its seal too
    with open_run(Path(last["path"])) as run:
        assert run.kind == "static" and run.attrs["operator"] == "tester"
        assert len(run.steps) == 1
        assert run.channel("shaker_x")[-1] == 0.0
        messages = [e["message"] for e in run.events if e["kind"] == "operator"]
    assert any("refused choice 'ok': question #2 is not pending (#1 is)" in m
               for m in messages)


def test_a_test_whose_client_stops_renewing_its_lease_is_aborted(tmp_path: Path) -> None:
    """The operator's lease (`control.daemon.lease`): renewed, the test waits at its question;
    unrenewed for the lease (1 s here), it is aborted the safe way with the reason."""
    backend = SimulatedBackend(seed=3)
    cfg = DaemonConfig(runs_dir=tmp_path / "runs", sndhwm=0, lossless_publish=True,
                       heartbeat_s=0.05, operator_lease_s=1.0)
    d = Daemon(backend, default_channel_map(), cfg, hands=SimulatedHands(backend))
    t = threading.Thread(target=d.serve, name="test-daemon-serve")
    t.start()
    try:
        with CommandClient(d.endpoints["command"]) as c:
            r = c.request("start_test", test="static", spec={"axes": ["x"], "repeats": 1,
                                                            "forces_n": [-40.0]})
            lease = r.data["lease"]
            assert r.data["lease_s"] == 1.0 and len(lease) == 16
            other = c.request("alive", check=False, lease="0" * 16)
            assert not other.ok and other.error_kind == "forbidden"
            assert other.error == ("alive: no running test holds this lease (the test has "
                                   "ended, or another client started it)")

            def renewing(what):  # noqa: ANN001, ANN202
                return lambda s: c.request("alive", lease=lease).ok and what(s)

            st = until(c, renewing(lambda s: s["question"] is not None))
            c.request("answer", question_id=st["question"]["id"], choice="ok")
            st = until(c, renewing(lambda s: s["question"] is not None
                                   and "accept this point?" in s["question"]["prompt"]))
            # renewed: never silent for longer than a status round trip
            assert st["operator_lease"]["lease_s"] == 1.0
            assert st["operator_lease"]["silent_s"] < 0.5
            silent_from = time.monotonic()  # the client is gone: no more renewals
            st = until(c, lambda s: s["state"] == "idle")
            took = time.monotonic() - silent_from
            late = c.request("alive", check=False, lease=lease)
    finally:
        d.stop("test over")
        t.join(30)
    assert 1.0 - 0.1 <= took <= 1.0 + 1.5, took  # the lease, then a beat, a block, the fade
    last = st["last_run"]
    assert last["status"] == "aborted" and st["operator_lease"] is None
    assert "operator lost: no heartbeat for 1." in last["reason"]
    assert "(the lease is 1 s: the client that started the test hung up or was killed)" \
        in last["reason"]
    assert not late.ok and "no running test holds this lease" in late.error
    with open_run(Path(last["path"])) as run:
        assert run.attrs["status"] == "aborted" and run.attrs["status_reason"] == last["reason"]
        fx, drive = run.channel("fx"), run.channel("shaker_x")
        (abort,) = [e for e in run.events if e["kind"] == "abort"]
    held = fx[abort["sample"] - 1000:abort["sample"]]
    assert np.mean(held) == pytest.approx(-40.0, abs=4.0)  # it held the load until then
    assert np.all(drive[-100:] == 0.0)
