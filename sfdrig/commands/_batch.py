"""One action per file of a command's list: a failure is one line and the next file goes on."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable
from pathlib import Path


def run_each(paths: Iterable[Path], action: Callable[[Path], object],
             known: tuple[type[Exception], ...]) -> int:
    """Call ``action(path)`` for every path; errors of the ``known`` kinds (whose messages name
    the file) print as they are, anything else with the file and its type, never a traceback.
    Returns how many failed."""
    failed = 0
    for path in paths:
        try:
            action(path)
        except BrokenPipeError:
            raise  # stdout's reader has gone: the CLI stops quietly (sfdrig.cli)
        except known as err:
            print(f"error: {err}", file=sys.stderr)
            failed += 1
        except Exception as err:  # noqa: BLE001 - one line, never a traceback
            print(f"error: {path}: {type(err).__name__}: {err}", file=sys.stderr)
            failed += 1
    return failed
