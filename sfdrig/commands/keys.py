"""`sfdrig keys DIR`: make CURVE keys for a daemon exposed beyond loopback.

Gives a server key pair, and one key pair per client: commanders may send commands and read live
data; readers may only read live data. Copy ``DIR/server.key`` and ``DIR/clients/NAME.key_secret``
to each client; keep ``DIR/server.key_secret`` on the rig PC. See `control.wire.security`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from control.wire.security import KeyFileError, make_keys

NAME = "keys"
HELP = "make CURVE keys (server, commanders, read-only viewers) for a daemon off loopback"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("directory", type=Path, help="key directory to create or extend")
    parser.add_argument("--commander", action="append", default=None, metavar="NAME",
                        help="a client allowed to command (repeatable; default for a new "
                             "directory: operator)")
    parser.add_argument("--reader", action="append", default=None, metavar="NAME",
                        help="a client allowed to read live data only (repeatable; "
                             "default for a new directory: viewer)")


def run(args: argparse.Namespace) -> int:
    # A new directory gets one commander and one reader by default; an existing one only
    # the clients asked for.
    new_dir = not (args.directory / "server.key_secret").exists()
    commanders = args.commander if args.commander is not None else (
        ["operator"] if new_dir else [])
    readers = args.reader if args.reader is not None else (["viewer"] if new_dir else [])
    try:
        written = make_keys(args.directory, commanders, readers)
    except KeyFileError as err:
        print(f"keys: {err}")
        return 1
    for p in written:
        print(p)
    print(f"start the daemon with --keys {args.directory}; give each client "
          f"{args.directory}/server.key and its own {args.directory}/clients/NAME.key_secret")
    return 0
