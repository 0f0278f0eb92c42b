"""Client library of the sfdrig daemon: `CommandClient` (commands), `Subscriber` (live data).

Example::

    from control.wire.client import CommandClient, Subscriber

    with Subscriber("tcp://127.0.0.1:5556", topics=["block", "step"]) as sub, \\
            CommandClient("tcp://127.0.0.1:5555") as cmd:
        sub.wait_connected(timeout_s=5)          # the first heartbeat proves the subscription
        cmd.start_sweep(spec_dict)
        while (msg := sub.recv(timeout_s=5)) is not None:
            if msg.topic == "block":
                print(msg.header["first_sample"], msg.array.shape)

With CURVE keys (``sfdrig keys``), pass ``keys=load_client_keys(DIR, NAME)`` to either class.
"""

from __future__ import annotations

import json
import os
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, NoReturn

import numpy as np
import zmq
from pydantic import TypeAdapter, ValidationError
from zmq.utils.monitor import recv_monitor_message

from control.wire.heartbeat import Heartbeat, heartbeat_from_wire
from control.wire.protocol import TOPICS, Reply, RunListing, decode_block
from control.wire.security import ClientKeys, secure_client_socket

_RUN_LISTINGS: TypeAdapter[list[RunListing]] = TypeAdapter(list[RunListing])


def process_gone(pid: object) -> bool:
    """Whether ``pid`` names no process on this computer (a killed daemon's state file); a
    value that is not a pid is not known to be gone."""
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # another user's process: alive
        return False
    return False


class DaemonUnavailable(TimeoutError):
    """No reply from the daemon in time (not running, wrong endpoint, or keys refused)."""


class CommandRefused(RuntimeError):
    """The daemon answered ``ok: false``; ``reply`` holds the error kind and message."""

    def __init__(self, reply: Reply) -> None:
        super().__init__(f"{reply.cmd or 'request'} refused ({reply.error_kind}): {reply.error}")
        self.reply = reply


