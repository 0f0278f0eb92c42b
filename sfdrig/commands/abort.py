"""`sfdrig abort`: abort the running sweep (drives ramp to zero, the run file closes valid)."""

from __future__ import annotations

import argparse

from control.wire.client import CommandRefused, DaemonUnavailable
from sfdrig.commands._client_args import add_connection_arguments, command_client

NAME = "abort"
HELP = "abort the running sweep: drives ramp to zero, the run is marked aborted"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)
    parser.add_argument("--reason", default="operator abort (sfdrig abort)",
                        help="recorded in the run file (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    try:
        with command_client(args) as client:
            reply = client.abort(args.reason)
    except (DaemonUnavailable, CommandRefused) as err:
        print(f"abort: {err}")
        return 1
    print(f"abort sent; daemon state {reply.state.value}")
    return 0
