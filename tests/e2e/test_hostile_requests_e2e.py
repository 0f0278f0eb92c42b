"""Regression tests of issue 12: each defect's exact message, sent as ``[b"", message]`` from a
raw DEALER socket to a real daemon process. Every one gets a reply naming what is wrong (how
fast: `benchmarks/bench_command_replies.py`, target 1 s); the daemon stays up, its state does not
change, and no run file is created."""

from __future__ import annotations

import json

import pytest

from control.wire.client import CommandClient, Subscriber
from storage.reader import open_run
from tests.e2e.raw_dealer import RawDealer

pytestmark = pytest.mark.e2e

FREQ_POINTS = ', "freq_start_hz":20, "freq_stop_hz":500, "freq_points":10000'
LOADS_100 = json.dumps([20.0 + 0.1 * i for i in range(100)])

# (defect, message, error kind, text the error must contain)
REFUSED = [
    (1, r'{"cmd":"status","request_id":"\ud800"}', "invalid", "status.request_id"),
    (1, r'{"cmd":"list_runs","request_id":"\ud800"}', "invalid", "list_runs.request_id"),
    (1, r'{"cmd":"pump","on":true,"request_id":"\ud800"}', "invalid", "pump.request_id"),
    (1, r'{"cmd":"fly","request_id":"\ud800"}', "invalid", "unknown command 'fly'"),
    (2, '{"cmd":"start","spec":{"motion":"circular_forward","load_n":[20.0],"freq_start_hz":20,'
        '"freq_stop_hz":1e308,"freq_step_hz":50}}', "invalid", "at most 10,000"),
    (2, '{"cmd":"start","spec":{"motion":"circular_forward","load_n":[20.0],'
        '"freq_start_hz":1e308,"freq_stop_hz":20,"freq_step_hz":50}}', "invalid", "at most 10,000"),
    (2, '{"cmd":"start","spec":{"motion":"circular_forward","load_n":[20.0],'
        '"freq_start_hz":1e9,"freq_stop_hz":20,"freq_step_hz":50}}', "invalid", "at most 10,000"),
    (3, '{"cmd":"start","spec":{"motion":"x","load_n":' + LOADS_100 + FREQ_POINTS + '}}',
     "invalid", "1e+06 steps (100 targets x 1e+04 frequencies); at most 10,000"),
    (3, '{"cmd":"start","spec":{"motion":"x","load_n":[20.0],"freq_start_hz":20,'
        '"freq_stop_hz":200,"freq_step_hz":1.8e-4}}', "invalid", "at most 10,000"),
    (3, '{"cmd":"start","spec":{"motion":"x","load_n":[20.0],"freq_hz":[5.0,5.0,5.0],'
        '"settle_cycles":100000,"record_cycles":100000}}', "invalid", "at most 24 h"),
    (4, '{"cmd":"start","operator":"a\\u0000b","spec":{"motion":"x","load_n":[20.0],'
        '"freq_hz":[30.0]}}', "invalid", "start.operator: Value error, must not contain NUL"),
    (4, '{"cmd":"start","notes":"a\\u0000b","spec":{"motion":"x","load_n":[20.0],'
        '"freq_hz":[30.0]}}', "invalid", "start.notes: Value error, must not contain NUL"),
    (5, '{"cmd":"start","spec":{"motion":"x","amplitude_m":[2e-5],"freq_hz":[30.0],'
        '"control":{"initial_stiffness_n_per_m":Infinity}}}', "invalid",
     "start.spec.control.initial_stiffness_n_per_m: Input should be a finite number"),
    (7, '{"cmd":"start","spec":{"motion":"x","load_n":[20.0],"freq_hz":[30.0],'
        '"control":{"block_s":0.02,"ahead_blocks":3}}}', "invalid",
     "exceeds the 100 ms shutdown budget"),
    (8, '{"cmd":"start","spec":{"motion":"x","load_n":["20"],"freq_hz":[30.0]}}', "invalid",
     "start.spec.load_n.0: Input should be a valid number"),
    (8, '{"cmd":"start","spec":{"motion":"x","load_n":[true],"freq_hz":[30.0]}}', "invalid",
     "start.spec.load_n.0: Input should be a valid number"),
    (8, '{"cmd":"start","spec":{"motion":"x","load_n":[20.0],"freq_hz":[30.0],'
        '"settle_cycles":true}}', "invalid", "start.spec.settle_cycles: Input should be a valid "
                                             "integer"),
    (8, '{"cmd":"start","spec":{"motion":"x","load_n":[20.0],"freq_hz":[30.0],'
        '"lubricated":"no"}}', "invalid", "start.spec.lubricated: Input should be a valid boolean"),
    (8, '{"cmd":"start","spec":{"motion":"x","load_n":[20.0],"freq_start_hz":20,'
        '"freq_stop_hz":40,"freq_points":"3"}}', "invalid",
     "start.spec.freq_points: Input should be a valid integer"),
]


