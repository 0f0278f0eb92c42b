"""`sfdrig proxy`: fan the daemon's live data out to many subscribers, off the rig PC.

Deployment
----------
The daemon runs on the rig PC, next to the DAQ hardware, and publishes every block once. The
proxy runs on another host (a lab server): it subscribes to the daemon (XSUB) and re-publishes to
any number of subscribers (XPUB), using ZeroMQ's own ``zmq.proxy``, so the cost of fan-out (copies,
slow subscribers, network) lands on the proxy host and never on the acquisition loop. Subscribers
(``sfdrig watch``, ``sfdrig sweep``, notebooks with `control.wire.client.Subscriber`) connect to the
proxy, anywhere on the network; commands still go straight to the daemon's command socket::

    rig PC:       sfdrig daemon --backend nidaqmx --data-endpoint tcp://10.0.0.5:5556 \\
                      --command-endpoint tcp://10.0.0.5:5555 --keys /etc/sfdrig/keys
    lab server:   sfdrig proxy --upstream tcp://10.0.0.5:5556 --bind tcp://0.0.0.0:6556 \\
                      --keys /etc/sfdrig/keys --key-name proxy
    anywhere:     sfdrig watch --data-endpoint tcp://labserver:6556 --command-endpoint \\
                      tcp://10.0.0.5:5555 --keys ~/keys --key-name operator

Subscriptions travel upstream through the proxy, so each subscriber still receives only its
topics. Sequence numbers pass through unchanged: a subscriber that falls behind the proxy sees its
gaps exactly as it would on the daemon. With CURVE, the proxy is a client of the daemon (a reader
key is enough) and a CURVE server to its own subscribers with the same key directory.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

import zmq

from control.wire.security import (
    DATA_DOMAIN,
    is_loopback,
    load_client_keys,
    load_server_keys,
    secure_client_socket,
    secure_server_socket,
    start_authenticator,
)

NAME = "proxy"
HELP = "relay the daemon's live data to many subscribers (ZeroMQ XSUB/XPUB proxy)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--upstream", required=True,
                        help="the daemon's data endpoint, e.g. tcp://rigpc:5556")
    parser.add_argument("--bind", default="tcp://127.0.0.1:0",
                        help="where subscribers connect (default: %(default)s, a random port)")
    parser.add_argument("--keys", type=Path, help="CURVE key directory (needed off loopback)")
    parser.add_argument("--key-name", default="viewer",
                        help="the proxy's own client key towards the daemon (default: "
                             "%(default)s)")
    parser.add_argument("--sndhwm", type=int, default=1000,
                        help="per-subscriber send high-water mark [messages] (default: "
                             "%(default)s)")


def run(args: argparse.Namespace) -> int:
    if not is_loopback(args.bind) and args.keys is None:
        print(f"proxy: binding {args.bind} beyond loopback requires --keys DIR", file=sys.stderr)
        return 2
    ctx = zmq.Context()
    auth = None
    xsub = ctx.socket(zmq.XSUB)
    xpub = ctx.socket(zmq.XPUB)
    ctrl_in = ctx.socket(zmq.PAIR)
    ctrl_out = ctx.socket(zmq.PAIR)
    for s in (xsub, xpub, ctrl_in, ctrl_out):
        s.linger = 0
    xpub.sndhwm = args.sndhwm
    if args.keys is not None:
        auth = start_authenticator(ctx, load_server_keys(args.keys))
        secure_server_socket(xpub, load_server_keys(args.keys), DATA_DOMAIN)
        secure_client_socket(xsub, load_client_keys(args.keys, args.key_name))
    bind = args.bind[:-2] + ":*" if args.bind.endswith(":0") else args.bind
    xpub.bind(bind)
    xsub.connect(args.upstream)
    ctrl_in.bind("inproc://sfdrig-proxy-control")
    ctrl_out.connect("inproc://sfdrig-proxy-control")
    print(f"data={xpub.getsockopt_string(zmq.LAST_ENDPOINT)} upstream={args.upstream}",
          flush=True)

    stop = threading.Event()

    def terminate(signum: int, frame: object) -> None:
        stop.set()

    old = {sig: signal.signal(sig, terminate) for sig in (signal.SIGTERM, signal.SIGINT)}
    # zmq.proxy_steerable blocks in C. It runs in a thread of its own: Python runs a signal's
    # handler only in the main thread, and a SIGTERM the kernel delivered to another thread
    # never interrupted the main thread's poll (the proxy then ignored it: 1 in a few CI runs).
    # The main thread waits in Python, wakes for the handler within 0.2 s, and steers the
    # proxy to TERMINATE.
    failure: list[BaseException] = []

    def relay() -> None:
        try:
            zmq.proxy_steerable(xsub, xpub, None, ctrl_out)
        except zmq.ContextTerminated:
            pass
        except BaseException as err:  # reported by the main thread
            failure.append(err)

    proxy = threading.Thread(target=relay, name="sfdrig-proxy", daemon=True)
    proxy.start()
    try:
        while proxy.is_alive() and not stop.wait(0.2):
            pass
    finally:
        if proxy.is_alive():
            ctrl_in.send(b"TERMINATE")
            proxy.join(5)
        for sig, handler in old.items():
            signal.signal(sig, handler)
        for s in (xsub, xpub, ctrl_in, ctrl_out):
            s.close()
        if auth is not None:
            auth.stop()
        ctx.term()
    if failure:
        print(f"proxy: stopped: {failure[0]}", file=sys.stderr)
        return 1
    return 0
