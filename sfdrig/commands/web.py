"""`sfdrig web`: the operator's live view in a browser (see `web/`).

A separate process that subscribes to the daemon (or a proxy) like any other client and sends
commands to the daemon's command socket. Loopback by default; beyond loopback it needs the
daemon's key directory (browsers log in with their client key file: operator or viewer) and TLS.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import socket
import ssl
import sys
from pathlib import Path

from aiohttp import web as aioweb
from threadpoolctl import threadpool_limits

from control.wire.client import DaemonUnavailable
from control.wire.security import KeyFileError, is_loopback
from sfdrig.commands._client_args import STATE_FILE_NAME, _state, add_connection_arguments, keys
from sfdrig.commands._native_memory import limit_arenas, pin_mmap_threshold, trim_heap
from web.auth import OPERATOR, VIEWER
from web.feed import DaemonLink
from web.server import LOOPBACK_NAMES, WebApp, WebConfig
from web.view import LiveView

NAME = "web"
HELP = "serve the live view (orbits, traces, harmonics, sweep progress) and controls to browsers"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default: %(default)s; off loopback needs "
                             "--keys and --tls-cert/--tls-key)")
    parser.add_argument("--port", type=int, default=8080,
                        help="TCP port, 0 for any free one (default: %(default)s)")
    parser.add_argument("--role", choices=(OPERATOR, VIEWER), default=OPERATOR,
                        help="without --keys: the role of every browser (default: %(default)s)")
    parser.add_argument("--examples", type=Path, default=Path("examples"),
                        help="directory of sweep TOML files offered on the page "
                             "(default: %(default)s)")
    parser.add_argument("--fps", type=float, default=10.0,
                        help="frames per second sent to each browser (default: %(default)s)")
    parser.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                        help="a host name (or address) browsers may use for this server, "
                             "repeatable; the loopback names, --host and, on a wildcard "
                             "address, this computer's names are allowed; a request naming any "
                             "other host is refused (DNS rebinding)")
    parser.add_argument("--tls-cert", type=Path, help="TLS certificate chain (PEM)")
    parser.add_argument("--tls-key", type=Path, help="TLS private key (PEM)")
    add_connection_arguments(parser, data=True)


def _fail(message: str) -> int:
    print(f"web: {message}", file=sys.stderr)
    return 1


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    loopback = is_loopback(f"tcp://{args.host}:1")
    if not loopback and args.keys is None:
        return _fail(f"serving on {args.host} beyond loopback requires --keys DIR "
                     "(browsers then log in with their client key file)")
    if (args.tls_cert is None) != (args.tls_key is None):
        return _fail("give both --tls-cert and --tls-key")
    if not loopback and args.tls_cert is None:
        return _fail(f"serving on {args.host} beyond loopback requires --tls-cert and "
                     "--tls-key (key files and session cookies must not cross the network "
                     "in clear)")
    if not 0 < args.fps <= 60:
        return _fail(f"--fps must be in (0, 60], got {args.fps:g}")
    tls = None
    if args.tls_cert is not None:
        tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        try:
            tls.load_cert_chain(args.tls_cert, args.tls_key)
        except (OSError, ssl.SSLError) as err:
            return _fail(f"cannot load TLS certificate {args.tls_cert}: {err}")
    try:
        client_keys = keys(args)
        command = args.command_endpoint or _state(args)["command"]
        data = args.data_endpoint or _state(args)["data"]
        # found through the state file: read it again while the daemon is gone, to find a
        # restarted one (on any ports); endpoints given by hand are kept
        followed = args.command_endpoint is None and args.data_endpoint is None
        link = DaemonLink(command, data, LiveView(), keys=client_keys, timeout_s=args.timeout,
                          state_file=args.runs_dir / STATE_FILE_NAME if followed else None)
    except (KeyFileError, SystemExit) as err:
        return _fail(str(err))
    try:
        link.start(timeout_s=max(args.timeout, 5.0))
    except DaemonUnavailable as err:
        link.close()
        return _fail(str(err))
    # The frame's lock-in fit is a small matrix product (0.4 ms on one thread). OpenBLAS would
    # spread it over every core and spin-wait there: on a loaded 2-core machine, 20 times the CPU
    # for the same product, taken from the paced daemon (docs/benchmarks.md).
    threadpool_limits(limits=1, user_api="blas")
    # Freed arrays of 128 KiB or more (a transfer request's segments, the frames' windows) go
    # back to the kernel, and what is smaller stays on one arena, not scattered over the
    # executor threads' own; the heap's free pages are given back after each transfer request
    # (sfdrig.commands._native_memory)
    logging.getLogger("sfdrig.web").info("%s; %s", pin_mmap_threshold(), limit_arenas(1))
    config = WebConfig(key_dir=args.keys, anonymous_role=args.role, examples_dir=args.examples,
                       fps=args.fps, secure_cookie=tls is not None,
                       allowed_hosts=allowed_hosts(args.host, args.allow_host),
                       runs_dir=args.runs_dir, release_memory=trim_heap)
    app = WebApp(link, config)
    try:
        asyncio.run(_serve(app, args.host, args.port, tls))
    except OSError as err:
        return _fail(f"cannot serve on {args.host}:{args.port}: {err}")
    finally:
        link.close()
    return 0


def allowed_hosts(host: str, extra: list[str]) -> tuple[str, ...]:
    """The names a browser may give in ``Host``: loopback, the bound address, ``extra`` and,
    bound to every interface, this computer's host name, its fully qualified name and the
    addresses that name resolves to."""
    names = [*LOOPBACK_NAMES, *extra]
    if host in ("0.0.0.0", "::", ""):
        names += [socket.gethostname(), socket.getfqdn()]
        with contextlib.suppress(OSError):  # and the addresses its name resolves to here
            names += socket.gethostbyname_ex(socket.gethostname())[2]
    else:
        names.append(host)
    return tuple(dict.fromkeys(n.lower() for n in names if n))


async def _serve(app: WebApp, host: str, port: int, tls: ssl.SSLContext | None) -> None:
    runner = aioweb.AppRunner(app.app, **app.runner_options())
    await runner.setup()
    site = aioweb.TCPSite(runner, host, port, ssl_context=tls)
    await site.start()
    bound = runner.addresses[0][1] if runner.addresses else port
    scheme = "https" if tls else "http"
    shown = f"[{host}]" if ":" in host else host
    print(f"url={scheme}://{shown}:{bound}/", flush=True)  # the first line: tests read it
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await stop.wait()
    finally:
        await runner.cleanup()
