"""One daemon per runs directory: a second daemon there would recover the first one's run files
as interrupted, overwrite its ``daemon.json`` and delete it when it exits. The lock is a
`daq.locks.InstanceLock` (a flock the kernel drops when its holder dies) on
``RUNS_DIR/daemon.lock``; the board's own lock (one tool per board) is `daq.board.board_lock`."""

from __future__ import annotations

from pathlib import Path

from daq.locks import InstanceLock

RUNS_LOCK_NAME = "daemon.lock"


def runs_lock(runs_dir: Path) -> InstanceLock:
    """The lock of one runs directory (not yet acquired)."""
    return InstanceLock(Path(runs_dir) / RUNS_LOCK_NAME, f"runs directory {runs_dir}")
