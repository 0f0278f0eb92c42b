"""`sfdrig pump on|off`: switch the oil pump relay (refused off while the shakers run)."""

from __future__ import annotations

import argparse

from sfdrig.commands._client_args import add_connection_arguments, request_command

NAME = "pump"
HELP = "switch the oil pump on or off (off is refused while the shakers run)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("switch", choices=["on", "off"])
    add_connection_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return request_command(args, NAME, lambda client: client.pump(args.switch == "on"),
                           lambda reply: f"pump {'on' if reply.data['pump_on'] else 'off'}")
