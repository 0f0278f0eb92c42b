"""`SimulatedBackend`: the `DaqBackend` protocol in process, on the simulated rig.

Fast mode (``realtime=False``) simulates a block the moment it is read: a 40 s sweep takes well
under a second. Paced mode (``realtime=True``) behaves as hardware does: samples become available
as the wall clock advances, a read waits for them (timeout -> DAQmx -200284), a reader that falls
more than the buffer behind loses data (-200279), and an AO writer that falls behind the
generation underflows (-200290). The clock and the sleep are injectable for tests.

A trip's `cut_ao` drops the AO queued beyond the generation (fast mode: beyond the samples read;
the rig has not simulated them yet). ``cut_stops=True`` (default): the generation stops there
with the drives at 0 V, as a board's AO task stopped with idle output 0 V does;
``cut_stops=False``: the stream goes on with the next write (the caller's fade) from the first
sample dropped, which a board cannot do (`benchmarks/bench_trip.py` compares the two).

``ao_ring_s`` (None: non-regenerating) makes the AO a regenerating ring of that many seconds, as
`NidaqmxBackend` with ``ao_ring_s`` makes the board's: position ``k mod B`` plays at sample ``k``.
Paced, what plays is fixed when the wall clock generates it (a write changes only what has not
been generated yet), so a late writer hears the ring repeat, exactly as on a board; fast, the
generation is the samples read.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from daq.backend import AoCut
from daq.channels import ChannelMap
from daq.errors import (
    INPUT_BUFFER_OVERWRITTEN,
    OUTPUT_UNDERFLOW,
    READ_TIMEOUT,
    DaqError,
    error_for_code,
)
from simulated_hw import physics
from simulated_hw.params import RigParams
from simulated_hw.rig import RigModel

#: Paced: what a resuming cut leaves queued past the generation, so that the fade written next
#: arrives before the generation does [s].
CUT_MARGIN_S = 0.002


class SimulatedBackend:
    """The simulated rig behind the `daq.DaqBackend` protocol."""

    def __init__(
        self,
        params: RigParams | None = None,
        seed: int = 0,
        realtime: bool = False,
        buffer_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        cut_stops: bool = True,
        ao_ring_s: float | None = None,
    ) -> None:
        if ao_ring_s is not None and not ao_ring_s > 0:
            raise ValueError(f"ao_ring_s must be positive or None, got {ao_ring_s}")
        self.ao_ring_s = ao_ring_s
        self.params = params if params is not None else RigParams()
        self.seed = seed
        self.realtime = realtime
        self.buffer_s = buffer_s
        self._clock = clock
        self._rest_since: float | None = None  # when the last run stopped (the rig rests)
        self._sleep = sleep
        self._map: ChannelMap | None = None
        self.rig: RigModel | None = None
        self._ao_chunks: list[np.ndarray] = []
        self._ao_queued = 0
        self._running = False
        self._t0 = 0.0
        self._read = 0  # samples handed to the reader
        self._closed = False
        self.cut_stops = cut_stops
        self._ao_stopped = False  # a stopping cut: the drives are at 0 V until the run stops
        # the regenerating ring (ao_ring_s): its content, the end of the samples written, and
        # what the generation has fixed already (samples _played_from.. not yet read)
        self._ring: np.ndarray | None = None
        self._written_end = 0
        self._played: list[np.ndarray] = []
        self._played_to = 0  # AO fixed for every sample before this (from the ring)
        self._stopped_at: int | None = None  # a stopping cut: 0 V from this sample on

    # --- protocol -------------------------------------------------------------------------
    @property
    def channel_map(self) -> ChannelMap:
        if self._map is None:
            raise DaqError("backend not configured: call configure(channel_map) first")
        return self._map

    @property
    def sample_rate_hz(self) -> float:
        return self.channel_map.sample_rate_hz

    def configure(self, channel_map: ChannelMap) -> None:
        if self._running:
            raise DaqError("cannot reconfigure while running; stop first")
        self._map = channel_map
        physics.warm_up()  # before start: a paced first read must not wait for the compiler
        self.rig = RigModel(self.params, channel_map, self.seed)
        self._rest_since = self._clock()
        self._ao_chunks, self._ao_queued, self._read = [], 0, 0
        self._reset_ring()

    @property
    def ao_ring_samples(self) -> int | None:
        if self.ao_ring_s is None:
            return None
        return max(int(round(self.ao_ring_s * self.sample_rate_hz)), 1)

    @property
    def ao_min_lead(self) -> int:
        """Paced: a write lands at once, nothing between it and the generation."""
        return 0

    def ao_generated(self) -> int:
        if not self._running:
            return 0
        return self._generated() if self.realtime else self._read

    def _reset_ring(self) -> None:
        ring = self.ao_ring_samples if self._map is not None else None
        self._ring = None if ring is None else np.zeros((len(self.channel_map.ao), ring))
        self._written_end, self._played, self._played_to = 0, [], 0
        self._stopped_at = None

    def _fix_played(self, upto: int) -> None:
        """The ring's content for samples ``_played_to..upto`` is what plays there: fix it now,
        before a write changes the ring (a board has generated them already)."""
        ring = self._ring
        assert ring is not None
        if upto <= self._played_to:
            return
        k = np.arange(self._played_to, upto)
        block = ring[:, k % ring.shape[1]]
        if self._stopped_at is not None:
            block[:, k >= self._stopped_at] = 0.0
        self._played.append(block)
        self._played_to = upto

    def _take_played(self, n: int) -> np.ndarray:
        self._fix_played(self._read + n)
        parts, got = [], 0
        while got < n:
            chunk = self._played[0]
            take = min(n - got, chunk.shape[1])
            parts.append(chunk[:, :take])
            if take == chunk.shape[1]:
                self._played.pop(0)
            else:
                self._played[0] = chunk[:, take:]
            got += take
        return np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]

    def start(self) -> None:
        """Start the generation and the acquisition: a new run counts its samples from 0, as a
        board's tasks do (the rig itself keeps moving from where the last run left it)."""
        self._rest()
        self._rest_since = None
        self._running = True
        self._read = 0
        self._played, self._played_to, self._stopped_at = [], 0, None
        self._t0 = self._clock()

    def write_ao(self, block: np.ndarray, at: int | None = None) -> None:
        cm = self.channel_map
        arr = np.asarray(block, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] != len(cm.ao):
            raise ValueError(f"AO block must have shape ({len(cm.ao)}, n), got {arr.shape}")
        for row, ch in enumerate(cm.ao):
            lo, hi = ch.range_v
            if arr.size and (arr[row].min() < lo or arr[row].max() > hi):
                raise error_for_code(
                    f"{ch.name}: AO sample outside the channel range {ch.range_v} V", -200561
                )
        if self._ao_stopped:
            return  # the generation has stopped: nothing written now plays
        if self._ring is not None:
            self._write_ring(arr, self._written_end if at is None else int(at))
            return
        if at is not None and at != self._read + self._ao_queued:
            raise ValueError(f"a non-regenerating AO stream writes at sample "
                             f"{self._read + self._ao_queued}, not {at}")
        if self.realtime and self._running:
            generated = self._generated()
            if generated > self._read + self._ao_queued:
                raise error_for_code("AO generation ran past the samples written", OUTPUT_UNDERFLOW)
        self._ao_chunks.append(arr.copy())
        self._ao_queued += arr.shape[1]

    def _write_ring(self, arr: np.ndarray, at: int) -> None:
        ring = self._ring
        assert ring is not None
        n, size = arr.shape[1], ring.shape[1]
        if n > size:
            raise ValueError(f"AO write of {n} samples is longer than the {size}-sample ring")
        if at < 0:
            raise ValueError(f"AO write position must be >= 0, got {at}")
        if self._running:  # what the clock has generated already keeps what it played
            self._fix_played(self.ao_generated())
        ring[:, (at + np.arange(n)) % size] = arr
        self._written_end = max(self._written_end, at + n)

    def read_ai(self, n: int, timeout_s: float = 10.0) -> np.ndarray:
        rig = self._require_rig()
        if not self._running:
            raise DaqError("read_ai before start()")
        if n <= 0:
            raise ValueError(f"read_ai: n must be positive, got {n}")
        if self.realtime:
            self._wait_for(self._read + n, timeout_s)
        if self._ring is not None:
            ao = self._take_played(n)
        elif self._ao_stopped:  # what is left of the queue, then the drives at 0 V
            take = min(n, self._ao_queued)
            ao = np.zeros((len(self.channel_map.ao), n))
            if take:
                ao[:, :take] = self._take_ao(take)
        elif self._ao_queued < n:
            raise error_for_code(
                f"AO buffer ran dry: {self._ao_queued} samples queued, {n} needed",
                OUTPUT_UNDERFLOW,
            )
        else:
            ao = self._take_ao(n)
        self._read += n
        return rig.process(ao)

    def ai_on_host(self) -> int:
        """Never reads ahead: in process a read costs no round trip."""
        return 0

    def set_do(self, name: str, value: bool) -> None:
        self.channel_map.relay(name)  # KeyError names the missing relay
        self._rest()  # the oil up to now followed the relay as it was
        self._require_rig().set_relay(name, value)

    def _rest(self) -> None:
        """Between runs the rig rests in real time: its oil goes on filling or draining. In
        whole seconds (the fraction carries over): a program's own set-up between a relay
        switch and its start (milliseconds) leaves the rig as the sim-server's board, which
        starts every acquisition from rest (issue 22), has it, so both give the same samples."""
        rig = self._require_rig()
        if self._rest_since is not None and not self._running:
            whole = math.floor(self._clock() - self._rest_since)
            if whole >= 1:
                rig.rest(whole)
                self._rest_since += whole

    def ao_backlog(self) -> int:
        """Samples written and not yet generated: paced, the wall clock generates them
        (regenerating: negative once the generation has passed the last sample written)."""
        if self._ring is not None:
            return self._written_end - self.ao_generated()
        if self.realtime and self._running:
            return self._read + self._ao_queued - self._generated()
        return self._ao_queued

    def cut_ao(self) -> AoCut:
        """Drop the AO queued beyond the generation (see the module doc)."""
        if self._ring is not None:
            return self._cut_ring()
        keep = self._ao_queued
        if self._running and not self._ao_stopped:
            keep = 0
            if self.realtime:
                margin = 0 if self.cut_stops else int(CUT_MARGIN_S * self.sample_rate_hz)
                keep = min(max(self._generated() + margin - self._read, 0), self._ao_queued)
            dropped = self._ao_queued - keep
            while dropped:
                last = self._ao_chunks[-1]
                if last.shape[1] <= dropped:
                    self._ao_chunks.pop()
                    dropped -= last.shape[1]
                    self._ao_queued -= last.shape[1]
                else:
                    self._ao_chunks[-1] = last[:, :last.shape[1] - dropped]
                    self._ao_queued -= dropped
                    dropped = 0
            self._ao_stopped = self.cut_stops
        return AoCut(self._read + keep, not self._ao_stopped)

    def _cut_ring(self) -> AoCut:
        if not self._running or self._ao_stopped:
            at = self._stopped_at if self._stopped_at is not None else self._written_end
            return AoCut(at, not self._ao_stopped)
        margin = 0 if self.cut_stops or not self.realtime else \
            int(CUT_MARGIN_S * self.sample_rate_hz)
        at = self.ao_generated() + margin
        self._fix_played(at)
        if self.cut_stops:
            self._stopped_at = at
            self._ao_stopped = True
        return AoCut(at, not self._ao_stopped)

    def feed_watchdog(self) -> None:
        """No watchdog: the in-process rig stops with the process that runs it."""

    def estop_pressed(self) -> bool:
        """No emergency-stop input on the in-process rig (the sim-server has one)."""
        return False

    def stop(self) -> None:
        """Stop both tasks: what was written and not generated is dropped (a board's buffer
        is), and the next run primes the AO again and counts from sample 0."""
        self._running = False
        self._ao_stopped = False
        self._ao_chunks, self._ao_queued = [], 0
        self._reset_ring()
        self._rest_since = self._clock()

    def close(self) -> None:
        self._running = False
        self._closed = True

    # --- simulation-only helpers ----------------------------------------------------------
    @property
    def samples_read(self) -> int:
        return self._read

    def _require_rig(self) -> RigModel:
        if self.rig is None:
            raise DaqError("backend not configured: call configure(channel_map) first")
        if self._closed:
            raise DaqError("backend is closed")
        return self.rig

    def _generated(self) -> int:
        # a hair over the float product: 0.01 s at 10 kS/s is 100 samples, not 99.99999
        return int((self._clock() - self._t0) * self.sample_rate_hz + 1e-6)

    def _wait_for(self, needed: int, timeout_s: float) -> None:
        fs = self.sample_rate_hz
        behind = self._generated() - self._read
        if behind > self.buffer_s * fs:
            raise error_for_code(
                f"input buffer overwritten: reader {behind / fs:.2f} s behind, buffer "
                f"{self.buffer_s:g} s",
                INPUT_BUFFER_OVERWRITTEN,
            )
        deadline = self._clock() + timeout_s
        while True:
            now = self._clock()
            ready_at = self._t0 + needed / fs
            if now >= ready_at:
                return
            if ready_at > deadline:
                wait = deadline - now
                if wait > 0:
                    self._sleep(wait)
                raise error_for_code(
                    f"read of {needed - self._read} samples timed out after {timeout_s:g} s",
                    READ_TIMEOUT,
                )
            self._sleep(ready_at - now)

    def _take_ao(self, n: int) -> np.ndarray:
        parts, got = [], 0
        while got < n:
            chunk = self._ao_chunks[0]
            take = min(n - got, chunk.shape[1])
            parts.append(chunk[:, :take])
            if take == chunk.shape[1]:
                self._ao_chunks.pop(0)
            else:
                self._ao_chunks[0] = chunk[:, take:]
            got += take
        self._ao_queued -= n
        return np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
