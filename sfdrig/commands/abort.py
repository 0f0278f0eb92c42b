"""`sfdrig abort`: abort the running sweep (drives ramp to zero, the run file closes valid)."""

from __future__ import annotations

import argparse

from sfdrig.commands._client_args import add_connection_arguments, request_command

NAME = "abort"
HELP = "abort the running sweep: drives ramp to zero, the run is marked aborted"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)
    parser.add_argument("--reason", default="operator abort (sfdrig abort)",
                        help="recorded in the run file (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    return request_command(args, NAME, lambda client: client.abort(args.reason),
                           lambda reply: f"abort sent; daemon state {reply.state.value}")
