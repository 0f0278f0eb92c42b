"""Shared by the commands that open a board (``daemon``, ``commission``, ``channels check`` and
``channels live``): the check of ``--grpc-target`` and the board's lock (`daq.board`). Not a
command itself (the CLI loads only the modules it lists)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from daq.board import Board, board_lock, grpc_target_problem
from daq.locks import AlreadyRunning, InstanceLock

__all__ = ["BoardBusy", "board_held", "grpc_target_error", "hold_board"]


class BoardBusy(Exception):
    """The board cannot be had; the message is the command's one line (exit 2)."""


def grpc_target_error(command: str, target: str | None) -> str:
    """The one line refusing ``--grpc-target target`` ("" if it is usable or not given)."""
    if target is None:
        return ""
    problem = grpc_target_problem(target)
    return f"{command}: --grpc-target {target!r}: {problem}" if problem else ""


def hold_board(board: Board, **info: str | bool) -> InstanceLock | None:
    """Take ``board``'s lock until `InstanceLock.release` or the end of this process (None: the
    simulated rig in process has none). Raises `AlreadyRunning` naming the holder's pid and
    command line, or `OSError` when the lock directory cannot be used."""
    lock = board_lock(board)
    return lock.acquire(board=board.describe(), **info) if lock is not None else None


@contextlib.contextmanager
def board_held(command: str, board: Board) -> Iterator[None]:
    """Hold ``board``'s lock while the block runs; `BoardBusy` (``commission: nidaqmx device
    Dev1 via gRPC ... is in use by pid 1234 (sfdrig daemon ...): stop it first ...``) when
    another process holds it, idle or not."""
    try:
        lock = hold_board(board)
    except AlreadyRunning as err:
        raise BoardBusy(f"{command}: {err}: stop it first (one tool at a time on a board)") \
            from None
    except OSError as err:
        raise BoardBusy(f"{command}: cannot use the board's lock file {err.filename}: "
                        f"{err.strerror or err}") from None
    try:
        yield
    finally:
        if lock is not None:
            lock.release()
