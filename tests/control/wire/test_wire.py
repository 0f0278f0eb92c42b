"""The wire protocol: request validation names what is wrong, replies round-trip, block frames
decode to the array that was sent, and the publisher numbers every topic without gaps."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zmq
from hypothesis import given
from hypothesis import strategies as st

from control.wire.client import GapCounter, Subscriber
from control.wire.protocol import (
    DaemonState,
    ErrorKind,
    PumpRequest,
    Reply,
    RequestError,
    StartRequest,
    decode_block,
    parse_request,
)
from control.wire.publisher import Publisher
from storage.records import StepRecord


@pytest.mark.parametrize(("frame", "kind", "message"), [
    (b"\xff", ErrorKind.MALFORMED, "request is not JSON"),
    (b"[]", ErrorKind.MALFORMED, "must be a JSON object, got list"),
    (b'{"cmd": "launch"}', ErrorKind.INVALID, "unknown command 'launch'"),
    (b'{"cmd": "pump"}', ErrorKind.INVALID, "pump.on: Field required"),
    (b'{"cmd": "pump", "on": 1}', ErrorKind.INVALID, "pump.on: Input should be a valid boolean"),
    (b'{"cmd": "pump", "on": "yes"}', ErrorKind.INVALID, "(got 'yes')"),
    (b'{"cmd": "status", "force": true}', ErrorKind.INVALID, "status.force: Extra inputs"),
    (b'{"cmd": "start", "spec": []}', ErrorKind.INVALID, "start.spec: Input should be a valid"),
    (b"x" * 1_000_001, ErrorKind.MALFORMED, "exceeds 1000000 bytes"),
])
def test_bad_requests_name_the_problem(frame, kind, message):
    with pytest.raises(RequestError) as info:
        parse_request(frame)
    assert info.value.kind is kind
    assert message in str(info.value)


def test_valid_requests_parse_to_their_models():
    assert parse_request(b'{"cmd": "pump", "on": false, "request_id": "r1"}') == PumpRequest(
        cmd="pump", on=False, request_id="r1")
    start = parse_request(b'{"cmd": "start", "spec": {"freq_hz": [20.0]}, "operator": "ana"}')
    assert isinstance(start, StartRequest)
    assert start.spec == {"freq_hz": [20.0]} and start.operator == "ana"


@pytest.mark.parametrize(("frame", "reason"), [
    (rb'{"cmd": "abort", "reason": "stop\u0000now"}',
     "stop\ufffdnow [reason sanitised: 1 NUL replaced by U+FFFD]"),
    (rb'{"cmd": "abort", "reason": "\ud800\u0000\u0000", "request_id": "\udc00"}',
     "\ufffd\ufffd\ufffd [reason sanitised: 2 NULs replaced by U+FFFD; 1 lone surrogate "
     "replaced by U+FFFD]"),
    (b'{"cmd": "abort", "reason": "' + b"x" * 501 + b'"}',
     "x" * 500 + " [reason sanitised: cut from 501 to 500 characters]"),
    (b'{"cmd": "abort", "reason": ""}', "operator abort"),
    (b'{"cmd": "abort", "reason": 7, "extra": true}',
     "operator abort [reason sanitised: a JSON number was sent, not text]"),
])
def test_an_abort_is_never_refused_for_its_reason(frame, reason):
    req = parse_request(frame)
    assert req.cmd == "abort" and req.reason == reason
    assert "\x00" not in req.request_id and len(req.request_id) <= 128


def test_request_id_is_kept_on_invalid_requests():
    with pytest.raises(RequestError) as info:
        parse_request(b'{"cmd": "pump", "request_id": "abc"}')
    assert info.value.request_id == "abc" and info.value.cmd == "pump"


@given(st.binary(max_size=64))
def test_arbitrary_bytes_never_escape_as_other_errors(frame):
    try:
        req = parse_request(frame)
    except RequestError as err:
        assert err.kind in (ErrorKind.MALFORMED, ErrorKind.INVALID) and str(err)
    else:  # a few byte strings are valid requests, e.g. b'{"cmd":"status"}'
        assert req.cmd in ("status", "list_runs", "pause", "resume", "abort", "reset")


def test_reply_round_trip():
    r = Reply(ok=False, cmd="pause", state=DaemonState.IDLE, error_kind=ErrorKind.FORBIDDEN,
              error="'pause' is not allowed while idle")
    assert Reply.from_frame(r.to_frame()) == r


def test_decode_block_checks_the_payload_length():
    a = np.arange(12.0).reshape(3, 4)
    header = {"shape": [3, 4], "seq": 7}
    np.testing.assert_array_equal(decode_block(header, a.tobytes()), a)
    with pytest.raises(ValueError, match="block seq 7: payload holds 11 values"):
        decode_block(header, a.tobytes()[:-8])


def test_gap_counter_counts_lost_messages_per_topic():
    g = GapCounter()
    assert [g.see("block", s) for s in (5, 6, 9, 10)] == [0, 0, 2, 0]
    assert g.see("step", 0) == 0
    assert g.lost == {"block": 2}


def test_publisher_frames_carry_run_id_and_consecutive_seq():
    ctx = zmq.Context()
    pub_sock = ctx.socket(zmq.PUB)
    pub_sock.bind("tcp://127.0.0.1:*")
    endpoint = pub_sock.getsockopt_string(zmq.LAST_ENDPOINT)
    pub = Publisher(pub_sock, ["a", "b", "d"], 2, 1000.0)
    try:
        with Subscriber(endpoint, rcvhwm=0, context=ctx) as sub:
            # heartbeats until the subscription is live (no sleep: wait on the message)
            while True:
                pub.publish_status({"state": "idle"})
                if sub.recv(timeout_s=0.05) is not None:
                    break
            pub.set_run("run-1")
            rng = np.random.default_rng(1)
            sent = []
            for i in range(20):
                ai, ao = rng.normal(size=(2, 50)), rng.normal(size=(1, 50))
                sent.append(np.vstack([ai, ao]))
                pub.on_block(50 * i, ai, ao)
            pub.on_step(StepRecord.from_wire({"index": 0, "freq_hz": 20.0}))
            got, step = [], None
            while step is None:
                msg = sub.recv(timeout_s=10)
                assert msg is not None
                if msg.topic == "block":
                    assert msg.header["run_id"] == "run-1"
                    assert msg.header["channels"] == ["a", "b", "d"]
                    got.append(msg)
                elif msg.topic == "step":
                    step = msg.header["step"]
            assert [m.header["seq"] for m in got] == list(range(20))
            assert [m.header["first_sample"] for m in got] == [50 * i for i in range(20)]
            for m, a in zip(got, sent, strict=True):
                np.testing.assert_array_equal(m.array, a)
            assert (step["index"], step["freq_hz"], step["converged"]) == (0, 20.0, False)
            assert sub.lost == {}
            assert json.loads(json.dumps(pub.sequence_numbers()))["block"] == 20
    finally:
        pub.close()
        pub_sock.close()
        ctx.term()
