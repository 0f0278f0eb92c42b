"""One daemon per runs directory and per device: advisory locks that a dead process releases.

A daemon takes two exclusive `fcntl.flock` locks before it touches anything: one on
``RUNS_DIR/daemon.lock`` (a second daemon there would recover the first one's run files as
interrupted, overwrite its ``daemon.json`` and delete it when it exits) and, on a board, one on
a file named after the device in a per-user runtime directory (two daemons must not drive one
board, whether through the local driver or the same NI gRPC device server). The kernel drops a
flock when its holder exits, however it exits, so the lock of a killed daemon is simply taken
over; the lock files are never deleted (deleting one would let two holders lock two files).
Each lock file holds its holder's pid and what it serves, for the message of the refusal.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any

RUNS_LOCK_NAME = "daemon.lock"


class AlreadyRunning(RuntimeError):
    """Another live process holds the lock; ``holder`` is what its lock file says."""

    def __init__(self, message: str, holder: dict[str, Any]) -> None:
        super().__init__(message)
        self.holder = holder


class InstanceLock:
    """An exclusive, non-blocking flock on ``path``, held until `release` or the process ends.

    Parameters
    ----------
    path : Path
        The lock file (created if missing, never deleted).
    what : str
        What the lock guards, for messages ("runs directory runs", "device Dev1 ...").
    """

    def __init__(self, path: Path, what: str) -> None:
        self.path = Path(path)
        self.what = what
        self._fd: int | None = None

    def acquire(self, **info: Any) -> InstanceLock:
        """Take the lock and write ``{"pid": ..., **info}`` into the file.

        Raises
        ------
        AlreadyRunning
            If another process holds it (the message names its pid and ``info``).
        """
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise AlreadyRunning(f"{self.what} is in use by another daemon "
                                 f"({describe_holder(holder)})", holder) from None
        except BaseException:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({"pid": os.getpid(), **info}).encode(), 0)
        self._fd = fd
        return self

    def update(self, **info: Any) -> None:
        """Add to what the lock file says about its holder (e.g. the endpoints once bound)."""
        if self._fd is None:
            return
        holder = {**_read_holder(self._fd), **info, "pid": os.getpid()}
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, json.dumps(holder).encode(), 0)

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None


def _read_holder(fd: int) -> dict[str, Any]:
    try:
        data = json.loads(os.pread(fd, 65536, 0) or b"{}")
    except ValueError:
        return {}
    return data if isinstance(data, dict) else {}


def describe_holder(holder: dict[str, Any]) -> str:
    """``pid 1234, command=tcp://... data=tcp://..., runs dir runs`` from a lock file's fields."""
    parts = [f"pid {holder.get('pid', '?')}"]
    if holder.get("command"):
        parts.append(f"command={holder['command']} data={holder.get('data', '?')}")
    elif "command" not in holder:
        parts.append("still starting")
    if holder.get("runs_dir"):
        parts.append(f"runs dir {holder['runs_dir']}")
    return ", ".join(parts)


def runtime_dir() -> Path:
    """This user's directory for device locks: ``$SFDRIG_RUNTIME_DIR`` if set, else
    ``$XDG_RUNTIME_DIR/sfdrig``, else ``<tmp>/sfdrig-<uid>``."""
    if os.environ.get("SFDRIG_RUNTIME_DIR"):
        return Path(os.environ["SFDRIG_RUNTIME_DIR"])
    base = os.environ.get("XDG_RUNTIME_DIR")
    if base and Path(base).is_dir():
        return Path(base) / "sfdrig"
    return Path(tempfile.gettempdir()) / f"sfdrig-{os.getuid()}"


def device_key(device_name: str, grpc_target: str | None) -> str:
    """What identifies a board: its name behind the local driver, or the gRPC device server's
    ``host:port`` and the name (``localhost`` and ``127.0.0.1`` are one host)."""
    if not grpc_target:
        return f"local-{device_name}"
    host, _, port = grpc_target.strip().lower().rpartition(":")
    if host in ("localhost", "127.0.0.1", "[::1]", "::1", ""):
        host = "localhost"
    return f"grpc-{host}-{port}-{device_name}"


def device_lock(device_name: str, grpc_target: str | None,
                directory: Path | None = None) -> InstanceLock:
    """The lock of one board (not yet acquired)."""
    key = device_key(device_name, grpc_target)
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", key)
    where = f"through the NI gRPC device server {grpc_target}" if grpc_target \
        else "on the local NI-DAQmx driver"
    return InstanceLock((directory or runtime_dir()) / f"device-{name}.lock",
                        f"device {device_name} {where}")


def runs_lock(runs_dir: Path) -> InstanceLock:
    """The lock of one runs directory (not yet acquired)."""
    return InstanceLock(Path(runs_dir) / RUNS_LOCK_NAME, f"runs directory {runs_dir}")
