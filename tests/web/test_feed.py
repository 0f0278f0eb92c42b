"""`web.feed.DaemonLink` against stand-in daemons made here (a PUB socket sending heartbeats and
a ROUTER answering status, on random loopback ports): the feed survives any message, a silent
daemon is judged lost within the page's 2 s, a late stream whose daemon still answers is not,
and a daemon restarted on new ports is found again through the state file.

Waits are on conditions (polled every 10 ms with a deadline), never fixed sleeps."""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq

from control.wire import Reply, encode_header
from web.feed import LOST_AFTER_S, DaemonLink
from web.view import LiveView


def _until(condition: Callable[[], bool], timeout_s: float = 10.0) -> float:
    """Seconds until ``condition()`` held (fails after ``timeout_s``)."""
    t0 = time.monotonic()
    while not condition():
        assert time.monotonic() - t0 < timeout_s, "condition not met in time"
        time.sleep(0.01)
    return time.monotonic() - t0


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
        return {"state": "idle", "run_id": "", "who": self.name, "allowed": ["start"]}

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


def _block(first: int, n: int = 100) -> tuple[dict[str, Any], bytes]:
    rows = np.vstack([np.sin(np.arange(first, first + n) * 0.1)] * 3)
    header = {"first_sample": first, "n_samples": n, "shape": [3, n], "n_ai": 2,
              "channels": ["fx", "x1", "shaker_x"], "sample_rate_hz": 1000.0,
              "t_acquired": time.time(), "run_id": "R1"}
    return header, rows.astype("<f8").tobytes()


def test_the_feed_survives_every_malformed_message(fakes):
    """The message that killed the page's feed (two frames) and others like it are counted and
    skipped; the blocks after them are drawn."""
    daemon = fakes("A")
    view = LiveView()
    link = DaemonLink(daemon.command, daemon.data, view)
    try:
        link.start(timeout_s=10)
        header, payload = _block(0)
        bad = [[b"block", encode_header({"seq": 0})],                      # 2 frames
               [b"block"], [b"status", b"{bad", b""],                      # 1 frame; bad JSON
               [b"status", b"[1,2,3]", b""], [b"status", b"null", b""],    # not an object
               [b"status", encode_header({"seq": 1, "status": "x"}), b""],  # status not one
               [b"block", encode_header({**header, "seq": 0}), payload[:-8]],  # short payload
               [b"step", encode_header({"seq": 0}), b""],                  # no step inside
               [b"event", encode_header({"seq": 0, "kind": 3}), b""],      # no message
               [b"block", b"\xff\xfe", b""]]                               # not UTF-8
        for frames in bad:
            daemon.raw(frames)
        daemon.send("block", header, payload)
        _until(lambda: view.frame()["traces"] is not None)
        assert link.malformed == len(bad)
        assert link._thread.is_alive()
        fr = view.frame()
        assert fr["traces"]["last_sample"] == 99 and fr["link"]["malformed"] == len(bad)
        assert fr["link"]["state"] == "live"
        header, payload = _block(100)
        daemon.send("block", header, payload)  # and it goes on
        _until(lambda: view.frame()["traces"]["last_sample"] == 199)
    finally:
        link.close()


def _gone_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def test_a_dead_daemon_is_lost_within_2_s_and_a_restarted_one_is_found(fakes, tmp_path: Path):
    state = tmp_path / "daemon.json"
    a = fakes("A")
    state.write_text(json.dumps({"command": a.command, "data": a.data, "pid": os.getpid()}))
    view = LiveView()
    link = DaemonLink(a.command, a.data, view, state_file=state)
    try:
        link.start(timeout_s=10)
        _until(lambda: view.frame()["link"]["state"] == "live")
        # killed: no heartbeat, no reply, its pid gone (a kill -9 leaves the state file)
        a.stop()
        state.write_text(json.dumps({"command": a.command, "data": a.data,
                                     "pid": _gone_pid()}))
        took = _until(lambda: view.frame()["link"]["state"] == "lost")
        link_now = view.frame()["link"]
        assert took < 2.0 and link_now["heartbeat_age_s"] >= LOST_AFTER_S
        assert "is not running" in link_now["message"] and link_now["stale"]
        assert view.frame()["time_left_s"] is None
        # a new daemon on other ports writes the state file: followed without a restart
        b = fakes("B")
        state.write_text(json.dumps({"command": b.command, "data": b.data,
                                     "pid": os.getpid()}))
        _until(lambda: view.frame()["link"]["state"] == "live")
        assert view.frame()["status"]["who"] == "B" and link.reconnects == 1
        assert link.command_endpoint == b.command and link.data_endpoint == b.data
        assert link.try_command("status")["data"]["who"] == "B"
    finally:
        link.close()


def test_a_late_stream_with_an_answering_daemon_is_late_not_lost(fakes):
    """Heartbeats stop but the daemon answers status (a loaded machine, a stuck proxy): the
    page says late, keeps the state; a daemon that answers nothing either is lost."""
    a = fakes("A")
    view = LiveView()
    link = DaemonLink(a.command, a.data, view)
    try:
        link.start(timeout_s=10)
        a.beating.clear()
        _until(lambda: view.frame()["link"]["state"] == "late")
        assert "answers status" in view.frame()["link"]["message"]
        a.answer = False
        took = _until(lambda: view.frame()["link"]["state"] == "lost")
        assert took < 2.0
        assert "no reply to status" in view.frame()["link"]["message"]
    finally:
        link.close()
