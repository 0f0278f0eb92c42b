"""The web server against someone on the lab network (issue 25): raw HTTP requests, as a tool
like curl sends them, to a real aiohttp server on a random loopback port. The daemon is a
stand-in that records the commands that reach it: a refused request must never get there."""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient, TestServer

from control.wire.security import make_keys
from web.auth import COOKIE
from web.server import WS_REVOKED, WebApp, WebConfig, host_name
from web.view import LiveView


class _Daemon:
    """The `DaemonLink` as the server uses it: the view, and the commands it forwards."""

    def __init__(self) -> None:
        self.view = LiveView()
        self.sent: list[tuple[str, dict[str, Any]]] = []

    def try_command(self, cmd: str, **fields: Any) -> dict[str, Any]:
        self.sent.append((cmd, fields))
        return {"ok": True, "error": "", "data": {}}


Raw = Callable[[bytes], Awaitable[tuple[int, dict[str, str], bytes]]]


async def _raw(port: int, request: bytes, timeout_s: float = 10.0
               ) -> tuple[int, dict[str, str], bytes]:
    """Send ``request`` as it is; (status, headers with lower-case names, body)."""
    r, w = await asyncio.open_connection("127.0.0.1", port)
    try:
        w.write(request)
        await w.drain()
        data = await asyncio.wait_for(r.read(), timeout_s)
    finally:
        w.close()
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {}
    for line in lines[1:]:
        k, _, v = line.partition(":")
        headers[k.strip().lower()] = v.strip()
    return int(lines[0].split()[1]), headers, body


def _post(path: str, body: bytes, host: str, origin: str | None = None, cookie: str = "",
          length: int | None = None) -> bytes:
    head = [f"POST {path} HTTP/1.1", f"Host: {host}", "Content-Type: application/json",
            f"Content-Length: {len(body) if length is None else length}", "Connection: close"]
    if origin:
        head.append(f"Origin: {origin}")
    if cookie:
        head.append(f"Cookie: {COOKIE}={cookie}")
    return ("\r\n".join(head) + "\r\n\r\n").encode() + body


def _get(path: str, host: str) -> bytes:
    return f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode()


def _serve(app: WebApp, test: Callable[[TestServer, int], Awaitable[Any]]) -> Any:
    async def main() -> Any:
        server = TestServer(app.app)
        await server.start_server(**app.runner_options())  # (the constructor drops them)
        async with server:
            assert server.port is not None
            return await test(server, server.port)
    return asyncio.run(main())


PUMP_ON = b'{"cmd":"pump","on":true}'


def test_a_request_for_another_host_is_refused_dns_rebinding():
    """The issue's curl: Host and Origin of attacker.example on 127.0.0.1. Refused with 421 and
    the pump command never reaches the daemon; the same request naming this server goes on."""
    daemon = _Daemon()
    app = WebApp(daemon, WebConfig())  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> list[int]:
        evil = "attacker.example:8080"
        out = [(await _raw(port, _post("/api/command", PUMP_ON, evil, f"http://{evil}")))[0],
               (await _raw(port, _post("/api/command", PUMP_ON, evil)))[0],
               (await _raw(port, _get("/", evil)))[0],
               (await _raw(port, _get("/ws", "127.0.0.1.attacker.example")))[0]]
        assert daemon.sent == []
        ok = f"127.0.0.1:{port}"
        out.append((await _raw(port, _post("/api/command", PUMP_ON, ok, f"http://{ok}")))[0])
        out.append((await _raw(port, _post("/api/command", PUMP_ON, f"localhost:{port}")))[0])
        # a page of this server posting with another origin: still refused
        out.append((await _raw(port, _post("/api/command", PUMP_ON, ok, f"http://{evil}")))[0])
        return out

    assert _serve(app, test) == [421, 421, 421, 421, 200, 200, 403]
    assert daemon.sent == [("pump", {"on": True})] * 2


def test_host_names_are_parsed_strictly():
    assert host_name("127.0.0.1:8080") == "127.0.0.1"
    assert host_name("[::1]:8080") == "::1"
    assert host_name("LocalHost.") == "localhost"
    assert host_name("localhost:80x") is None
    assert host_name("") is None
    assert host_name("[::1") is None


def test_every_answer_forbids_framing():
    """Clickjacking: the page, its scripts, a refusal and a 404 all say DENY and carry a
    content security policy whose frame-ancestors is 'none'."""
    app = WebApp(_Daemon(), WebConfig())  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> list[tuple[int, dict[str, str]]]:
        ok = f"127.0.0.1:{port}"
        out = []
        for req in (_get("/", ok), _get("/static/app.js", ok), _get("/nothing", ok),
                    _get("/", "attacker.example"), _post("/api/command", b"{bad", ok)):
            status, headers, _ = await _raw(port, req)
            out.append((status, headers))
        return out

    answers = _serve(app, test)
    assert [s for s, _ in answers] == [200, 200, 404, 421, 400]
    for _, h in answers:
        assert h["x-frame-options"] == "DENY"
        csp = [d.strip() for d in h["content-security-policy"].split(";")]
        assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp
        assert h["x-content-type-options"] == "nosniff"


