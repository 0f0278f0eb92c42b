"""`sfdrig resume`: continue a paused sweep; the interrupted step runs again from its start."""

from __future__ import annotations

import argparse

from sfdrig.commands._client_args import add_connection_arguments, one_request

NAME = "resume"
HELP = "resume a paused sweep (the interrupted step runs again from its start)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)


def run(args: argparse.Namespace) -> int:
    reply = one_request(args, NAME, lambda client: client.resume())
    if reply is None:
        return 1
    print(f"resumed (daemon state {reply.state.value}): repeating the interrupted step")
    return 0