class CommandClient:
    """Send commands to the daemon's ROUTER socket and wait for each reply.

    Parameters
    ----------
    endpoint : str
        The daemon's command endpoint, e.g. ``tcp://127.0.0.1:5555``.
    timeout_s : float
        How long to wait for a reply [s].
    keys : ClientKeys, optional
        CURVE keys when the daemon requires them.
    context : zmq.Context, optional
        Defaults to the process's shared context.
    """

    def __init__(self, endpoint: str, timeout_s: float = 5.0, keys: ClientKeys | None = None,
                 context: zmq.Context | None = None) -> None:
        self.endpoint = endpoint
        self.timeout_s = timeout_s
        self._ctx = context or zmq.Context.instance()
        self._keys = keys
        self._sock = self._connect()
        try:
            self._monitor: zmq.Socket | None = self._watch(self._sock) \
                if keys is not None else None
        except zmq.ZMQError:
            self._sock.close(0)
            raise

    @staticmethod
    def _watch(sock: zmq.Socket) -> zmq.Socket:
        """A monitor of ``sock``'s refused handshakes, on an inproc address of its own:
        pyzmq's default names it after the socket's file descriptor, which a new socket may
        reuse while the old monitor is still being torn down ('Address already in use')."""
        return sock.get_monitor_socket(
            zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL,
            addr=f"inproc://sfdrig-client-monitor-{uuid.uuid4().hex}")

    def _connect(self) -> zmq.Socket:
        sock = self._ctx.socket(zmq.DEALER)
        sock.linger = 0
        if self._keys is not None:
            secure_client_socket(sock, self._keys)
        sock.connect(self.endpoint)
        return sock

    # --- the generic call ---------------------------------------------------------------------
    def request(self, cmd: str, check: bool = True, **fields: Any) -> Reply:
        """Send ``{"cmd": cmd, **fields}``; return the reply.

        Raises
        ------
        CommandRefused
            when ``check`` and the reply is not ok.
        DaemonUnavailable
            when no reply comes within ``timeout_s`` (or the daemon refused this client's key).
        """
        rid = uuid.uuid4().hex[:12]
        frame = json.dumps({"cmd": cmd, "request_id": rid, **fields}).encode()
        reply = Reply.from_frame(self.send_raw([b"", frame], rid))
        if check and not reply.ok:
            raise CommandRefused(reply)
        return reply

    def send_raw(self, frames: list[bytes], request_id: str | None = None) -> bytes:
        """Send raw frames (the caller builds the envelope); return the reply's JSON frame.

        Replies to earlier requests that timed out are skipped when ``request_id`` is given.
        """
        self._sock.send_multipart(frames)
        deadline = time.monotonic() + self.timeout_s
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        if self._monitor is not None:  # a refused CURVE handshake ends the wait at once
            poller.register(self._monitor, zmq.POLLIN)
        while True:
            left = deadline - time.monotonic()
            ready = dict(poller.poll(int(left * 1000))) if left > 0 else {}
            if not ready:
                self._timed_out()
            if self._sock not in ready:
                if self._auth_refused():
                    self._timed_out(refused=True)
                continue
            parts = self._sock.recv_multipart()
            body = parts[-1]
            if request_id is None:
                return body
            try:
                if json.loads(body).get("request_id") in (request_id, ""):
                    return body
            except (ValueError, AttributeError):
                return body

    def _auth_refused(self) -> bool:
        """Drain the monitor; True if the server refused this client's key."""
        refused = False
        while self._monitor is not None and self._monitor.poll(0):
            event = recv_monitor_message(self._monitor)
            refused |= event["event"] == zmq.EVENT_HANDSHAKE_FAILED_AUTH
        return refused

    def _timed_out(self, refused: bool = False) -> NoReturn:
        refused = refused or self._auth_refused()
        # A DEALER would deliver the stale request later: start afresh.
        if self._monitor is not None:
            self._sock.disable_monitor()
            self._monitor.close(0)
        self._sock.close(0)
        self._sock = self._connect()
        if self._monitor is not None:
            self._monitor = self._watch(self._sock)
        if refused:
            raise DaemonUnavailable(
                f"{self.endpoint}: the daemon refused this client's CURVE key (not authorised)"
            )
        raise DaemonUnavailable(f"no reply from {self.endpoint} within {self.timeout_s:g} s")

    # --- commands -------------------------------------------------------------------------
    def start_sweep(self, spec: dict[str, Any], operator: str = "", notes: str = "") -> Reply:
        """Start a sweep from a sweep spec dict; ``reply.data["run_id"]`` names the run."""
        return self.request("start", spec=spec, operator=operator, notes=notes)

    def pause(self) -> Reply:
        return self.request("pause")

    def resume(self) -> Reply:
        return self.request("resume")

    def abort(self, reason: str = "operator abort") -> Reply:
        return self.request("abort", reason=reason)

    def pump(self, on: bool) -> Reply:
        return self.request("pump", on=on)

    def status(self) -> Heartbeat:
        """The daemon's status: state, run id, progress, sequence numbers, endpoints.

        Raises DaemonUnavailable when the answer is no daemon's status (a field missing or
        of the wrong type: another program, or a daemon of another version)."""
        reply = self.request("status")
        try:
            return heartbeat_from_wire({"state": reply.state.value, **reply.data},
                                       self.endpoint)
        except ValueError as err:
            raise DaemonUnavailable(f"not a daemon's status: {err}") from None

    def list_runs(self) -> list[RunListing]:
        """The daemon's run files, newest first (DaemonUnavailable: an answer that is none)."""
        try:
            return _RUN_LISTINGS.validate_python(self.request("list_runs").data.get("runs"))
        except ValidationError as err:
            raise DaemonUnavailable(f"not a daemon's list of runs: {err.errors()[0]}") from None

    def reset(self) -> Reply:
        return self.request("reset")

    def close(self) -> None:
        if self._monitor is not None:
            self._sock.disable_monitor()
            self._monitor.close(0)
        self._sock.close(0)

    def __enter__(self) -> CommandClient:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@dataclass
class Message:
    """One live-data message. ``array`` is the block (rows = ``header["channels"]``) or None;
    a ``status`` message's heartbeat is `heartbeat`."""

    topic: str
    header: dict[str, Any]
    array: np.ndarray | None
    received_at: float  # wall-clock time.time() at receipt [s]

    def row(self, name: str) -> np.ndarray:
        """One channel's samples of a block message."""
        if self.array is None:
            raise ValueError(f"{self.topic} message carries no samples")
        return self.array[self.header["channels"].index(name)]

    def heartbeat(self) -> Heartbeat:
        """A ``status`` message's heartbeat, every field checked (ValueError names the one
        that is wrong)."""
        if self.topic != "status":
            raise ValueError(f"a {self.topic} message carries no heartbeat")
        return heartbeat_from_wire(self.header.get("status"), "the status topic")


