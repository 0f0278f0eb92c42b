"""A stand-in daemon for clients' tests: a PUB socket sending status heartbeats every 50 ms and a
ROUTER answering status, on random loopback ports; ``raw(frames)`` publishes anything (the
malformed messages a client must survive)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import zmq

from control.wire.protocol import Reply, encode_header


def until(condition: Callable[[], bool], timeout_s: float = 10.0) -> float:
    """Seconds until ``condition()`` held (fails after ``timeout_s``)."""
    t0 = time.monotonic()
    while not condition():
        assert time.monotonic() - t0 < timeout_s, "condition not met in time"
        time.sleep(0.01)
    return time.monotonic() - t0


def heartbeat(**fields: Any) -> dict[str, Any]:
    """An idle daemon's status, every field of `Heartbeat`, with ``fields`` over it."""
    return {"state": "idle", "allowed": ["start"], "run_id": "", "run_path": "", "progress": {},
            "samples": 0, "samples_flushed": 0, "pump_on": False, "film_drains_for_s": 0.0,
            "safety": {"radial_clearance_m": 63.5e-6, "displacement_limit_m": 50e-6,
                       "load_limit_n": 448.0, "drive_limit_v": 5.0},
            "tolerance": None, "fault_reason": "", "idle_incidents": 0, "question": None,
            "operator_lease": None, "last_run": {}, "recovered_at_start": [], "next_seq": {},
            "dropped_in_daemon": 0, "sample_rate_hz": 10000.0, "channels": [], "units": {},
            "drives": [], "input_ranges": {}, "endpoints": {}, "board": {}, "pid": 0, **fields}


class FakeDaemon:
    """Heartbeats on a PUB socket every 50 ms and status replies on a ROUTER, until stopped;
    ``raw(frames)`` publishes anything."""

    def __init__(self, name: str, answer: bool = True) -> None:
        ctx = zmq.Context.instance()
        self.name = name
        self.pub = ctx.socket(zmq.PUB)
        self.pub.linger = 0
        self.pub.bind("tcp://127.0.0.1:*")
        self.router = ctx.socket(zmq.ROUTER)
        self.router.linger = 0
        self.router.bind("tcp://127.0.0.1:*")
        self.data = self.pub.getsockopt_string(zmq.LAST_ENDPOINT)
        self.command = self.router.getsockopt_string(zmq.LAST_ENDPOINT)
        self.answer = answer
        self.beating = threading.Event()
        self.beating.set()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def status(self) -> dict[str, Any]:
        return heartbeat(who=self.name,
                         endpoints={"command": self.command, "data": self.data})

    def send(self, topic: str, header: dict[str, Any], payload: bytes = b"") -> None:
        with self._lock:
            header = {**header, "seq": self._seq.get(topic, 0), "topic": topic}
            self._seq[topic] = header["seq"] + 1
            self.pub.send_multipart([topic.encode(), encode_header(header), payload])

    def raw(self, frames: list[bytes]) -> None:
        with self._lock:
            self.pub.send_multipart(frames)

    def _run(self) -> None:
        poller = zmq.Poller()
        poller.register(self.router, zmq.POLLIN)
        next_beat = 0.0
        while not self._stop.is_set():
            if self.beating.is_set() and time.monotonic() >= next_beat:
                self.send("status", {"status": self.status(), "run_id": ""})
                next_beat = time.monotonic() + 0.05
            if dict(poller.poll(10)).get(self.router):
                ident, *_, body = self.router.recv_multipart()
                req = json.loads(body)
                if self.answer:
                    reply = Reply(ok=True, cmd=req["cmd"], request_id=req["request_id"],
                                  state="idle", data=self.status())
                    self.router.send_multipart([ident, b"", reply.to_frame()])

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.pub.close(0)
        self.router.close(0)


@pytest.fixture
def fakes() -> Iterator[Callable[..., FakeDaemon]]:
    made: list[FakeDaemon] = []

    def make(name: str, answer: bool = True) -> FakeDaemon:
        made.append(FakeDaemon(name, answer))
        return made[-1]

    yield make
    for f in made:
        if not f._stop.is_set():
            f.stop()


def block_message(first: int, n: int = 100) -> tuple[dict[str, Any], bytes]:
    """A block message (header, payload) of 3 rows (fx, x1, shaker_x) from ``first``."""
    rows = np.vstack([np.sin(np.arange(first, first + n) * 0.1)] * 3)
    header = {"first_sample": first, "n_samples": n, "shape": [3, n], "n_ai": 2,
              "channels": ["fx", "x1", "shaker_x"], "sample_rate_hz": 1000.0,
              "t_acquired": time.time(), "run_id": "R1"}
    return header, rows.astype("<f8").tobytes()
