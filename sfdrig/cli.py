"""The `sfdrig` command line: one sub-command per module in `sfdrig.commands`.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
The CLI wires backends and configs; it never talks to hardware itself. Every command ends
without a traceback on Ctrl-C (exit 130) and on a closed pipe (`sfdrig status --json | head`:
quietly, exit 141), handled here once. Commands answer their own errors; one that escapes them
(a defect) is named in one line, its traceback written to a file for the report (exit 70).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import tempfile
import traceback
from types import ModuleType

# Order is the order shown in --help.
COMMAND_MODULES = (
    "demo", "daemon", "sweep", "watch", "pump", "status", "runs", "pause", "resume", "abort",
    "keys", "proxy", "sim_server", "channels", "commission", "structure", "identify",
    "import_data", "export", "diagnose", "calibrate", "web",
)
# The command name of each module where it differs from the module's name.
_NAMED = {"import": "import_data", "sim-server": "sim_server"}


def _module_of(argv: list[str]) -> str | None:
    """The module of the command ``argv`` names, or None (no command, an option first, or an
    unknown name: then every command is loaded, for --help and argparse's error)."""
    if not argv or argv[0].startswith("-"):
        return None
    name = _NAMED.get(argv[0], argv[0])
    return name if name in COMMAND_MODULES else None


def _load_commands(only: str | None = None) -> list[ModuleType]:
    # one command loads only its own module: `sfdrig web` or `sfdrig watch` do not carry the
    # simulator's numba/LLVM (90 MB resident) or h5py, and every command starts sooner
    mods = []
    for name in (only,) if only else COMMAND_MODULES:
        try:
            mods.append(importlib.import_module(f"sfdrig.commands.{name}"))
        except ModuleNotFoundError as err:
            if err.name != f"sfdrig.commands.{name}":
                raise
    return mods


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sfdrig",
        description="Squeeze-film-damper rig: shaker control, live data, run files, analysis.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for mod in _load_commands(only):
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        args = build_parser(_module_of(argv)).parse_args(argv)
        try:
            code = int(args._run(args) or 0)
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            code = 130
        except BrokenPipeError:
            raise  # answered below, as the closed pipe it is
        except Exception as err:  # a defect: one line here, the traceback in a file
            code = _unexpected(argv[0] if argv else "", err)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's last flush
        return code
    except BrokenPipeError:
        # `sfdrig status --json | head`: the reader has gone; stop quietly, as `cat` would
        _discard_stdout()
        return 128 + signal.SIGPIPE


def _unexpected(command: str, err: Exception) -> int:
    """Name an error no command answered, keep its traceback for the bug report; exit 70
    (EX_SOFTWARE)."""
    fd, path = tempfile.mkstemp(prefix=f"sfdrig-{command or 'cli'}-", suffix=".traceback")
    with os.fdopen(fd, "w") as f:
        traceback.print_exception(err, file=f)
    print(f"sfdrig {command}: unexpected error: {type(err).__name__}: {err} (a defect: please "
          f"report it with {path})", file=sys.stderr)
    return 70


def _discard_stdout() -> None:
    """Point stdout at /dev/null, so that nothing left in its buffer fails again at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # no file descriptor (tests capture stdout)
        pass


if __name__ == "__main__":
    sys.exit(main())
