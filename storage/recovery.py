"""Run files whose writer died (kill -9, power loss): tell them apart from live ones, and close
them as "interrupted" so that any HDF5 reader opens them.

A writer that dies leaves the superblock's status flags set ("open for write"), and a plain
``h5py.File(path, "r")`` refuses the file. HDF5 has no public call to clear them (its ``h5clear
-s`` tool uses a private property), so `clear_open_flags` does what that tool does: it clears
the flags byte of the version 2/3 superblock and rewrites the superblock's checksum (Jenkins
lookup3, as HDF5 computes it). It refuses any superblock it does not recognise exactly.
"""

from __future__ import annotations

import os
import socket
import struct
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py

_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: A "running" file without a writer pid, not modified for this long, has lost its writer [s]
#: (live writers flush at least every second).
STALE_AFTER_S = 30.0


def writer_identity() -> dict[str, object]:
    """Attributes a writer records so that others can tell whether it is still alive."""
    return {"writer_pid": os.getpid(), "writer_host": socket.gethostname()}


def writer_gone(attrs: Any, path: Path,
                now: float | None = None) -> bool:
    """True when the process that wrote the "running" file at ``path`` is certainly gone: its
    pid is no longer alive on this host, or (no pid recorded, or another host) the file has not
    changed for `STALE_AFTER_S`. A reused pid reads as alive: the safe direction."""
    pid, host = attrs.get("writer_pid"), attrs.get("writer_host")
    if pid is not None and str(host) == socket.gethostname():
        try:
            os.kill(int(str(pid)), 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False  # alive, another user's
        return False
    return (time.time() if now is None else now) - path.stat().st_mtime > STALE_AFTER_S


def _lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle``, the checksum of HDF5 metadata."""
    m = 0xFFFFFFFF

    def rot(x: int, k: int) -> int:
        return ((x << k) | (x >> (32 - k))) & m

    length = len(data)
    a = b = c = (0xDEADBEEF + length + initval) & m
    i = 0
    while length > 12:
        a = (a + int.from_bytes(data[i:i + 4], "little")) & m
        b = (b + int.from_bytes(data[i + 4:i + 8], "little")) & m
        c = (c + int.from_bytes(data[i + 8:i + 12], "little")) & m
        a = (a - c) & m; a ^= rot(c, 4); c = (c + b) & m  # noqa: E702
        b = (b - a) & m; b ^= rot(a, 6); a = (a + c) & m  # noqa: E702
        c = (c - b) & m; c ^= rot(b, 8); b = (b + a) & m  # noqa: E702
        a = (a - c) & m; a ^= rot(c, 16); c = (c + b) & m  # noqa: E702
        b = (b - a) & m; b ^= rot(a, 19); a = (a + c) & m  # noqa: E702
        c = (c - b) & m; c ^= rot(b, 4); b = (b + a) & m  # noqa: E702
        length -= 12
        i += 12
    if length == 0:
        return c
    tail = data[i:i + length] + b"\x00" * (12 - length)
    a = (a + int.from_bytes(tail[0:4], "little")) & m
    b = (b + int.from_bytes(tail[4:8], "little")) & m
    c = (c + int.from_bytes(tail[8:12], "little")) & m
    c ^= b; c = (c - rot(b, 14)) & m  # noqa: E702
    a ^= c; a = (a - rot(c, 11)) & m  # noqa: E702
    b ^= a; b = (b - rot(a, 25)) & m  # noqa: E702
    c ^= b; c = (c - rot(b, 16)) & m  # noqa: E702
    a ^= c; a = (a - rot(c, 4)) & m  # noqa: E702
    b ^= a; b = (b - rot(a, 14)) & m  # noqa: E702
    c ^= b; c = (c - rot(b, 24)) & m  # noqa: E702
    return c


def clear_open_flags(path: str | Path) -> bool:
    """Clear the "open for write" flags a dead writer left in the superblock (``h5clear -s``).

    Returns True if flags were cleared, False if none were set. Call it only for a file whose
    writer is gone (`writer_gone`): a live writer would be corrupted.

    Raises
    ------
    ValueError
        When the superblock is not a version 2/3 one at offset 0 with a valid checksum.
    """
    with open(path, "r+b") as f:
        head = f.read(48)
        if head[:8] != _SIGNATURE or head[8] not in (2, 3) or head[9] not in (4, 8):
            raise ValueError(f"{path}: not a version 2/3 HDF5 superblock at offset 0")
        n = 12 + 4 * head[9]
        body, stored = head[:n], struct.unpack_from("<I", head, n)[0]
        if _lookup3(body) != stored:
            raise ValueError(f"{path}: superblock checksum does not match; not touching it")
        if body[11] == 0:
            return False
        cleared = body[:11] + b"\x00" + body[12:]
        f.seek(0)
        f.write(cleared + struct.pack("<I", _lookup3(cleared)))
        f.flush()
        os.fsync(f.fileno())
    return True


def close_interrupted(path: str | Path, reason: str) -> int:
    """Close a run file whose writer died: clear the open flags, then record status
    "interrupted", the reason, ``last_sample`` (one past the last sample on disk) and a stop
    time (the file's last change). Returns ``last_sample``."""
    path = Path(path)
    stopped = datetime.fromtimestamp(path.stat().st_mtime, UTC).isoformat(timespec="milliseconds")
    from storage.layout import LIBVER  # the format bounds every run file is written with

    clear_open_flags(path)
    with h5py.File(path, "r+", libver=LIBVER) as f:
        channels = f.get("channels")
        lengths = [ds.shape[0] for ds in channels.values()] if channels is not None else []
        last = int(min(lengths)) if lengths else 0
        f.attrs["status"] = "interrupted"
        f.attrs["status_reason"] = reason
        f.attrs["last_sample"] = last
        f.attrs["stop_time"] = stopped.replace("+00:00", "Z")
    return last
