"""Shared by the commands that open a board (``daemon``, ``commission``, ``channels check`` and
``channels live``): the check of ``--grpc-target`` and the board's lock (`daq.board`). Not a
command itself (the CLI loads only the modules it lists)."""

from __future__ import annotations

from typing import Any

from daq.board import Board, board_lock, grpc_target_problem
from daq.locks import AlreadyRunning, InstanceLock

__all__ = ["AlreadyRunning", "busy_line", "grpc_target_error", "hold_board"]


def grpc_target_error(command: str, target: str | None) -> str:
    """The one line refusing ``--grpc-target target`` ("" if it is usable or not given)."""
    if target is None:
        return ""
    problem = grpc_target_problem(target)
    return f"{command}: --grpc-target {target!r}: {problem}" if problem else ""


def hold_board(board: Board, **info: Any) -> InstanceLock | None:
    """Take ``board``'s lock for the life of this process (None: the simulated rig in process
    has none). Raises `AlreadyRunning` naming the holder's pid and command line, or `OSError`
    when the lock directory cannot be used."""
    lock = board_lock(board)
    return lock.acquire(board=board.describe(), **info) if lock is not None else None


def busy_line(command: str, err: AlreadyRunning) -> str:
    """``commission: nidaqmx device Dev1 via gRPC ... is in use by pid 1234 (sfdrig daemon
    ...): stop it first``."""
    return f"{command}: {err}: stop it first (one tool at a time on a board)"
