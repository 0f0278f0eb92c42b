"""The live-data publisher: one consumer of the sweep stream (contract A), sending over ZeroMQ PUB.

The acquisition thread calls `Publisher.on_block` and friends; those only stamp the message
(sequence number, acquisition time), copy the block into one contiguous array and put it on a
bounded queue: cheap and never blocking on the network. A publisher thread owns the PUB socket
(ZeroMQ sockets are not thread-safe), encodes the JSON headers and sends with zero copy. The PUB
socket's send high-water mark drops messages for a subscriber that does not keep up, so a slow
subscriber never stalls acquisition; the drop shows as a gap in that subscriber's ``seq``.

If the queue itself is full (the publisher thread starved of CPU), the message is dropped and
counted (`Publisher.dropped`), unless ``block_when_full`` is set: then the caller waits, which is
right only for a simulated rig running faster than real time, where waiting loses nothing.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import zmq

from control.wire.heartbeat import Heartbeat
from control.wire.protocol import (
    PAYLOAD_DTYPE,
    TOPIC_BLOCK,
    TOPIC_EVENT,
    TOPIC_STATUS,
    TOPIC_STEP,
    encode_header,
)
from storage.records import BlockHeader, EventRecord, StepRecord

_STOP = object()


class Publisher:
    """Publish sweep blocks, steps, events and status heartbeats on a bound PUB socket.

    Parameters
    ----------
    socket : zmq.Socket
        A bound PUB socket; the publisher thread becomes its only user.
    channels : sequence of str
        Row names of block payloads: the AI channels then the AO channels.
    n_ai : int
        How many of ``channels`` are AI rows.
    sample_rate_hz : float
        The sample clock [S/s], copied into block headers.
    queue_size : int
        Messages that may wait for the publisher thread.
    block_when_full : bool
        Wait for room instead of dropping when the queue is full (simulated fast mode only).
    """

    def __init__(
        self,
        socket: zmq.Socket,
        channels: Sequence[str],
        n_ai: int,
        sample_rate_hz: float,
        queue_size: int = 256,
        block_when_full: bool = False,
    ) -> None:
        self._socket = socket
        self.channels = tuple(channels)
        self.n_ai = n_ai
        self.sample_rate_hz = float(sample_rate_hz)
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        self._block_when_full = block_when_full
        self._lock = threading.Lock()
        self._seq = {TOPIC_BLOCK: 0, TOPIC_STEP: 0, TOPIC_STATUS: 0, TOPIC_EVENT: 0}
        self.run_id = ""
        self.dropped = 0  # messages dropped because the queue was full
        self.sent = 0
        self.send_errors = 0
        self._thread = threading.Thread(target=self._loop, name="sfdrig-publisher", daemon=True)
        self._thread.start()

    # --- Listener (contract A), called from the acquisition thread --------------------
    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        """Queue one block: ``ai`` (n_ai, n) engineering units, ``ao`` (n_ao, n) volts."""
        t_acquired = time.time()
        n = ai.shape[1]
        payload = np.empty((ai.shape[0] + ao.shape[0], n), dtype=PAYLOAD_DTYPE)
        payload[: ai.shape[0]] = ai
        payload[ai.shape[0]:] = ao
        header = BlockHeader(int(first_sample), int(n), self.n_ai, self.channels,
                             self.sample_rate_hz, t_acquired).to_wire()
        self._put(TOPIC_BLOCK, header, payload)

    def on_step(self, step: StepRecord) -> None:
        """Queue one step (its JSON dict under ``step``)."""
        self._put(TOPIC_STEP, {"step": step.to_wire()}, None)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        """Queue one log event."""
        self._put(TOPIC_EVENT, EventRecord(kind, message, sample).to_wire(time.time()), None)

    # --- from the command thread --------------------------------------------------------------
    def publish_status(self, status: Heartbeat) -> None:
        """Queue a status heartbeat (never waits: a heartbeat is worth dropping)."""
        self._put(TOPIC_STATUS, {"status": status}, None, wait=False)

    def set_run(self, run_id: str) -> None:
        """The run id stamped on the following messages ("" between runs)."""
        with self._lock:
            self.run_id = run_id

    def sequence_numbers(self) -> dict[str, int]:
        """The next ``seq`` of every topic (for status replies to late joiners)."""
        with self._lock:
            return {t.decode(): s for t, s in self._seq.items()}

    def close(self, timeout_s: float = 5.0) -> None:
        """Send what is queued, then stop the publisher thread (the socket stays open)."""
        if self._thread.is_alive():
            self._queue.put(_STOP)
            self._thread.join(timeout_s)

    # --- internals -------------------------------------------------------------------------
    def _put(self, topic: bytes, header: dict[str, Any], payload: np.ndarray | None,
             wait: bool | None = None) -> None:
        with self._lock:
            header["topic"] = topic.decode()
            header["run_id"] = self.run_id
            header["seq"] = self._seq[topic]
            self._seq[topic] += 1
        wait = self._block_when_full if wait is None else wait
        try:
            if wait:
                self._queue.put((topic, header, payload))
            else:
                self._queue.put_nowait((topic, header, payload))
        except queue.Full:
            self.dropped += 1

    def _loop(self) -> None:
        sock = self._socket
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            topic, header, payload = item
            frames: list[Any] = [topic, encode_header(header)]
            frames.append(memoryview(payload).cast("B") if payload is not None else b"")
            try:
                # PUB never blocks: at the high-water mark it drops for that subscriber.
                sock.send_multipart(frames, copy=payload is None, flags=zmq.NOBLOCK)
                self.sent += 1
            except zmq.Again:
                self.send_errors += 1
            except zmq.ZMQError:
                self.send_errors += 1
                if sock.closed:
                    return