def test_each_defects_message_is_refused_at_once_and_changes_nothing(daemon_factory):
    d = daemon_factory()
    with CommandClient(d.command, timeout_s=10) as c, RawDealer(d.command) as raw:
        before = c.status()
        for defect, message, kind, text in REFUSED:
            reply, _ = raw.ask([b"", message.encode()])  # the reply's speed: the benchmark
            where = f"defect {defect}: {message[:90]}"
            assert reply["ok"] is False, where
            assert reply["error_kind"] == kind, (where, reply)
            assert text in reply["error"], (where, reply["error"])
            assert reply["state"] == "idle", where
            if "request_id" in message:
                assert reply["request_id"] == "\ufffd", where  # echoed, made encodable
        after = c.status()
    assert d.proc.poll() is None, "the daemon died"
    assert after["pid"] == before["pid"]
    for key in ("state", "run_id", "pump_on", "fault_reason", "last_run", "next_seq"):
        if key != "next_seq":
            assert after[key] == before[key], key
    assert after["next_seq"]["block"] == before["next_seq"]["block"], "a drive was written"
    assert list(d.runs_dir.glob("*.h5")) == [], "a refused start created a run file"
    assert d.terminate() == 0


@pytest.mark.paced
def test_an_abort_with_a_nul_in_its_reason_is_not_refused_the_reason_is_replaced(
        daemon_factory):
    """Issue 21: an abort must never be refused for its text (it was, as invalid)."""
    d = daemon_factory(fast=False)  # paced: the run is still going when the abort arrives
    spec = {"motion": "x", "load_n": [40.0], "freq_hz": [70.0, 80.0], "settle_cycles": 20,
            "record_cycles": 400, "control": {"block_s": 0.0125, "ahead_blocks": 3}}
    with CommandClient(d.command, timeout_s=10) as c, RawDealer(d.command) as raw, \
            Subscriber(d.data, topics=["block", "event"], rcvhwm=0) as sub:
        sub.wait_connected()
        run_id = c.start_sweep(spec).data["run_id"]
        while (msg := sub.recv(timeout_s=60)) is not None and msg.topic != "block":
            pass
        assert msg is not None, "no block while waiting for the run"
        long_tail = "x" * 600
        reply = raw.request(r'{"cmd":"abort","reason":"stop\u0000now \ud800' + long_tail
                            + r'","request_id":"\udc00"}')
        assert reply["ok"] is True and reply["state"] == "aborting", reply
        expected = ("stop\ufffdnow \ufffd" + "x" * 490 + " [reason sanitised: 1 NUL replaced "
                    "by U+FFFD; 1 lone surrogate replaced by U+FFFD; cut from 610 to 500 "
                    "characters]")
        while (msg := sub.recv(timeout_s=60)) is not None:
            if msg.topic == "event" and msg.header["message"].startswith(f"run {run_id} "):
                break
        assert msg is not None
        assert msg.header["message"] == f"run {run_id} aborted: {expected}"
        status = c.status()
    assert status["state"] == "idle" and status["fault_reason"] == ""
    with open_run(d.runs_dir / f"{run_id}.h5") as run:
        assert run.status == "aborted"
        assert run.attrs["status_reason"] == expected
    assert d.terminate() == 0
