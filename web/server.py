"""The web server (aiohttp): one page, its static files, a WebSocket of frames, and commands.

Every ``1 / fps`` seconds the server computes one frame from the `LiveView` (decimated on the
server) and serialises it once, off the event loop (orjson: a frame is about 10,000 numbers);
the same bytes go to every connected browser, so a browser costs a send, never a frame or an
encoding. Each browser has a sender task that sends the newest frame once the browser has
drawn the previous one (it answers each frame with ``drawn``, after painting or at the latest
after 250 ms): a slow browser skips frames, frames
never queue up in its network buffers (seconds of delay), it never makes the others wait, and it
never reaches back to the daemon. Commands
are POSTs checked against the browser's role (`web.auth`) and sent to the daemon's command
socket by the `DaemonLink`.
"""

from __future__ import annotations

import asyncio
import json
import logging
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson
from aiohttp import WSMsgType, web
from aiohttp.web_request import FileField

from web.auth import COOKIE, OPERATOR, LoginRefused, Session, Sessions, role_of_key_file
from web.feed import DaemonLink
from web.view import LiveView

log = logging.getLogger(__name__)
STATIC = Path(__file__).parent / "static"
COMMANDS = ("pause", "resume", "abort", "pump", "reset", "answer")
MAX_UPLOAD_BYTES = 256 * 1024
DRAWN = "drawn"  # a browser's answer to each frame: send the next one


@dataclass
class WebConfig:
    """How the web server runs.

    Attributes
    ----------
    key_dir : Path or None
        The daemon's key directory: browsers log in with a client key file. None: no login, every
        browser gets ``anonymous_role`` (loopback only; checked by the command).
    anonymous_role : "operator" | "viewer"
    examples_dir : Path or None
        Sweep TOML files offered on the page.
    fps : float
        Frames per second sent to each browser.
    secure_cookie : bool
        Mark the session cookie Secure (served over TLS).
    """

    key_dir: Path | None = None
    anonymous_role: str = OPERATOR
    examples_dir: Path | None = None
    fps: float = 10.0
    secure_cookie: bool = False


@dataclass(eq=False)  # hashed by identity: one per connection
class _Browser:
    ws: web.WebSocketResponse
    wake: asyncio.Event = field(default_factory=asyncio.Event)  # a newer frame is there
    drawn: asyncio.Event = field(default_factory=asyncio.Event)  # the last one sent is drawn
    frame: bytes = b""  # the newest frame's JSON text, shared by all browsers
    sent: int = 0


def parse_sweep_toml(text: str, source: str) -> dict[str, Any]:
    """A sweep TOML's fields; the error reads like the CLI's (``cannot read SOURCE: ...``)."""
    try:
        spec = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"cannot read {source}: {err}") from None
    if not spec:
        raise ValueError(f"{source} holds no sweep fields")
    return spec


