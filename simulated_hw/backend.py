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

``wiring`` (None: the map the backend is configured with) is the simulated rig's own channel
map: which sensor is on which terminal, with its true gain and gap voltage, and the drives and
lines by terminal, as the sim-server's ``--channels``. The map given to `configure` is then only
what the software believes: a terminal the wiring leaves empty reads the board's noise about
0 V, and a sensor on another terminal than the map says reads there. It rehearses mis-wiring
(`sfdrig commission`); `press_estop` presses the wiring's emergency stop (a map's ``[estop]``
line the wiring leaves open reads low, as a board's pulled-down line does). ``watchdog_s``: a
watchdog timer as a board's (relays off, drives to 0 V and `feed_watchdog` raising -200644 once
not fed for that long, on the backend's clock, cleared by the next run's first write or a relay
switched on); None (default): none, the in-process rig stops with the process that runs it.

``ao_ring_s`` (None: non-regenerating) makes the AO a regenerating ring of that many seconds, as
`NidaqmxBackend` with ``ao_ring_s`` makes the board's: position ``k mod B`` plays at sample ``k``.
Paced, what plays is fixed when the wall clock generates it (a write changes only what has not
been generated yet), so a late writer hears the ring repeat, exactly as on a board; fast, the
generation is the samples read.

The board's parts it shares with the sim-server's `simulated_hw.board.device.SimDevice`: the AO
generation (`board.ao_generation.AoStream`), the watchdog and e-stop (`board.safe_states`), the
wiring's sensors and an unwired terminal's noise (`board.sensor_wiring`).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import numpy as np

