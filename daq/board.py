"""Which board a tool drives, said the same way everywhere, and the lock that lets one tool at a
time open it.

`Board`: the backend (the simulated rig in this process, or NI-DAQmx), the device, and the NI gRPC
device server it is reached through (None: the local driver). `Board.describe` is the one
sentence every place shows (the daemon's first line, ``sfdrig status``, ``daemon.json``, the
page's header, run files, the commissioning report): "simulated rig (in process)", "nidaqmx
device Dev1 (local driver)", "nidaqmx device Dev1 via gRPC 127.0.0.1:31763" ("simulated nidaqmx
device ..." once the device has said it is one). Each backend names its own
(`daq.backend.DaqBackend.board`).

`board_lock`: one tool per board. Every command that opens a board (the daemon, ``commission``,
``channels check`` and ``channels live``) takes it before it touches the board; a second is
refused with the holder's pid and command line, whether the holder is idle or not. A flock the
kernel drops when its holder dies (`daq.locks`), on a file named after the board in this user's
runtime directory: the device's name behind the local driver, or the gRPC server's host:port and
the device (``localhost`` and ``127.0.0.1`` are one host). The simulated rig in process has no
lock: each process has its own rig, and two of them share nothing.

`grpc_target_problem`: what makes a gRPC target unusable (one place for the channel map's
``grpc_target`` and every ``--grpc-target``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from daq.locks import InstanceLock, runtime_dir

#: a host name (RFC 1123 labels), a dotted IPv4 address, or a bracketed IPv6 address
_HOST = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                   r"(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*)$")
SIM = "sim"
NIDAQMX = "nidaqmx"


def grpc_target_problem(target: str) -> str:
    """Why ``target`` is not a usable ``HOST:PORT`` of an NI gRPC device server ("" if it is):
    a host name or address (IPv6 in brackets) and a TCP port 1-65535."""
    example = "e.g. 127.0.0.1:31763"
    host, sep, port = target.rpartition(":")
    if not sep:
        return f"not HOST:PORT: no port ({example})"
    if not host:
        return f"not HOST:PORT: no host before the port ({example})"
    if not _HOST.match(host):
        return f"not HOST:PORT: {host!r} is not a host name or address ({example})"
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        return f"not HOST:PORT: the port {port!r} is not a TCP port 1-65535 ({example})"
    return ""


@dataclass(frozen=True)
class Board:
    """The board a backend drives.

    Attributes
    ----------
    backend : str
        ``"sim"`` (the simulated rig in this process) or ``"nidaqmx"``.
    device : str
        The device's name (the channel map's ``device.name``, e.g. Dev1).
    grpc_target : str or None
        ``host:port`` of the NI gRPC device server; None for the local driver (and the
        simulated rig).
    simulated : bool
        The device answered DAQmx's DevIsSimulated yes (`NidaqmxBackend` asks it at
        ``configure``): an NI simulated device, or `sfdrig sim-server`.
    """

    backend: str
    device: str
    grpc_target: str | None = None
    simulated: bool = False

    def describe(self) -> str:
        """The sentence every place names the board with ("simulated" before a device that
        says it is one: an NI simulated device, or `sfdrig sim-server`)."""
        if self.backend == SIM:
            return "simulated rig (in process)"
        device = f"{'simulated ' if self.simulated else ''}nidaqmx device {self.device}"
        if self.grpc_target:
            return f"{device} via gRPC {self.grpc_target}"
        return f"{device} (local driver)"

    def as_dict(self) -> dict[str, str]:
        """``backend``, ``device``, ``grpc_target`` ("" for none) and ``description``: the
        status's, daemon.json's and the run file's attributes."""
        return {"backend": self.backend, "device": self.device,
                "grpc_target": self.grpc_target or "", "description": self.describe()}

    def lock_name(self) -> str | None:
        """The lock file's name for this board (None: the simulated rig in process needs none)."""
        if self.backend == SIM:
            return None
        if not self.grpc_target:
            key = f"local-{self.device}"
        else:
            host, _, port = self.grpc_target.strip().lower().rpartition(":")
            if host in ("localhost", "127.0.0.1", "[::1]", "::1", ""):
                host = "localhost"
            key = f"grpc-{host}-{port}-{self.device}"
        return "device-" + re.sub(r"[^A-Za-z0-9_.-]", "_", key) + ".lock"


def board_lock(board: Board, directory: Path | None = None) -> InstanceLock | None:
    """The lock of ``board`` (not yet acquired), or None for the simulated rig in process."""
    name = board.lock_name()
    if name is None:
        return None
    return InstanceLock((directory or runtime_dir()) / name, board.describe())
