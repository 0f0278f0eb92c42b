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

A structure test started from the page holds the rig for the person at a page: the server keeps
its operator lease (`control.daemon.lease`) only while an operator's page is connected (its
WebSocket open). Close every operator page, or lose this server, and the lease lapses: the daemon
aborts the test, drives ramped to zero. A reload is quicker than the lease. A sweep has no lease.

Every request must name an allowed host in its ``Host`` header (`WebConfig.allowed_hosts`: a page
of another name resolved to this address, DNS rebinding, is refused with 421 before anything
else), and a POST or WebSocket from a browser must come from this page's own origin. Every answer
forbids framing (``X-Frame-Options: DENY`` and a content security policy with
``frame-ancestors 'none'``: no clickjacking). A request's head must arrive within
``header_timeout_s`` (aiohttp's keep-alive timer, which also closes idle connections) and its body
within ``body_timeout_s``; a body that is not a JSON object is answered 400 with the reason.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import os
import shutil
import sys
import tempfile
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson
from aiohttp import WSMsgType, web
from aiohttp.web_request import FileField

from control.wire.protocol import renew_every_s
from web import sweep_form
from web.auth import COOKIE, OPERATOR, LoginRefused, Session, Sessions, role_of_key_file
from web.feed import DaemonLink
from web.history import HistoryError, RunHistory
from web.trips import parse_incidents, parse_since, to_csv
from web.view import LiveView

log = logging.getLogger(__name__)
STATIC = Path(__file__).parent / "static"
STATIC_PREFIX = "/static/"
COMMANDS = ("pause", "resume", "abort", "pump", "reset", "answer")
MAX_UPLOAD_BYTES = 256 * 1024
SEND_CHUNK_BYTES = 1024 * 1024  # a download is read and sent this much at a time
DRAWN = "drawn"  # a browser's answer to each frame: send the next one
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")
SECURITY_HEADERS = {
    "X-Frame-Options": "DENY",
    "Content-Security-Policy": (
        "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
        "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
        "frame-ancestors 'none'"),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",  # no-referrer would make form POSTs say Origin: null
}
# a report page (analysis.report) styles itself inline and runs no script
REPORT_ROUTE = "report_file"
REPORT_CSP = ("default-src 'none'; style-src 'unsafe-inline'; img-src 'self'; "
              "frame-ancestors 'none'; base-uri 'none'; form-action 'none'")
REVOCATION_CHECK_S = 1.0  # open WebSockets of revoked keys are closed within this
WS_REVOKED = 4001  # the close code a page reads as "log in again"


def host_name(host: str) -> str | None:
    """The name in a ``Host`` header (``name``, ``name:port``, ``[v6]:port``), lower case;
    None when it is not one."""
    host = host.strip().lower()
    if host.startswith("["):
        end = host.find("]")
        name, rest = (host[1:end], host[end + 1:]) if end > 0 else ("", "")
    else:
        name, sep, port = host.partition(":")
        rest = sep + port
    if not name or (rest and not (rest.startswith(":") and rest[1:].isdigit())):
        return None
    return name.rstrip(".")


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
    allowed_hosts : tuple of str
        The names (or addresses) a request's ``Host`` header may give, any port; the loopback
        names by default. Anything else is refused (DNS rebinding).
    header_timeout_s, body_timeout_s : float
        How long a request's head, and then its body, may take to arrive [s].
    runs_dir : Path or None
        The daemon's runs directory: the page's run history (`web.history`).
    identify_command, identify_timeout_s
        The command that makes a run's identification report (given the run file, then
        ``--no-store --report DIR``) and how long it may take [s].
    release_memory : callable or None
        Called after each transfer request, in its thread: `sfdrig web` gives the free pages
        inside the C heap back to the kernel there (glibc keeps free space under blocks still
        in use resident; once a step of a sweep is often enough).
    """

    key_dir: Path | None = None
    anonymous_role: str = OPERATOR
    examples_dir: Path | None = None
    fps: float = 10.0
    secure_cookie: bool = False
    allowed_hosts: tuple[str, ...] = LOOPBACK_NAMES
    header_timeout_s: float = 10.0
    body_timeout_s: float = 10.0
    runs_dir: Path | None = None
    identify_command: tuple[str, ...] = (sys.executable, "-m", "sfdrig", "identify")
    identify_timeout_s: float = 600.0
    release_memory: Callable[[], object] | None = None


@dataclass(eq=False)  # hashed by identity: one per connection
class _Browser:
    ws: web.WebSocketResponse
    wake: asyncio.Event = field(default_factory=asyncio.Event)  # a newer frame is there
    drawn: asyncio.Event = field(default_factory=asyncio.Event)  # the last one sent is drawn
    frame: bytes = b""  # the newest frame's JSON text, shared by all browsers
    sent: int = 0
    token: str | None = None  # its login session (re-checked: a revoked key closes it)


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
        self._allowed = {h.lower().strip("[]").rstrip(".") for h in config.allowed_hosts}
        self.app = web.Application(client_max_size=MAX_UPLOAD_BYTES,
                                   middlewares=[self._check_host])
        self.app.on_response_prepare.append(self._security_headers)
        self.app.add_routes([
            web.get("/", self.index),
            web.get("/login", self.login_page),
            web.post("/login", self.login),
            web.post("/logout", self.logout),
            web.get("/ws", self.websocket),
            web.get("/api/session", self.whoami),
            web.get("/api/examples", self.examples),
            web.post("/api/start", self.start),
            web.post("/api/command", self.command),
            web.post("/api/start_test", self.start_test),
            web.get("/api/sweep/schema", self.sweep_schema),
            web.post("/api/sweep/check", self.sweep_check),
            web.get("/api/runs", self.runs),
            web.get("/api/trips", self.trips),
            web.get("/api/runs/{run_id}", self.run_details),
            web.get("/api/runs/{run_id}/download", self.download),
            web.get("/api/runs/{run_id}/transfer", self.transfer),
            web.post("/api/runs/{run_id}/notes", self.add_note),
            web.post("/api/runs/{run_id}/report", self.make_report),
            web.get("/api/runs/{run_id}/report/{name:.+}", self.report_file,
                    name=REPORT_ROUTE),
            web.static(STATIC_PREFIX.rstrip("/"), STATIC),
        ])
        self.app.on_startup.append(self._start_ticker)
        self.app.on_startup.append(self._start_lease_keeper)
        self.app.on_shutdown.append(self._close_browsers)
        self._ticker: asyncio.Task[None] | None = None
        self._lease_keeper: asyncio.Task[None] | None = None
        # the operator lease of the test this page started: its token and length [s]
        self.lease: tuple[str, float] | None = None
        self.history = RunHistory(config.runs_dir) if config.runs_dir is not None else None
        self._exporting = asyncio.Lock()  # one export at a time: the daemon needs the CPU
        self._identifying = asyncio.Lock()  # and one identification

    def runner_options(self) -> dict[str, Any]:
        """The `aiohttp.web.AppRunner` options this app needs: its keep-alive timer is the
        header timeout (it closes a connection whose request head is not complete by then);
        after a refused or timed-out body it reads what is left for at most a second."""
        return {"keepalive_timeout": self.cfg.header_timeout_s, "lingering_time": 1.0,
                "access_log": None}

    # --- every request and answer --------------------------------------------------------
    @web.middleware
    async def _check_host(self, request: web.Request,
                          handler: Callable[[web.Request], Any]) -> web.StreamResponse:
        name = host_name(request.headers.get("Host", ""))
        if name is None or name not in self._allowed:
            log.warning("refused a request for host %r from %s", request.headers.get("Host"),
                        request.remote)
            raise web.HTTPMisdirectedRequest(
                text=f"this server does not serve the host {request.headers.get('Host', '')!r}"
                     " (allowed: " + ", ".join(sorted(self._allowed)) + ")")
        return await handler(request)

    @staticmethod
    async def _security_headers(request: web.Request, response: web.StreamResponse) -> None:
        response.headers.update(SECURITY_HEADERS)
        # the page and every answer are asked for again each time (a cached page of a revoked
        # key would never reach the login); the static files are checked for a newer version
        response.headers["Cache-Control"] = (
            "no-cache" if request.path.startswith(STATIC_PREFIX) else "no-store")
        if request.match_info.route.name == REPORT_ROUTE:  # analysis's page: its own <style>
            response.headers["Content-Security-Policy"] = REPORT_CSP

    async def _json_object(self, request: web.Request) -> dict[str, Any]:
        """The request's body as a JSON object, read within the body timeout.

        Raises
        ------
        web.HTTPBadRequest
            for a body that is not UTF-8 JSON, not an object, or nested beyond reason.
        web.HTTPRequestTimeout
            when the body does not arrive in time.
        """
        try:
            async with asyncio.timeout(self.cfg.body_timeout_s):
                raw = await request.read()
        except TimeoutError:
            raise _timed_out("the request body did not arrive in time") from None
        try:
            body = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as err:
            raise _bad(f"the body is not JSON: {err}") from None
        except RecursionError:
            raise _bad("the body is not JSON: nested too deeply") from None
        if not isinstance(body, dict):
            raise _bad(f"the body must be a JSON object, not {type(body).__name__}")
        return body

    # --- who is asking --------------------------------------------------------------------
    def session(self, request: web.Request) -> Session | None:
        return self._session_of(request.cookies.get(COOKIE))

    def _session_of(self, token: str | None) -> Session | None:
        if self.cfg.key_dir is None:
            return Session("local", self.cfg.anonymous_role, float("inf"))
        return self.sessions.current(token, self.cfg.key_dir)

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

    async def whoami(self, request: web.Request) -> web.Response:
        """Who this browser is logged in as (401 when not: a page whose WebSocket was refused
        asks here whether to go to the login)."""
        s = self._guard(request, need_operator=False)
        return web.json_response({"ok": True, "name": s.name, "role": s.role})

    async def login_page(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "login.html")

    async def login(self, request: web.Request) -> web.Response:
        if self.cfg.key_dir is None:
            raise web.HTTPFound("/")
        if not self._same_origin(request):
            raise web.HTTPForbidden(text="cross-origin request refused")
        try:
            async with asyncio.timeout(self.cfg.body_timeout_s):
                form = await request.post()
        except TimeoutError:
            raise _timed_out("the login form did not arrive in time") from None
        except ValueError as err:  # a malformed form body
            raise web.HTTPBadRequest(text=f"login refused: not a login form: {err}") from None
        key = form.get("key")
        raw = key.file.read() if isinstance(key, FileField) else str(key or "").encode()
        text = raw[:MAX_UPLOAD_BYTES].decode("utf-8", "replace")
        try:
            name, role, public = role_of_key_file(text, self.cfg.key_dir)
        except LoginRefused as err:
            return web.Response(status=403, text=f"login refused: {err}")
        log.info("login: %s as %s from %s", name, role, request.remote)
        resp = web.HTTPFound("/")
        resp.set_cookie(COOKIE, self.sessions.new(name, role, public), httponly=True,
                        samesite="Strict", secure=self.cfg.secure_cookie)
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
        body = await self._json_object(request)
        try:
            if isinstance(body.get("spec"), dict):  # the page's form (the daemon validates it)
                spec = body["spec"]
            elif body.get("example"):
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

    async def sweep_schema(self, request: web.Request) -> web.Response:
        self._guard(request, need_operator=False)
        return web.json_response({"ok": True, "schema": sweep_form.schema()})

    async def sweep_check(self, request: web.Request) -> web.Response:
        """The page's sweep (``spec``, or a TOML file's text ``toml``) checked by `SweepSpec`:
        the problems by field, or the summary and the TOML; ``spec`` is what was checked."""
        self._guard(request, need_operator=False)
        body = await self._json_object(request)
        spec: Any
        if "toml" in body:
            try:
                spec = parse_sweep_toml(str(body["toml"]),
                                        str(body.get("filename") or "the uploaded file"))
            except ValueError as err:
                return web.json_response({"ok": False, "spec": None, "summary": None,
                                          "toml": "", "errors": [{"field": "",
                                                                  "message": str(err)}]})
        else:
            spec = body.get("spec")
        safety = self.view.status["safety"] if self.view.status is not None else None
        out = await asyncio.get_running_loop().run_in_executor(
            None, sweep_form.check, spec, safety)
        return web.json_response({**out, "spec": spec})

    async def start_test(self, request: web.Request) -> web.Response:
        """Start a structure test, with its default settings or the few the page offers
        (``spec``, e.g. the static test's ``load_by``; the daemon validates them); its questions
        come back in the status, so this page (or a terminal) is its operator."""
        s = self._guard(request, need_operator=True)
        body = await self._json_object(request)
        test = str(body.get("test", ""))
        spec = body.get("spec") or {}
        if not isinstance(spec, dict):
            return web.json_response({"ok": False, "data": {},
                                      "error": "start_test: spec must be an object"})
        out = await self._daemon(lambda: self.link.try_command(
            "start_test", test=test, spec=spec, operator=s.name, notes="started from sfdrig web"))
        data = out.get("data") or {}
        if out.get("ok") and data.get("lease"):
            self.lease = (str(data["lease"]), float(data["lease_s"]))
        return web.json_response({**out, "data": {k: v for k, v in data.items()
                                                  if k != "lease"}})

    def operator_pages(self) -> int:
        """The connected pages whose login may operate (a viewer's page holds nothing)."""
        return sum(1 for b in self.browsers
                   if (s := self._session_of(b.token)) is not None and s.role == OPERATOR)

    async def _keep_lease(self) -> None:
        """Renew the lease of the test this page started while an operator's page is open;
        forget it once the daemon refuses it (the test has ended)."""
        while True:
            lease = self.lease
            if lease is None:
                await asyncio.sleep(0.5)
                continue
            token, lease_s = lease
            if self.operator_pages():
                out = await self._daemon(functools.partial(self.link.try_command, "alive",
                                                           lease=token))
                if not out["ok"] and "lease" in out["error"] and self.lease == lease:
                    self.lease = None  # the test has ended (or another start replaced it)
            await asyncio.sleep(renew_every_s(lease_s))

    async def command(self, request: web.Request) -> web.Response:
        self._guard(request, need_operator=True)
        body = await self._json_object(request)
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

    # --- run history ----------------------------------------------------------------------
    async def _history(self, request: web.Request, call: Callable[[RunHistory], Any]) -> Any:
        if self.history is None:
            raise _refused(404, "no runs directory: start sfdrig web with --runs-dir")
        history = self.history
        try:
            return await asyncio.get_running_loop().run_in_executor(None, call, history)
        except HistoryError as err:
            raise _refused(err.status, str(err)) from None

    async def runs(self, request: web.Request) -> web.Response:
        """A page of the run history (`web.history.RunHistory.runs`): the filters of
        `storage.catalog.FILTERS` (``kind``, ``status``, ``since``, ``until``,
        ``lubricated``, ``seal``, ``motion``) and ``limit``/``offset``; a bad one is a 400."""
        self._guard(request, need_operator=False)
        query = dict(request.query)
        return web.json_response({"ok": True, **await self._history(
            request, lambda h: h.runs(query))})

    async def trips(self, request: web.Request) -> web.Response:
        """The trips, e-stops, watchdogs and interrupted runs of the runs directory
        (`web.trips`): ``incident=trip,e-stop`` (or all), ``since=`` an ISO date or time,
        ``format=json`` or ``csv`` (a download)."""
        self._guard(request, need_operator=False)
        q = request.query
        unknown = sorted(set(q) - {"incident", "since", "format"})
        if unknown:
            raise _refused(400, f"unknown parameter {unknown[0]!r}: incident, since, format")
        fmt = q.get("format", "json")
        if fmt not in ("json", "csv"):
            raise _refused(400, f"format={fmt!r}: json or csv")
        try:
            incidents = parse_incidents(q.get("incident", ""))
            since = parse_since(q["since"]) if q.get("since") else None
        except ValueError as err:
            raise _refused(400, str(err)) from None
        out = await self._history(request, lambda h: h.trips(incidents, since))
        if fmt == "csv":
            return web.Response(text=to_csv(out["incidents"]), content_type="text/csv",
                                headers={"Content-Disposition":
                                         'attachment; filename="sfdrig-incidents.csv"'})
        return web.json_response({"ok": True, **out})

    async def run_details(self, request: web.Request) -> web.Response:
        self._guard(request, need_operator=False)
        run_id = request.match_info["run_id"]
        return web.Response(content_type="application/json", body=orjson.dumps(
            {"ok": True, **await self._history(request, lambda h: h.details(run_id))}))

    async def transfer(self, request: web.Request) -> web.Response:
        """The run's X/F, F/X and coherence per step from its file (`web.transfer`): the page
        asks again at each new step of a running sweep."""
        self._guard(request, need_operator=False)
        run_id = request.match_info["run_id"]
        release = self.cfg.release_memory

        def answer(h: RunHistory) -> dict[str, Any]:
            try:
                return h.transfer(run_id)
            finally:
                if release is not None:
                    release()

        return web.Response(content_type="application/json", body=orjson.dumps(
            {"ok": True, **await self._history(request, answer)}))

    async def download(self, request: web.Request) -> web.StreamResponse:
        """The run file (``format=h5``) or `sfdrig export`'s files (mat, csv, tdms; a zip when
        several), made in a temporary folder that goes once the answer has been sent whole
        (`_send_whole`: aiohttp prepares a returned response again, and a `FileResponse` would
        then look for its file in the folder already gone)."""
        self._guard(request, need_operator=False)
        run_id = request.match_info["run_id"]
        fmt = request.query.get("format", "h5")
        if fmt == "h5":  # the run file as it is: nothing to make
            path, name = await self._history(
                request, lambda h: h.download(run_id, fmt, Path(tempfile.gettempdir())))
            return _attachment(path, name)
        if self._exporting.locked():
            raise _refused(503, "another export is under way: try again when it is done")
        async with self._exporting:
            with tempfile.TemporaryDirectory(prefix="sfdrig-web-") as work:
                path, name = await self._history(
                    request, lambda h: h.download(run_id, fmt, Path(work)))
                return await _send_whole(request, path, name)

    async def make_report(self, request: web.Request) -> web.Response:
        """Identify the run in a process of its own (`sfdrig identify --no-store`: the run file
        is not written), one at a time, at a lower priority than the daemon."""
        self._guard(request, need_operator=True)
        run_id = request.match_info["run_id"]
        path, folder = await self._history(request, lambda h: h.report_job(run_id))
        if self._identifying.locked():
            raise _refused(503, "another identification is under way: try again when it is "
                                "done")
        async with self._identifying:
            nice = [n, "-n", "10"] if (n := shutil.which("nice")) else []
            proc = await asyncio.create_subprocess_exec(
                *nice, *self.cfg.identify_command, str(path), "--no-store", "--report",
                str(folder), stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
                env={**os.environ, "PYTHONUNBUFFERED": "1"})
            try:
                async with asyncio.timeout(self.cfg.identify_timeout_s):
                    out, _ = await proc.communicate()
            except TimeoutError:
                proc.kill()
                await proc.wait()
                raise _refused(504, f"identification of {run_id} took longer than "
                                    f"{self.cfg.identify_timeout_s:g} s: stopped") from None
        text = out.decode("utf-8", "replace").strip()
        made = (folder / "index.html").is_file() and proc.returncode == 0
        return web.json_response({
            "ok": made, "data": {"lines": text.splitlines()[-40:]},
            "error": "" if made else f"identify {run_id}: " + (
                text.splitlines()[-1] if text else f"exit {proc.returncode}")})

    async def report_file(self, request: web.Request) -> web.StreamResponse:
        self._guard(request, need_operator=False)
        run_id, name = request.match_info["run_id"], request.match_info["name"]
        path = await self._history(request, lambda h: h.report_file(run_id, name))
        return web.FileResponse(path)

    async def add_note(self, request: web.Request) -> web.Response:
        s = self._guard(request, need_operator=True)
        run_id = request.match_info["run_id"]
        body = await self._json_object(request)
        notes = await self._history(request, lambda h: h.add_note(run_id, s.name,
                                                                   body.get("text")))
        return web.json_response({"ok": True, "error": "", "notes": notes})

    # --- live frames ----------------------------------------------------------------------
    async def websocket(self, request: web.Request) -> web.WebSocketResponse:
        s = self._guard(request, need_operator=False)
        ws = web.WebSocketResponse(heartbeat=20.0, compress=False)  # CPU over bytes
        await ws.prepare(request)
        b = _Browser(ws, token=request.cookies.get(COOKIE))
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

    async def _close_revoked(self) -> None:
        """Close the WebSockets whose login key was revoked (the page then asks to log in)."""
        if self.cfg.key_dir is None:
            return
        for b in list(self.browsers):
            if self._session_of(b.token) is None:
                log.warning("closing a page whose key was revoked")
                self.browsers.discard(b)
                await b.ws.close(code=WS_REVOKED, message=b"key revoked: log in again")

    async def _tick(self) -> None:
        period = 1.0 / self.cfg.fps
        loop = asyncio.get_running_loop()
        next_check = loop.time()
        while True:
            t0 = loop.time()
            if t0 >= next_check:
                next_check = t0 + REVOCATION_CHECK_S
                await self._close_revoked()
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

    async def _start_lease_keeper(self, app: web.Application) -> None:
        self._lease_keeper = asyncio.create_task(self._keep_lease())

    async def _close_browsers(self, app: web.Application) -> None:
        for task in (self._ticker, self._lease_keeper):
            if task is not None:
                task.cancel()
        for b in list(self.browsers):
            await b.ws.close()



def _bad(message: str) -> web.HTTPBadRequest:
    """A 400 answer in the commands' JSON shape."""
    return web.HTTPBadRequest(content_type="application/json",
                              text=json.dumps({"ok": False, "error": message, "data": {}}))


def _timed_out(message: str) -> web.HTTPRequestTimeout:
    """A 408 answer that also closes the connection (the rest of the body may still come)."""
    resp = web.HTTPRequestTimeout(text=message)
    resp.force_close()
    return resp


def _refused(status: int, message: str) -> web.HTTPException:
    """An answer of ``status`` in the commands' JSON shape."""
    cls = {400: web.HTTPBadRequest, 404: web.HTTPNotFound, 409: web.HTTPConflict,
           503: web.HTTPServiceUnavailable, 504: web.HTTPGatewayTimeout}.get(
        status, web.HTTPInternalServerError)
    return cls(content_type="application/json",
               text=json.dumps({"ok": False, "error": message, "data": {}}))


def _attachment_headers(name: str) -> dict[str, str]:
    return {"Content-Disposition": f'attachment; filename="{name}"',
            "Content-Type": "application/octet-stream"}


def _attachment(path: Path, name: str) -> web.FileResponse:
    return web.FileResponse(path, headers=_attachment_headers(name))


async def _send_whole(request: web.Request, path: Path, name: str) -> web.StreamResponse:
    """Send ``path`` as the attachment ``name`` and return once it is all sent (or the browser
    went away): the caller may delete the file then. Read in chunks off the event loop."""
    resp = web.StreamResponse(headers=_attachment_headers(name))
    resp.content_length = path.stat().st_size
    await resp.prepare(request)
    loop = asyncio.get_running_loop()
    try:
        with path.open("rb") as f:
            while chunk := await loop.run_in_executor(None, f.read, SEND_CHUNK_BYTES):
                await resp.write(chunk)
        await resp.write_eof()
    except ConnectionError:  # the browser cancelled the download: nothing to answer
        log.info("download of %s stopped: the browser went away", name)
    return resp