@pytest.mark.parametrize("body", [b"{bad", b"[1,2,3]", b"null", b"[" * 100_000, b"\xff\xfe{}",
                                  b'"text"', b""])
def test_malformed_bodies_are_answered_400_with_a_message(body, caplog):
    daemon = _Daemon()
    app = WebApp(daemon, WebConfig())  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> list[tuple[int, bytes]]:
        host = f"127.0.0.1:{port}"
        return [(s, b) for path in ("/api/command", "/api/start", "/api/start_test")
                for s, _, b in [await _raw(port, _post(path, body, host))]]

    with caplog.at_level(logging.WARNING):
        answers = _serve(app, test)
    for status, text in answers:
        assert status == 400, (status, text[:200])
        error = json.loads(text)["error"]
        assert error.startswith("the body is not JSON") or error.startswith(
            "the body must be a JSON object"), error
    assert daemon.sent == []
    assert "Traceback" not in caplog.text and not [r for r in caplog.records
                                                  if r.levelno >= logging.ERROR]


@pytest.mark.paced  # a timing bound: closed between 0.4 and 5 s
def test_half_open_requests_are_closed_at_the_header_timeout():
    """1,000 half-open requests held for 60 s (issue 25): here 50 heads that never end and 50
    connections that send nothing are all closed by the server at its 0.5-s header timeout."""
    app = WebApp(_Daemon(), WebConfig(header_timeout_s=0.5))  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> list[tuple[float, bytes]]:
        async def hold(payload: bytes) -> tuple[float, bytes]:
            r, w = await asyncio.open_connection("127.0.0.1", port)
            t0 = time.monotonic()
            w.write(payload)
            await w.drain()
            data = await asyncio.wait_for(r.read(), 10)  # EOF: the server closed it
            w.close()
            return time.monotonic() - t0, data

        half = f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Slow: ".encode()
        return await asyncio.gather(*[hold(half) for _ in range(50)],
                                    *[hold(b"") for _ in range(50)])

    closed = _serve(app, test)
    assert len(closed) == 100 and all(data == b"" for _, data in closed)
    assert min(t for t, _ in closed) > 0.4 and max(t for t, _ in closed) < 5.0


@pytest.mark.paced  # a timing bound: answered between 0.4 and 5 s
def test_a_body_that_does_not_arrive_is_answered_408():
    daemon = _Daemon()
    app = WebApp(daemon, WebConfig(body_timeout_s=0.5))  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> tuple[int, float]:
        t0 = time.monotonic()
        req = _post("/api/command", PUMP_ON[:5], f"127.0.0.1:{port}", length=len(PUMP_ON))
        status, _, _ = await _raw(port, req)  # 5 of 24 bytes, then nothing
        return status, time.monotonic() - t0

    status, took = _serve(app, test)
    assert status == 408 and 0.4 < took < 5.0 and daemon.sent == []


def _login_request(port: int, key_file: Path) -> bytes:
    boundary = "sfdrigtestboundary"
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"key\"; "
            f"filename=\"{key_file.name}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
            ).encode() + key_file.read_bytes() + f"\r\n--{boundary}--\r\n".encode()
    return (f"POST /login HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: multipart/form-data;"
            f" boundary={boundary}\r\nContent-Length: {len(body)}\r\nConnection: close\r\n\r\n"
            ).encode() + body


@pytest.mark.paced  # a timing bound: the page closed within 2 s
def test_revoking_a_key_ends_its_sessions_at_once(tmp_path):
    """The commander's key file removed: its cookie is refused at the next request (before:
    200 for up to 12 h) and its open page is closed (code 4001) within about a second; a key
    moved from commanders/ to readers/ makes its session a viewer's."""
    keys = tmp_path / "keys"
    make_keys(keys, commanders=["operator", "second"], readers=[])
    daemon = _Daemon()
    app = WebApp(daemon, WebConfig(key_dir=keys))  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> dict[str, Any]:
        host = f"127.0.0.1:{port}"
        out: dict[str, Any] = {}
        cookies = {}
        for name in ("operator", "second"):
            status, headers, _ = await _raw(
                port, _login_request(port, keys / "clients" / f"{name}.key_secret"))
            assert status == 302, status
            cookies[name] = headers["set-cookie"].split(";")[0].split("=", 1)[1]
        cookie = cookies["operator"]
        out["before"] = (await _raw(port, _post("/api/command", PUMP_ON, host, cookie=cookie)))[0]
        async with TestClient(server) as client:
            ws = await client.ws_connect("/ws", headers={"Cookie": f"{COOKIE}={cookie}"})
            hello = await ws.receive(timeout=10)
            assert json.loads(hello.data)["role"] == "operator"
            (keys / "commanders" / "operator.key").unlink()  # revoked
            t0 = time.monotonic()
            out["after"] = (await _raw(port, _post("/api/command", PUMP_ON, host,
                                                   cookie=cookie)))[0]
            while (msg := await ws.receive(timeout=10)).type == WSMsgType.TEXT:
                pass  # frames until the close
            out["ws_closed_after_s"] = time.monotonic() - t0
            out["ws_close"] = (msg.type, ws.close_code)
            # the other commander's key moved to readers/: a viewer from its next request on
            second = keys / "commanders" / "second.key"
            second.rename(keys / "readers" / "second.key")
            out["moved"] = (await _raw(port, _post("/api/command", PUMP_ON, host,
                                                   cookie=cookies["second"])))[0]
        return out

    out = _serve(app, test)
    assert out["before"] == 200 and out["after"] == 401 and out["moved"] == 403
    assert out["ws_close"] == (WSMsgType.CLOSE, WS_REVOKED)
    assert out["ws_closed_after_s"] < 2.0
    assert daemon.sent == [("pump", {"on": True})]


