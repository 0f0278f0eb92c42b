"""The `sfdrig` command line: one sub-command per module in `sfdrig.commands`.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
The CLI wires backends and configs; it never talks to hardware itself.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from types import ModuleType

# Order is the order shown in --help.
COMMAND_MODULES = (
    "demo", "daemon", "sweep", "watch", "pump", "status", "runs", "abort", "keys", "proxy",
    "sim_server", "structure", "identify", "import_data", "diagnose", "calibrate", "web",
)


def _load_commands() -> list[ModuleType]:
    mods = []
    for name in COMMAND_MODULES:
        try:
            mods.append(importlib.import_module(f"sfdrig.commands.{name}"))
        except ModuleNotFoundError as err:
            if err.name != f"sfdrig.commands.{name}":
                raise
    return mods


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sfdrig",
        description="Squeeze-film-damper rig: shaker control, live data, run files, analysis.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for mod in _load_commands():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
