"""A bare pyzmq DEALER on the daemon's command socket (not `control.wire.client`): what any program
on
the network can send, frame by frame, with a hard deadline on every reply (a hung daemon or a lost
request: 30 s by default, not a speed figure; how fast the replies come is
`benchmarks/bench_command_replies.py`'s)."""

from __future__ import annotations

import json
import time
from typing import Any

import zmq

#: the default deadline of a reply [s]: the daemon hung, not slow (see the benchmark)
DEADLINE_S = 30.0


class RawDealer:
    def __init__(self, endpoint: str) -> None:
        self._ctx = zmq.Context()
        self.sock = self._ctx.socket(zmq.DEALER)
        self.sock.linger = 0
        self.sock.connect(endpoint)

    def ask(self, frames: list[bytes],
            timeout_s: float = DEADLINE_S) -> tuple[dict[str, Any], float]:
        """Send ``frames`` as they are; (the parsed reply, seconds it took). Fails the test when
        no reply comes within ``timeout_s``."""
        t0 = time.monotonic()
        self.sock.send_multipart(frames)
        if not self.sock.poll(int(timeout_s * 1000)):
            raise AssertionError(f"no reply within {timeout_s:g} s to {frames[:3]!r:.300}")
        parts = self.sock.recv_multipart()
        elapsed = time.monotonic() - t0
        return json.loads(parts[-1]), elapsed

    def request(self, message: bytes | str, timeout_s: float = DEADLINE_S) -> dict[str, Any]:
        """One request frame after the empty delimiter, as in the issue: ``[b"", message]``."""
        raw = message.encode() if isinstance(message, str) else message
        return self.ask([b"", raw], timeout_s)[0]

    def close(self) -> None:
        self.sock.close(0)
        self._ctx.term()

    def __enter__(self) -> RawDealer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
