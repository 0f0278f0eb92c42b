"""`sfdrig pump on|off`: switch the oil pump relay (refused off while the shakers run).

`pump off --wait` then waits until the film has drained, as the daemon's status counts it
(`film_drains_for_s`), so the next line of a script can start a dry sweep."""

from __future__ import annotations

import argparse
import time

from control.wire.client import CommandClient, CommandRefused, DaemonUnavailable
from sfdrig.commands._client_args import add_connection_arguments, command_client, not_done

NAME = "pump"
HELP = "switch the oil pump on or off (off is refused while the shakers run)"

#: how often `--wait` asks the daemon again [s]: the status is the clock that counts
POLL_S = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("switch", choices=["on", "off"])
    parser.add_argument("--wait", action="store_true",
                        help="with off: return once the film has drained (the daemon's "
                             "--film-drain-s after the switch), when a dry sweep may start")
    add_connection_arguments(parser)


def wait_for_the_film(client: CommandClient) -> float | None:
    """Ask the daemon's status until its film has drained: the seconds waited, or None when the
    pump was switched on again meanwhile (the film fills instead)."""
    started = time.monotonic()
    status = client.status()
    if status["film_drains_for_s"] > 0:
        print(f"film drains for {status['film_drains_for_s']:g} s", flush=True)
    while status["film_drains_for_s"] > 0 or status["pump_on"]:
        if status["pump_on"]:
            return None
        time.sleep(min(POLL_S, float(status["film_drains_for_s"])))
        status = client.status()
    return time.monotonic() - started


def run(args: argparse.Namespace) -> int:
    if args.wait and args.switch != "off":
        print("pump: --wait goes with `off` (it waits for the film to drain)")
        return 2
    try:
        with command_client(args) as client:
            reply = client.pump(args.switch == "on")
            print(f"pump {'on' if reply.data['pump_on'] else 'off'}", flush=True)
            if args.wait:
                waited = wait_for_the_film(client)
                if waited is None:
                    print("pump: switched on again while the film drained: it fills instead")
                    return 1
                print(f"film drained ({waited:.0f} s): a dry sweep may start")
    except (DaemonUnavailable, CommandRefused) as err:
        print(f"pump: {not_done(err)}")
        return 1
    return 0