def _get_as(path: str, host: str, cookie: str) -> bytes:
    return (f"GET {path} HTTP/1.1\r\nHost: {host}\r\nCookie: {COOKIE}={cookie}\r\n"
            "Connection: close\r\n\r\n").encode()


def test_the_page_and_its_answers_are_never_cached(tmp_path):
    """A browser keeps nothing of the page or its API (a cached page of a revoked key would
    never reach the login): ``no-store`` on the page, the login, each answer and refusal; the
    static files are checked for a newer version each time (``no-cache``). After the key is
    revoked the page is the login and /api/session says 401 (the page's cue to go there)."""
    keys = tmp_path / "keys"
    make_keys(keys, commanders=["operator"], readers=[])
    app = WebApp(_Daemon(), WebConfig(key_dir=keys))  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> dict[str, Any]:
        host = f"127.0.0.1:{port}"
        _, headers, _ = await _raw(port, _login_request(port, keys / "clients" /
                                                        "operator.key_secret"))
        cookie = headers["set-cookie"].split(";")[0].split("=", 1)[1]
        out: dict[str, Any] = {}
        for path in ("/", "/login", "/api/session", "/api/sweep/schema", "/api/runs",
                     "/static/app.js", "/static/uPlot.iife.min.js"):
            status, headers, body = await _raw(port, _get_as(path, host, cookie))
            out[path] = (status, headers.get("cache-control"))
        out["session"] = json.loads((await _raw(port, _get_as("/api/session", host, cookie)))[2])
        (keys / "commanders" / "operator.key").unlink()  # revoked
        for path in ("/", "/api/session"):
            status, headers, _ = await _raw(port, _get_as(path, host, cookie))
            out[f"revoked {path}"] = (status, headers.get("cache-control"),
                                      headers.get("location"))
        return out

    out = _serve(app, test)
    assert out["/"] == (200, "no-store") and out["/login"] == (200, "no-store")
    assert out["/api/session"] == (200, "no-store")
    assert out["/api/sweep/schema"] == (200, "no-store")
    assert out["/api/runs"] == (404, "no-store")  # (no runs directory here): a refusal too
    assert out["/static/app.js"] == (200, "no-cache")
    assert out["/static/uPlot.iife.min.js"] == (200, "no-cache")
    assert out["session"] == {"ok": True, "name": "operator", "role": "operator"}
    assert out["revoked /"] == (302, "no-store", "/login")
    assert out["revoked /api/session"] == (401, "no-store", None)


def test_a_viewer_is_refused_every_commanding_route():
    daemon = _Daemon()
    app = WebApp(daemon, WebConfig(anonymous_role="viewer"))  # type: ignore[arg-type]

    async def test(server: TestServer, port: int) -> list[int]:
        host = f"127.0.0.1:{port}"
        return [(await _raw(port, _post(path, body, host)))[0] for path, body in (
            ("/api/command", PUMP_ON), ("/api/start", b'{"example": "dry_circular.toml"}'),
            ("/api/start_test", b'{"test": "flow"}'))]

    assert _serve(app, test) == [403, 403, 403]
    assert daemon.sent == []


def test_the_allowed_hosts_of_sfdrig_web():
    from sfdrig.commands.web import allowed_hosts

    assert allowed_hosts("127.0.0.1", []) == ("127.0.0.1", "localhost", "::1")
    assert allowed_hosts("10.1.2.3", ["Rig-PC.lab"]) == ("127.0.0.1", "localhost", "::1",
                                                         "rig-pc.lab", "10.1.2.3")
    wildcard = allowed_hosts("0.0.0.0", [])
    assert socket.gethostname().lower() in wildcard and "attacker.example" not in wildcard
