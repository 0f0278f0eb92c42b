"""Shared wiring of the client commands (sweep, watch, pump, status, abort): where the daemon is
and which keys to use. Not a command itself (the CLI loads only the modules it lists)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path

from control.wire.client import (
    CommandClient,
    CommandRefused,
    DaemonUnavailable,
    Subscriber,
    process_gone,
)
from control.wire.protocol import Reply
from control.wire.security import ClientKeys, load_client_keys

DEFAULT_RUNS_DIR = Path("runs")
STATE_FILE_NAME = "daemon.json"


def add_connection_arguments(parser: argparse.ArgumentParser, data: bool = False) -> None:
    g = parser.add_argument_group("connection")
    g.add_argument("--runs-dir", type=Path, default=DEFAULT_RUNS_DIR,
                   help="the daemon's runs directory; its daemon.json names the endpoints "
                        "(default: %(default)s)")
    g.add_argument("--command-endpoint", help="daemon command endpoint, e.g. tcp://host:5555")
    if data:
        g.add_argument("--data-endpoint",
                       help="live-data endpoint (the daemon's, or a proxy's XPUB)")
    g.add_argument("--keys", type=Path, help="CURVE key directory (made by `sfdrig keys`)")
    g.add_argument("--key-name", default="operator",
                   help="this client's key name in KEYS/clients (default: %(default)s)")
    g.add_argument("--timeout", type=float, default=5.0,
                   help="seconds to wait for a reply (default: %(default)s)")


def _state(args: argparse.Namespace) -> dict[str, str]:
    path = Path(args.runs_dir) / STATE_FILE_NAME
    try:
        state = dict(json.loads(path.read_text()))
        if process_gone(state.get("pid")):
            raise SystemExit(
                f"the daemon that wrote {path} (pid {state['pid']}) is not running: start "
                f"`sfdrig daemon --runs-dir {args.runs_dir}` (it takes the stale file over)")
        return state
    except FileNotFoundError:
        raise SystemExit(
            f"no daemon state file {path}: is `sfdrig daemon --runs-dir {args.runs_dir}` running? "
            f"(or pass --command-endpoint/--data-endpoint)"
        ) from None
    except (OSError, ValueError) as err:
        raise SystemExit(f"cannot read {path}: {err}") from None


def keys(args: argparse.Namespace) -> ClientKeys | None:
    return load_client_keys(args.keys, args.key_name) if args.keys else None


def command_client(args: argparse.Namespace) -> CommandClient:
    endpoint = args.command_endpoint or _state(args)["command"]
    return CommandClient(endpoint, timeout_s=args.timeout, keys=keys(args))


def subscriber(args: argparse.Namespace, topics: list[str] | None = None,
               rcvhwm: int = 1000) -> Subscriber:
    endpoint = getattr(args, "data_endpoint", None) or _state(args)["data"]
    return Subscriber(endpoint, topics=topics, rcvhwm=rcvhwm, keys=keys(args))


#: How the command line sends each request a refusal names as allowed now.
CLI_COMMANDS = {"start": "sfdrig sweep", "start_test": "sfdrig structure",
                "pause": "sfdrig pause", "resume": "sfdrig resume", "abort": "sfdrig abort",
                "reset": "sfdrig status --reset", "pump": "sfdrig pump on|off",
                "status": "sfdrig status", "list_runs": "sfdrig runs"}


def not_done(err: CommandRefused | DaemonUnavailable) -> str:
    """Why a request was not done; a refusal for the daemon's state also names the commands
    that send what it allows now (its words are the wire's: `start`, `list_runs`)."""
    allowed = err.reply.data.get("allowed") if isinstance(err, CommandRefused) else None
    if not isinstance(allowed, list):
        return str(err)
    cli = [CLI_COMMANDS[c] for c in allowed if c in CLI_COMMANDS]
    return f"{err}; from the command line: {', '.join(cli)}" if cli else str(err)


def request_command(args: argparse.Namespace, what: str, send: Callable[[CommandClient], Reply],
                    done: Callable[[Reply], str]) -> int:
    """A command that is one request (``send(client)``): exit 0 with ``done(reply)`` printed,
    or 1 with why it could not be sent or was refused, led by ``what`` (the command's name)."""
    try:
        with command_client(args) as client:
            reply = send(client)
    except (DaemonUnavailable, CommandRefused) as err:
        print(f"{what}: {not_done(err)}")
        return 1
    print(done(reply))
    return 0
