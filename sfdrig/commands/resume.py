"""`sfdrig resume`: continue a paused sweep; the interrupted step runs again from its start."""

from __future__ import annotations

import argparse

from sfdrig.commands._client_args import request_command
from sfdrig.commands.pause import add_arguments

NAME = "resume"
HELP = "resume a paused sweep (the interrupted step runs again from its start)"
__all__ = ["HELP", "NAME", "add_arguments", "run"]


def run(args: argparse.Namespace) -> int:
    return request_command(
        args, NAME, lambda client: client.resume(),
        lambda reply: f"resumed (daemon state {reply.state.value}): repeating the interrupted "
                      "step")