class WebApp:
    """The aiohttp application around one `DaemonLink` and its `LiveView`."""

    def __init__(self, link: DaemonLink, config: WebConfig) -> None:
        self.link = link
        self.view: LiveView = link.view
        self.cfg = config
        self.sessions = Sessions()
        self.browsers: set[_Browser] = set()
        self.frames_made = 0
        self.frame_errors = 0  # frames that could not be made (logged; the ticker goes on)
        self.app = web.Application(client_max_size=MAX_UPLOAD_BYTES)
        self.app.add_routes([
            web.get("/", self.index),
            web.get("/login", self.login_page),
            web.post("/login", self.login),
            web.post("/logout", self.logout),
            web.get("/ws", self.websocket),
            web.get("/api/examples", self.examples),
            web.post("/api/start", self.start),
            web.post("/api/command", self.command),
            web.post("/api/start_test", self.start_test),
            web.static("/static", STATIC),
        ])
        self.app.on_startup.append(self._start_ticker)
        self.app.on_shutdown.append(self._close_browsers)
        self._ticker: asyncio.Task[None] | None = None

    # --- who is asking --------------------------------------------------------------------
    def session(self, request: web.Request) -> Session | None:
        if self.cfg.key_dir is None:
            return Session("local", self.cfg.anonymous_role, float("inf"))
        return self.sessions.get(request.cookies.get(COOKIE))

    @staticmethod
    def _same_origin(request: web.Request) -> bool:
        """A browser's POST or WebSocket must come from this page (no cross-site requests)."""
        origin = request.headers.get("Origin")
        return origin is None or origin == f"{request.scheme}://{request.host}"

    def _guard(self, request: web.Request, need_operator: bool) -> Session:
        if not self._same_origin(request):
            raise web.HTTPForbidden(text="cross-origin request refused")
        s = self.session(request)
        if s is None:
            raise web.HTTPUnauthorized(text="log in first (/login)")
        if need_operator and s.role != OPERATOR:
            raise web.HTTPForbidden(
                content_type="application/json",
                text=json.dumps({"ok": False, "error": f"refused: {s.name} is a viewer; "
                                                       "viewers control nothing"}))
        return s

    # --- pages ----------------------------------------------------------------------------
    async def index(self, request: web.Request) -> web.StreamResponse:
        if self.session(request) is None:
            raise web.HTTPFound("/login")
        return web.FileResponse(STATIC / "index.html")

    async def login_page(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "login.html")

    async def login(self, request: web.Request) -> web.Response:
        if self.cfg.key_dir is None:
            raise web.HTTPFound("/")
        if not self._same_origin(request):
            raise web.HTTPForbidden(text="cross-origin request refused")
        form = await request.post()
        key = form.get("key")
        raw = key.file.read() if isinstance(key, FileField) else str(key or "").encode()
        text = raw[:MAX_UPLOAD_BYTES].decode("utf-8", "replace")
        try:
            name, role = role_of_key_file(text, self.cfg.key_dir)
        except LoginRefused as err:
            return web.Response(status=403, text=f"login refused: {err}")
        log.info("login: %s as %s from %s", name, role, request.remote)
        resp = web.HTTPFound("/")
        resp.set_cookie(COOKIE, self.sessions.new(name, role), httponly=True, samesite="Strict",
                        secure=self.cfg.secure_cookie)
        raise resp

    async def logout(self, request: web.Request) -> web.Response:
        self.sessions.end(request.cookies.get(COOKIE))
        resp = web.HTTPFound("/login")
        resp.del_cookie(COOKIE)
        raise resp

    # --- commands -------------------------------------------------------------------------
    def _example_files(self) -> dict[str, Path]:
        d = self.cfg.examples_dir
        return {p.name: p for p in sorted(d.glob("*.toml"))} if d and d.is_dir() else {}

    async def examples(self, request: web.Request) -> web.Response:
        self._guard(request, need_operator=False)
        return web.json_response({"examples": list(self._example_files())})

    async def _daemon(self, call: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        return await asyncio.get_running_loop().run_in_executor(None, call)

    async def start(self, request: web.Request) -> web.Response:
        s = self._guard(request, need_operator=True)
        body = await request.json()
        try:
            if body.get("example"):
                path = self._example_files().get(str(body["example"]))
                if path is None:
                    raise ValueError(f"no example sweep {body['example']!r}")
                spec = parse_sweep_toml(path.read_text(), path.name)
            else:
                spec = parse_sweep_toml(str(body.get("toml", "")),
                                        str(body.get("filename") or "the uploaded file"))
        except ValueError as err:
            return web.json_response({"ok": False, "error": str(err), "data": {}})
        out = await self._daemon(lambda: self.link.try_command(
            "start", spec=spec, operator=s.name, notes="started from sfdrig web"))
        return web.json_response(out)

    async def start_test(self, request: web.Request) -> web.Response:
        """Start a structure test, with its default settings or the few the page offers
        (``spec``, e.g. the static test's ``load_by``; the daemon validates them); its questions
        come back in the status, so this page (or a terminal) is its operator."""
        s = self._guard(request, need_operator=True)
        body = await request.json()
        test = str(body.get("test", ""))
        spec = body.get("spec") or {}
        if not isinstance(spec, dict):
            return web.json_response({"ok": False, "data": {},
                                      "error": "start_test: spec must be an object"})
        out = await self._daemon(lambda: self.link.try_command(
            "start_test", test=test, spec=spec, operator=s.name, notes="started from sfdrig web"))
        return web.json_response(out)

    async def command(self, request: web.Request) -> web.Response:
        self._guard(request, need_operator=True)
        body = await request.json()
        cmd = body.get("cmd")
        if cmd not in COMMANDS:
            return web.json_response({"ok": False, "error": f"unknown command {cmd!r}; "
                                      f"commands are {', '.join(COMMANDS)}", "data": {}})
        fields: dict[str, Any] = {}
        if cmd == "pump":
            fields["on"] = body.get("on")
        if cmd == "abort":
            fields["reason"] = "operator abort from sfdrig web"
        if cmd == "answer":  # the operator protocol's answer; the daemon checks it
            fields.update({k: body.get(k) for k in ("question_id", "choice", "text")})
        out = await self._daemon(lambda: self.link.try_command(cmd, **fields))
        return web.json_response(out)

    # --- live frames ----------------------------------------------------------------------
    async def websocket(self, request: web.Request) -> web.WebSocketResponse:
        s = self._guard(request, need_operator=False)
        ws = web.WebSocketResponse(heartbeat=20.0, compress=False)  # CPU over bytes
        await ws.prepare(request)
        b = _Browser(ws)
        await ws.send_str(json.dumps({"type": "hello", "name": s.name, "role": s.role,
                                      "examples": list(self._example_files()),
                                      "login": self.cfg.key_dir is not None}))
        b.drawn.set()
        self.browsers.add(b)
        sender = asyncio.create_task(self._send_frames(b))
        try:
            async for msg in ws:  # the page only says it drew a frame; this waits for the close
                if msg.type == WSMsgType.ERROR:
                    break
                if msg.type == WSMsgType.TEXT and msg.data == DRAWN:
                    b.drawn.set()
        finally:
            self.browsers.discard(b)
            sender.cancel()
        return ws

    async def _send_frames(self, b: _Browser) -> None:
        while not b.ws.closed:
            await b.drawn.wait()  # then the newest frame, whatever came meanwhile
            await b.wake.wait()
            b.drawn.clear()
            b.wake.clear()
            try:
                # the newest frame (older ones were skipped), as a text message
                await b.ws.send_frame(b.frame, WSMsgType.TEXT)
            except (ConnectionError, RuntimeError):  # the browser went away
                return
            b.sent += 1

    async def _tick(self) -> None:
        period = 1.0 / self.cfg.fps
        loop = asyncio.get_running_loop()
        while True:
            t0 = loop.time()
            if self.browsers:
                try:
                    data = await loop.run_in_executor(None, self._encoded_frame)
                except Exception:  # noqa: BLE001 - one bad frame must not freeze every page
                    self.frame_errors += 1
                    log.exception("frame %d could not be made; the next tick tries again",
                                  self.frames_made + self.frame_errors)
                else:
                    self.frames_made += 1
                    for b in list(self.browsers):
                        b.frame = data
                        b.wake.set()
            await asyncio.sleep(max(0.0, period - (loop.time() - t0)))  # frame pacing

    def _encoded_frame(self) -> bytes:
        """One frame as JSON text (UTF-8); NaN becomes null."""
        return orjson.dumps(self.view.frame(), option=orjson.OPT_SERIALIZE_NUMPY)

    async def _start_ticker(self, app: web.Application) -> None:
        self._ticker = asyncio.create_task(self._tick())

    async def _close_browsers(self, app: web.Application) -> None:
        if self._ticker is not None:
            self._ticker.cancel()
        for b in list(self.browsers):
            await b.ws.close()

