"""`sfdrig pause`: pause the running sweep (the drives ramp to zero, acquisition goes on);
`sfdrig resume` continues it, repeating the interrupted step from its start."""

from __future__ import annotations

import argparse

from sfdrig.commands._client_args import add_connection_arguments, request_command

NAME = "pause"
HELP = "pause the running sweep: drives ramp to zero and hold until `sfdrig resume`"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return request_command(
        args, NAME, lambda client: client.pause(),
        lambda reply: f"paused (daemon state {reply.state.value}): the drives ramp to zero; "
                      "`sfdrig resume` repeats the interrupted step, `sfdrig abort` ends the run")