from daq.backend import AoCut
from daq.channels import ChannelMap
from daq.errors import (
    CANT_RESET_EXPIRED_WATCHDOG,
    INPUT_BUFFER_OVERWRITTEN,
    OUTPUT_UNDERFLOW,
    READ_TIMEOUT,
    DaqError,
    EmergencyStopError,
    error_for_code,
)
from rig_model import physics
from rig_model.params import RigParams
from rig_model.rig import RigModel
from simulated_hw.board.ao_generation import AoStream
from simulated_hw.board.safe_states import EmergencyStop, SafeStates
from simulated_hw.board.sensor_wiring import floating, sensors_on
from simulated_hw.board.watchdog import Watchdog

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
        wiring: ChannelMap | None = None,
        watchdog_s: float | None = None,
    ) -> None:
        if watchdog_s is not None and not watchdog_s > 0:
            raise ValueError(f"watchdog_s must be positive or None, got {watchdog_s}")
        self.wiring = wiring
        self.watchdog_s = watchdog_s
        # the board's safe states, in the parts the sim-server's board keeps them in: the
        # watchdog expires when next looked at (nothing outlives this process to need a thread)
        self._safe = SafeStates(clock, threading.RLock(), self._expire, live=False)
        self._watchdog = None if watchdog_s is None else Watchdog("sim", watchdog_s)
        if self._watchdog is not None:
            self._safe.add(self._watchdog)
        self._estop = EmergencyStop(wiring.estop if wiring is not None else None)
        self._estop_latched = False  # read_ai raised for this press already
        #: per configured AI row: the rig's row, or None (a terminal the wiring leaves empty)
        self._ai_rows: list[int | None] = []
        #: per rig AO row (the wiring's drives): the configured map's AO row, or None
        self._ao_rows: list[int | None] = []
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
        self._ao = AoStream()  # the generation's samples, as the sim-server's board plays them
        self._running = False
        self._t0 = 0.0
        self._read = 0  # samples handed to the reader
        self._closed = False
        self.cut_stops = cut_stops
        self._ao_stopped = False  # a stopping cut: the drives are at 0 V until the run stops
        # the regenerating ring (ao_ring_s, the stream's loop): the end of the samples written,
        # and what the generation has played already and the rig not yet simulated (the
        # samples from _read on; a stopping cut is the stream's end: 0 V from there on)
        self._written_end = 0
        self._played: list[np.ndarray] = []

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
        self.rig = RigModel(self.params, self._rig_map(channel_map), self.seed)
        if self.wiring is None:  # the map's own button
            self._estop.button = channel_map.estop
        if self._watchdog is not None:
            self._safe.start(self._watchdog)
        self._rest_since = self._clock()
        self._read = 0
        self._new_stream()

    def _rig_map(self, cm: ChannelMap) -> ChannelMap:
        """The map the rig converts with: ``cm`` itself, or the wiring's sensors at the
        terminals ``cm`` reads (with ``cm``'s ranges) and the wiring's drives and lines."""
        wiring = self.wiring
        if wiring is None:
            self._ai_rows = list(range(len(cm.ai)))
            self._ao_rows = list(range(len(cm.ao)))
            return cm
        ai, self._ai_rows = sensors_on(wiring, [(c.physical_channel, c.range_v) for c in cm.ai])
        terminals = [c.physical_channel for c in cm.ao]
        self._ao_rows = [terminals.index(c.physical_channel) if c.physical_channel in terminals
                         else None for c in wiring.ao]
        return ChannelMap(device=cm.device, sample_rate_hz=cm.sample_rate_hz, ai=tuple(ai),
                          ao=wiring.ao, do=wiring.do)

    def _wired(self, ao: np.ndarray) -> np.ndarray:
        """The configured map's AO rows as the rig's drives (a terminal not driven: 0 V)."""
        if self.wiring is None:
            return ao
        out = np.zeros((len(self._ao_rows), ao.shape[1]))
        for i, row in enumerate(self._ao_rows):
            if row is not None:
                out[i] = ao[row]
        return out

    def _as_read(self, rig_out: np.ndarray) -> np.ndarray:
        """The rig's inputs in the configured map's rows; an empty terminal floats at 0 V."""
        if self.wiring is None:
            return rig_out
        spec = self.channel_map.device
        rng = np.random.default_rng(self.seed + 1 + self._read)
        out = np.empty((len(self._ai_rows), rig_out.shape[1]))
        for i, row in enumerate(self._ai_rows):
            out[i] = rig_out[row] if row is not None else floating(spec, rng, rig_out.shape[1])
        return out

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

    def _new_stream(self) -> None:
        """An empty generation: a queue, or (``ao_ring_s``) a ring of 0 V."""
        ring = self.ao_ring_samples if self._map is not None else None
        self._ao = AoStream(None if ring is None else np.zeros((len(self.channel_map.ao), ring)))
        self._written_end, self._played = 0, []

    def _fix_played(self, upto: int) -> None:
        """Generate the ring up to sample ``upto`` now, before a write changes the ring (a
        board has generated them already); past a stopping cut the drives are at 0 V."""
        k = upto - self._ao.generated
        if k > 0:
            block = np.zeros((len(self.channel_map.ao), k))
            self._ao.take_into(block)
            self._played.append(block)

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
        self._played = []
        self._ao.restart()
        self._t0 = self._clock()

    def write_ao(self, block: np.ndarray, at: int | None = None) -> None:
        cm = self.channel_map
        arr = np.asarray(block, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] != len(cm.ao):
            raise ValueError(f"AO block must have shape ({len(cm.ao)}, n), got {arr.shape}")
        if not self._running:  # a run's first write: the operator's decision to drive
            if self.estop_pressed():
                raise EmergencyStopError("the emergency stop is pressed: nothing is driven")
            self._estop_latched = False
            self._clear_watchdog()
        for row, ch in enumerate(cm.ao):
            lo, hi = ch.range_v
            if arr.size and (arr[row].min() < lo or arr[row].max() > hi):
                raise error_for_code(
                    f"{ch.name}: AO sample outside the channel range {ch.range_v} V", -200561
                )
        if self._ao_stopped:
            return  # the generation has stopped: nothing written now plays
        if self._ao.loop is not None:
            self._write_ring(arr, self._written_end if at is None else int(at))
            return
        end = self._read + self._ao.queued
        if at is not None and at != end:
            raise ValueError(f"a non-regenerating AO stream writes at sample {end}, not {at}")
        if self.realtime and self._running and self._generated() > end:
            raise error_for_code("AO generation ran past the samples written", OUTPUT_UNDERFLOW)
        self._ao.queue(arr)

    def _write_ring(self, arr: np.ndarray, at: int) -> None:
        assert self._ao.loop is not None
        n, size = arr.shape[1], self._ao.loop.shape[1]
        if n > size:
            raise ValueError(f"AO write of {n} samples is longer than the {size}-sample ring")
        if at < 0:
            raise ValueError(f"AO write position must be >= 0, got {at}")
        if self._running:  # what the clock has generated already keeps what it played
            self._fix_played(self.ao_generated())
        self._ao.overwrite(arr, at)
        self._written_end = max(self._written_end, at + n)

    def read_ai(self, n: int, timeout_s: float = 10.0) -> np.ndarray:
        rig = self._require_rig()
        if not self._running:
            raise DaqError("read_ai before start()")
        if n <= 0:
            raise ValueError(f"read_ai: n must be positive, got {n}")
        if not self._estop_latched and self.estop_pressed():
            self._estop_latched = True  # once: the reads of the ramp-down go on
            raise EmergencyStopError(f"emergency stop pressed ({self._estop_where()})")
        self._check_watchdog()
        if self.realtime:
            self._wait_for(self._read + n, timeout_s)
        if self._ao.loop is not None:
            ao = self._take_played(n)
        elif not self._ao_stopped and self._ao.queued < n:
            raise error_for_code(
                f"AO buffer ran dry: {self._ao.queued} samples queued, {n} needed",
                OUTPUT_UNDERFLOW,
            )
        else:  # stopped: what is left of the queue, then the drives at 0 V
            ao = np.zeros((len(self.channel_map.ao), n))
            self._ao.take_into(ao)
        w = self._watchdog
        if w is not None and w.expired:  # the board holds the drives at 0 V
            ao = np.zeros_like(ao)
        out = self._as_read(rig.process(self._wired(ao)))
        self._read += n
        if w is not None and not w.expired:
            w.fed_at = self._clock()  # a read feeds the watchdog, as the board backend's
        return out

    def ai_on_host(self) -> int:
        """Never reads ahead: in process a read costs no round trip."""
        return 0

    def set_do(self, name: str, value: bool) -> None:
        relay = self.channel_map.relay(name)  # KeyError names the missing relay
        self._rest()  # the oil up to now followed the relay as it was
        if value:
            self._clear_watchdog()  # switching a relay on: the operator's decision
        elif self._check_watchdog():
            return
        rig = self._require_rig()
        if self.wiring is None:
            rig.set_relay(name, value)
        else:  # the relay on that line, if the wiring has one there
            for d in self.wiring.do:
                if d.physical_channel == relay.physical_channel:
                    rig.set_relay(d.name, value)

    def _rest(self) -> None:
        """Between runs the rig rests in real time: its oil goes on filling or draining. In
        whole seconds (the fraction carries over): a program's own set-up between a relay
        switch and its start (milliseconds) leaves the rig as it was. (The sim-server's board
        instead runs its rig on over the whole gap, `SimDevice.new_rig`: not yet shared.)"""
        rig = self._require_rig()
        if self._rest_since is not None and not self._running:
            whole = math.floor(self._clock() - self._rest_since)
            if whole >= 1:
                rig.rest(whole)
                self._rest_since += whole

    def ao_backlog(self) -> int:
        """Samples written and not yet generated: paced, the wall clock generates them
        (regenerating: negative once the generation has passed the last sample written)."""
        if self._ao.loop is not None:
            return self._written_end - self.ao_generated()
        if self.realtime and self._running:
            return self._read + self._ao.queued - self._generated()
        return self._ao.queued

    def cut_ao(self) -> AoCut:
        """Drop the AO queued beyond the generation (see the module doc)."""
        if self._ao.loop is not None:
            return self._cut_ring()
        keep = self._ao.queued
        if self._running and not self._ao_stopped:
            keep = 0
            if self.realtime:
                margin = 0 if self.cut_stops else int(CUT_MARGIN_S * self.sample_rate_hz)
                keep = min(max(self._generated() + margin - self._read, 0), self._ao.queued)
            self._ao.keep_queued(keep)
            self._ao_stopped = self.cut_stops
        return AoCut(self._read + keep, not self._ao_stopped)

    def _cut_ring(self) -> AoCut:
        if not self._running or self._ao_stopped:
            at = self._ao.end if self._ao.end is not None else self._written_end
            return AoCut(at, not self._ao_stopped)
        margin = 0 if self.cut_stops or not self.realtime else \
            int(CUT_MARGIN_S * self.sample_rate_hz)
        at = self.ao_generated() + margin
        self._fix_played(at)
        if self.cut_stops:
            self._ao.end = at
            self._ao_stopped = True
        return AoCut(at, not self._ao_stopped)

    def feed_watchdog(self) -> None:
        """Reset the watchdog timer (``watchdog_s``; no-op without one); raises
        `daq.errors.DaqWatchdogExpiredError` (-200644) once it has expired."""
        if self._watchdog is None:
            return
        if self._check_watchdog():
            raise error_for_code(
                f"the watchdog timer expired (not reset for {self._watchdog.timeout_s:g} s): "
                "relays off, drives at 0 V", CANT_RESET_EXPIRED_WATCHDOG)
        self._safe.feed(self._watchdog, "watchdog")

    def _check_watchdog(self) -> bool:
        """Expire the watchdog if it has not been fed for ``watchdog_s``. Whether it has
        expired."""
        if self._watchdog is None:
            return False
        self._safe.check()
        return self._watchdog.expired

    def _expire(self, w: Watchdog) -> None:
        """The relays off and the drives at 0 V from then on, as a board does on its own."""
        self._safe.hold(w)
        if self.rig is not None:
            for d in self.rig.channel_map.do:
                self.rig.set_relay(d.name, False)

    def _clear_watchdog(self) -> None:
        if self._watchdog is not None:
            self._check_watchdog()
            self._safe.clear_expiration(self._watchdog)

    @property
    def watchdog_expired(self) -> bool:
        """Whether the watchdog has expired (what the board's own state says)."""
        return self._check_watchdog()

    def press_estop(self, pressed: bool) -> None:
        """A hand on the wiring's emergency-stop button (simulation only)."""
        self._estop.press(pressed)

    def estop_pressed(self) -> bool:
        """Whether the map's emergency-stop line reads pressed: the wiring's button (the map's
        own without a wiring) sets its level; a line the wiring leaves open reads low."""
        cm = self._map
        if cm is None or cm.estop is None:
            return False
        return self._estop.level_on(cm.estop.physical_channel) == cm.estop.pressed_level

    def _estop_where(self) -> str:
        estop = self.channel_map.estop
        return f"input {estop.name} on {estop.physical_channel}" if estop else "none"

    def stop(self) -> None:
        """Stop both tasks: what was written and not generated is dropped (a board's buffer
        is), and the next run primes the AO again and counts from sample 0."""
        self._running = False
        self._ao_stopped = False
        self._new_stream()
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
