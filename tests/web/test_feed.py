"""`web.feed.DaemonLink` against stand-in daemons made here (a PUB socket sending heartbeats and
a ROUTER answering status, on random loopback ports): the feed survives any message, a silent
daemon is judged lost within the page's 2 s, a late stream whose daemon still answers is not,
and a daemon restarted on new ports is found again through the state file.

Waits are on conditions (polled every 10 ms with a deadline), never fixed sleeps."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from control.wire.protocol import encode_header
from tests.fake_daemon import block_message, until
from web.feed import LOST_AFTER_S, DaemonLink
from web.view import LiveView


def test_the_feed_survives_every_malformed_message(fakes):
    """The message that killed the page's feed (two frames) and others like it are counted and
    skipped; the blocks after them are drawn."""
    daemon = fakes("A")
    view = LiveView()
    link = DaemonLink(daemon.command, daemon.data, view)
    try:
        link.start(timeout_s=10)
        header, payload = block_message(0)
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
        until(lambda: view.frame()["traces"] is not None)
        assert link.malformed == len(bad)
        assert link._thread.is_alive()
        fr = view.frame()
        assert fr["traces"]["last_sample"] == 99 and fr["link"]["malformed"] == len(bad)
        assert fr["link"]["state"] == "live"
        header, payload = block_message(100)
        daemon.send("block", header, payload)  # and it goes on
        until(lambda: view.frame()["traces"]["last_sample"] == 199)
    finally:
        link.close()


def _gone_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


@pytest.mark.paced  # a timing bound: lost within 2 s
def test_a_dead_daemon_is_lost_within_2_s_and_a_restarted_one_is_found(fakes, tmp_path: Path):
    state = tmp_path / "daemon.json"
    a = fakes("A")
    state.write_text(json.dumps({"command": a.command, "data": a.data, "pid": os.getpid()}))
    view = LiveView()
    link = DaemonLink(a.command, a.data, view, state_file=state)
    try:
        link.start(timeout_s=10)
        until(lambda: view.frame()["link"]["state"] == "live")
        # killed: no heartbeat, no reply, its pid gone (a kill -9 leaves the state file)
        a.stop()
        state.write_text(json.dumps({"command": a.command, "data": a.data,
                                     "pid": _gone_pid()}))
        took = until(lambda: view.frame()["link"]["state"] == "lost")
        link_now = view.frame()["link"]
        assert took < 2.0 and link_now["heartbeat_age_s"] >= LOST_AFTER_S
        assert "is not running" in link_now["message"] and link_now["stale"]
        assert view.frame()["time_left_s"] is None
        # a new daemon on other ports writes the state file: followed without a restart
        b = fakes("B")
        state.write_text(json.dumps({"command": b.command, "data": b.data,
                                     "pid": os.getpid()}))
        until(lambda: view.frame()["link"]["state"] == "live")
        assert view.frame()["status"]["who"] == "B" and link.reconnects == 1
        assert link.command_endpoint == b.command and link.data_endpoint == b.data
        assert link.try_command("status")["data"]["who"] == "B"
    finally:
        link.close()


@pytest.mark.paced  # a timing bound: lost within 2 s
def test_a_late_stream_with_an_answering_daemon_is_late_not_lost(fakes):
    """Heartbeats stop but the daemon answers status (a loaded machine, a stuck proxy): the
    page says late, keeps the state; a daemon that answers nothing either is lost."""
    a = fakes("A")
    view = LiveView()
    link = DaemonLink(a.command, a.data, view)
    try:
        link.start(timeout_s=10)
        a.beating.clear()
        until(lambda: view.frame()["link"]["state"] == "late")
        assert "answers status" in view.frame()["link"]["message"]
        a.answer = False
        took = until(lambda: view.frame()["link"]["state"] == "lost")
        assert took < 2.0
        assert "no reply to status" in view.frame()["link"]["message"]
    finally:
        link.close()
