"""The web server's frame fan-out: one frame computed and encoded per tick, whatever the number
of browsers, the same bytes to each. Counted, not timed: a per-browser cost (a frame decimated
or encoded per connection) shows as counts that grow with the browsers.

The server runs for real (aiohttp on a random loopback port, real WebSocket clients); instead of
its link to the daemon it gets a `LiveView` fed with the synthetic blocks of `test_view`: what is
counted here happens after the daemon (the browser tests in tests/e2e cover the whole path)."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import orjson
import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient, TestServer

from tests.web.test_view import blocks
from web import server
from web.server import WebApp, WebConfig
from web.view import LiveView

FRAMES_EACH = 5


class _ViewOnly:
    """What `WebApp` reads from its `DaemonLink` for frames: the view (no daemon, no commands)."""

    def __init__(self, view: LiveView) -> None:
        self.view = view

    def try_command(self, cmd: str, **fields: Any) -> dict[str, Any]:
        raise AssertionError("no command is sent in this test")


async def _serve_frames(browsers: int, counts: dict[str, int]) -> tuple[int, list[list[bytes]]]:
    view = LiveView(buffer_s=0.5, cycles=3, points=200)
    for msg in blocks(40.0, 20):
        view.on_message(msg)
    frame = view.frame

    def counted_frame(now: float | None = None) -> dict[str, Any]:
        counts["computed"] += 1
        return frame(now)

    view.frame = counted_frame  # type: ignore[method-assign]
    app = WebApp(_ViewOnly(view), WebConfig(fps=50.0))  # type: ignore[arg-type]
    async with TestClient(TestServer(app.app)) as client:
        sockets = [await client.ws_connect("/ws") for _ in range(browsers)]
        got: list[list[bytes]] = [[] for _ in sockets]

        async def read(i: int) -> None:
            while len(got[i]) < FRAMES_EACH:
                msg = await sockets[i].receive(timeout=30)
                assert msg.type == WSMsgType.TEXT, msg
                if json.loads(msg.data)["type"] == "frame":
                    got[i].append(msg.data.encode())
                    await sockets[i].send_str("drawn")  # as the page does after painting

        await asyncio.gather(*(read(i) for i in range(browsers)))
        made = app.frames_made
        for ws in sockets:
            await ws.close()
    return made, got


@pytest.mark.parametrize("browsers", [1, 4])
def test_each_frame_is_computed_and_encoded_once_for_all_browsers(browsers, monkeypatch):
    counts = {"computed": 0, "encoded": 0}
    dumps = orjson.dumps

    def counted_dumps(obj: Any, *args: Any, **kw: Any) -> bytes:
        counts["encoded"] += 1
        return dumps(obj, *args, **kw)

    monkeypatch.setattr(server.orjson, "dumps", counted_dumps)
    made, got = asyncio.run(_serve_frames(browsers, counts))
    assert all(len(frames) == FRAMES_EACH for frames in got)
    # per frame made: one decimation and one encoding (the ticker may be one frame further,
    # in the executor, when counted); per browser it would be `browsers` of each
    assert made <= counts["computed"] <= made + 1
    assert counts["encoded"] == counts["computed"]
    # the browsers got frames of that one text: a frame (by its server time) is the same bytes
    # for all of them, and it carries the triggered, decimated traces
    by_time: dict[float, set[bytes]] = {}
    for data in (d for frames in got for d in frames):
        by_time.setdefault(json.loads(data)["server_time"], set()).add(data)
    assert len(by_time) <= made and all(len(v) == 1 for v in by_time.values())
    fr = json.loads(got[0][-1])
    assert fr["traces"]["triggered"] and 0 < len(fr["traces"]["t_ms"]) <= 200


async def _slow_and_quick() -> tuple[float, float, float]:
    view = LiveView(buffer_s=0.5, cycles=3, points=200)
    for msg in blocks(40.0, 20):
        view.on_message(msg)
    app = WebApp(_ViewOnly(view), WebConfig(fps=50.0))  # type: ignore[arg-type]

    async def next_frame(ws: Any) -> dict[str, Any]:
        while True:
            msg = await ws.receive(timeout=30)
            assert msg.type == WSMsgType.TEXT, msg
            fr = json.loads(msg.data)
            if fr["type"] == "frame":
                return fr

    async with TestClient(TestServer(app.app)) as client:
        slow = await client.ws_connect("/ws")
        first = await next_frame(slow)  # and it does not say it has drawn it
        quick = await client.ws_connect("/ws")
        for _ in range(10):
            quick_last = await next_frame(quick)
            await quick.send_str("drawn")
        await slow.send_str("drawn")
        second = await next_frame(slow)
        await slow.close()
        await quick.close()
    return first["server_time"], quick_last["server_time"], second["server_time"]


def test_a_browser_that_has_not_drawn_gets_the_newest_frame_next_not_a_queue():
    """A page that is slow to draw is sent nothing meanwhile; when it has drawn, it gets the
    newest frame, not the ones made while it was busy (queued, they would arrive seconds late)."""
    first, quick_last, second = asyncio.run(_slow_and_quick())
    assert first < quick_last <= second


def test_a_frame_that_cannot_be_made_does_not_stop_the_frames(caplog):
    """A frame whose making raises (a bug, a value the encoder refuses) is logged and skipped:
    the ticker goes on and the page gets the next one (before, every page froze for good)."""
    counts = {"computed": 0}
    view = LiveView(buffer_s=0.5, cycles=3, points=200)
    for msg in blocks(40.0, 20):
        view.on_message(msg)
    frame = view.frame

    def failing_once(now: float | None = None) -> dict[str, Any]:
        counts["computed"] += 1
        if counts["computed"] == 2:
            raise ValueError("a frame that cannot be made")
        return frame(now)

    view.frame = failing_once  # type: ignore[method-assign]
    app = WebApp(_ViewOnly(view), WebConfig(fps=50.0))  # type: ignore[arg-type]

    async def run() -> int:
        async with TestClient(TestServer(app.app)) as client:
            ws = await client.ws_connect("/ws")
            frames = 0
            while frames < 3:
                msg = await ws.receive(timeout=30)
                assert msg.type == WSMsgType.TEXT, msg
                if json.loads(msg.data)["type"] == "frame":
                    frames += 1
                    await ws.send_str("drawn")
            await ws.close()
            return frames

    assert asyncio.run(run()) == 3
    assert app.frame_errors == 1 and counts["computed"] >= 4
    assert "could not be made" in caplog.text