@dataclass
class GapCounter:
    """Per-topic sequence tracking: lost messages show as jumps in ``seq``."""

    next_seq: dict[str, int] = field(default_factory=dict)
    lost: dict[str, int] = field(default_factory=dict)

    def see(self, topic: str, seq: int) -> int:
        """Record ``seq``; return how many messages of ``topic`` were lost just before it."""
        expected = self.next_seq.get(topic)
        gap = 0 if expected is None else max(0, seq - expected)
        if gap:
            self.lost[topic] = self.lost.get(topic, 0) + gap
        self.next_seq[topic] = seq + 1
        return gap


class Subscriber:
    """Subscribe to the daemon's (or a proxy's) live data.

    Parameters
    ----------
    endpoint : str
        The data endpoint (the daemon's PUB or a proxy's XPUB).
    topics : list of str, optional
        Any of "block", "step", "status", "event"; default all. "status" is always added, since
        heartbeats prove the subscription is live (`wait_connected`).
    rcvhwm : int
        Receive high-water mark [messages]; 0 means no limit.
    rcvbuf : int
        Kernel receive buffer [bytes]; 0 (default) leaves it to the OS, which on Linux may grow
        it to tens of MB (``net.ipv4.tcp_rmem``): a client that stops reading is only seen to
        lose messages once that is full.
    keys : ClientKeys, optional
        CURVE keys when the daemon requires them.
    """

    def __init__(self, endpoint: str, topics: list[str] | None = None, rcvhwm: int = 1000,
                 keys: ClientKeys | None = None, context: zmq.Context | None = None,
                 rcvbuf: int = 0) -> None:
        self.endpoint = endpoint
        self._ctx = context or zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.SUB)
        self._sock.linger = 0
        self._sock.rcvhwm = rcvhwm
        if rcvbuf > 0:
            self._sock.rcvbuf = rcvbuf
        if keys is not None:
            secure_client_socket(self._sock, keys)
        wanted = [t.encode() for t in (topics or [t.decode() for t in TOPICS])]
        unknown = [t for t in wanted if t not in TOPICS]
        if unknown:
            raise ValueError(f"unknown topics {unknown}; topics are {[t.decode() for t in TOPICS]}")
        self._status_only_for_sync = b"status" not in wanted
        for t in set(wanted) | {b"status"}:
            self._sock.subscribe(t)
        self._sock.connect(endpoint)
        self.gaps = GapCounter()
        self.received = 0

    def wait_connected(self, timeout_s: float = 10.0) -> Heartbeat:
        """Wait for the first status heartbeat (the subscription is then live); return it.
        Messages that cannot be decoded, and statuses that are no heartbeat, are passed over
        on the way.

        Raises
        ------
        DaemonUnavailable
            if no heartbeat arrives within ``timeout_s`` (naming the last status passed over).
        """
        deadline = time.monotonic() + timeout_s
        passed_over = ""
        while True:
            left = deadline - time.monotonic()
            try:
                msg = self._recv_any(max(left, 0.0)) if left > 0 else None
                if msg is not None and msg.topic == "status":
                    return msg.heartbeat()
            except (ValueError, KeyError, TypeError) as err:
                passed_over = f" ({err})"  # not a message of ours: waited past
                continue
            if msg is None:
                raise DaemonUnavailable(
                    f"no status heartbeat from {self.endpoint} within {timeout_s:g} s"
                    + passed_over)

    def recv(self, timeout_s: float | None = None) -> Message | None:
        """The next message of the subscribed topics, or None after ``timeout_s`` (None: wait)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            msg = self._recv_any(left)
            if msg is None:
                return None
            if msg.topic == "status" and self._status_only_for_sync:
                continue
            return msg

    def _recv_any(self, timeout_s: float | None) -> Message | None:
        if timeout_s is not None and not self._sock.poll(int(timeout_s * 1000)):
            return None
        frames = self._sock.recv_multipart(copy=False)
        now = time.time()
        if len(frames) != 3:
            raise ValueError(f"expected 3 frames [topic, header, payload], got {len(frames)}")
        topic = bytes(frames[0].buffer).decode()
        header = json.loads(frames[1].bytes)
        self.gaps.see(topic, int(header["seq"]))
        self.received += 1
        array = decode_block(header, frames[2].buffer) if topic == "block" else None
        return Message(topic, header, array, now)

    @property
    def lost(self) -> dict[str, int]:
        """Messages lost per topic so far (from gaps in ``seq``)."""
        return dict(self.gaps.lost)

    def close(self) -> None:
        self._sock.close(0)

    def __enter__(self) -> Subscriber:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
