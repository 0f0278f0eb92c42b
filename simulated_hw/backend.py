"""`SimulatedBackend`: the `DaqBackend` protocol in process, on the sim-server's own board.

A thin adapter: it holds a `simulated_hw.board.device.SimDevice` (the board `sfdrig sim-server`
serves) and drives it with the tasks `daq.nidaqmx_backend.NidaqmxBackend` creates on a board: AI
continuous on the board's clock, AO on the AI sample clock (non-regenerating, or the
regenerating ring ``ao_ring_s``) with idle output 0 V, the relay lines software-timed, and the
optional watchdog timer task (relay lines low, drives 0 V). The clock, the acquisition, the AO
generation and its errors, the watchdog, the e-stop and the rig between runs are the board's;
what is left here is the protocol's bookkeeping (the ring's prefill, the cut, the counts).

Fast mode (``realtime=False``) is the board's fast mode: the rig runs when a block is read, so a
40 s sweep takes well under a second, and between runs the device clock follows ``clock`` in
whole seconds (the oil fills or drains over a pause). Paced mode (``realtime=True``): samples
become available as the (injectable) clock advances, a read waits for them (timeout -> DAQmx
-200284), a reader that falls more than ``buffer_s`` behind loses data (-200279), and an AO
writer that falls behind the generation underflows (-200290; `read_ai` reports it too).

A trip's `cut_ao` drops the AO queued beyond the generation (fast mode: beyond the samples read).
``cut_stops=True`` (default): the AO task stops there and the drives show 0 V, as a board's AO
task stopped with idle output 0 V does; ``cut_stops=False``: the stream goes on with the next
write (the caller's fade) from the first sample dropped (paced: `CUT_MARGIN_S` after the
generation), which a board cannot do (`benchmarks/bench_trip.py` compares the two).

``wiring`` (None: the map the backend is configured with) is the simulated rig's own channel
map, as the sim-server's ``--channels``: which sensor is on which terminal, with its true gain
and gap voltage, and the drives and lines by terminal. The map given to `configure` is then only
what the software believes (a terminal the wiring leaves empty reads the board's noise about
0 V). `press_estop` presses the wiring's emergency stop. ``watchdog_s``: the board's watchdog
timer task on ``clock`` (relays off, drives 0 V, `feed_watchdog` raising -200644 once it was not
fed for that long; cleared by the next run's first write or a relay switched on); None
(default): none, the in-process rig stops with the process that runs it.

``ao_ring_s`` (None: non-regenerating) makes the AO a regenerating ring of that many seconds, as
`NidaqmxBackend` with ``ao_ring_s`` makes the board's: position ``k mod B`` plays at sample ``k``,
and a write lands at once (``ao_min_lead`` 0: no FIFO between it and the generation).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from daq.backend import AoCut, BackendBase, ring_samples
from daq.board import SIM, Board
from daq.channels import ChannelMap, TerminalConfig
from daq.errors import (
    OUTPUT_UNDERFLOW,
    DaqError,
    EmergencyStopError,
    error_for_code,
)
from rig_model.params import RigParams
from rig_model.rig import RigModel
from simulated_hw.board.codes import (
    IDLE_ZERO_VOLTS,
    MODE_CONTINUOUS,
    REGEN_ALLOW,
    REGEN_DONT_ALLOW,
    TERM_DEFAULT,
    TERM_DIFF,
    TERM_NRSE,
    TERM_PSEUDO_DIFF,
    TERM_RSE,
    WRITE_REL_CURR_POS,
    WRITE_REL_FIRST_SAMPLE,
    terminal_config_error,
)
from simulated_hw.board.device import SimDevice, rows_index
from simulated_hw.board.tasks import SimChannel, SimTask
from simulated_hw.board.watchdog import Watchdog

#: Paced: what a resuming cut leaves queued past the generation, so that the fade written next
#: arrives before the generation does [s].
CUT_MARGIN_S = 0.002
#: fast mode: the AI buffer [s] (nothing is ever behind the reader; a read larger grows it)
FAST_AI_BUFFER_S = 0.1
#: how long a non-regenerating write waits for room in the board's buffer [s]
WRITE_TIMEOUT_S = 10.0
#: the map's terminal configurations as DAQmx's codes: the in-process rig refuses what the
#: board refuses (its channels are differential only, as the report rig's PXIe-6358's are)
_TERM_CODES = {TerminalConfig.DEFAULT: TERM_DEFAULT, TerminalConfig.DIFFERENTIAL: TERM_DIFF,
               TerminalConfig.RSE: TERM_RSE, TerminalConfig.NRSE: TERM_NRSE,
               TerminalConfig.PSEUDO_DIFFERENTIAL: TERM_PSEUDO_DIFF}


class SimulatedBackend(BackendBase):
    """The simulated rig behind the `daq.DaqBackend` protocol: the sim-server's board, in
    process."""

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
        if ao_ring_s is not None and not ao_ring_s > 0:
            raise ValueError(f"ao_ring_s must be positive or None, got {ao_ring_s}")
        self.params = params if params is not None else RigParams()
        self.seed = seed
        self.realtime = realtime
        self.buffer_s = buffer_s
        self.cut_stops = cut_stops
        self.ao_ring_s = ao_ring_s
        self.wiring = wiring
        self.watchdog_s = watchdog_s
        self._clock = clock
        self._sleep = sleep
        super().__init__()
        #: the board (built at the first `configure`; again for another map without a wiring)
        self.device: SimDevice | None = None
        self._ai: SimTask | None = None
        self._ao: SimTask | None = None
        self._watchdog: SimTask | None = None
        self._prefill: np.ndarray | None = None  # the ring written before the start
        self._written_end = 0  # the end of the samples written this run
        self._running = False
        self._cut_at: int | None = None  # a stopping cut: the drives are at 0 V from here
        self._read = 0  # samples handed to the reader this run
        self._closed = False
        #: what the AO terminals showed at the samples not yet read (map rows), per block
        self._played: list[np.ndarray] = []
        self._ao_terminals: list[int] = []  # the map's AO rows among the board's terminals
        self._ao_index: slice | list[int] = []

    # --- protocol -------------------------------------------------------------------------
    @property
    def board(self) -> Board:
        """The simulated rig in this process (the map's device name)."""
        return Board(SIM, self.channel_map.device.name)

    @property
    def rig(self) -> RigModel | None:
        """The simulated rig now: the acquisition's, or the one between runs."""
        dev = self.device
        if dev is None:
            return None
        if dev.rig is not None:
            return dev.rig
        return dev.carried[0] if dev.carried is not None else None

    def configure(self, channel_map: ChannelMap) -> None:
        if self._running:
            raise DaqError("cannot reconfigure while running; stop first")
        for c in channel_map.ai:  # as the board refuses it (-200077), before anything is made
            if err := terminal_config_error(_TERM_CODES[c.terminal_config], [c.physical_channel],
                                            f"creating AI channel {c.name}"):
                raise err
        wiring = self.wiring if self.wiring is not None else channel_map
        if self.device is None or self.device.wiring != wiring:
            if self.device is not None:
                self.device.shutdown()
            self.device = SimDevice(wiring, self.params, self.seed, fast=not self.realtime,
                                    clock=self._clock, sleep=self._sleep, live_watchdog=False,
                                    rest_on_clock=True)
            self.device.on_terminals = self._on_terminals
        self._map = channel_map
        ao_all = self.device.spec.ao_channels()
        self._ao_terminals = [ao_all.index(c.physical_channel) for c in channel_map.ao]
        self._ao_index = rows_index(self._ao_terminals)  # a slice (a view) when in order
        fs = channel_map.sample_rate_hz
        buffer = max(int(round(self.buffer_s * fs)), 2)
        if not self.realtime:  # the board takes only what is read: a small buffer stays in cache
            buffer = min(buffer, max(int(fs * FAST_AI_BUFFER_S), 2))
        self._ai = SimTask("ai", [SimChannel(c.name, "ai", [c.physical_channel], *c.range_v)
                                  for c in channel_map.ai],
                           rate_hz=fs, sample_mode=MODE_CONTINUOUS, buffer_samples=buffer)
        self._new_ao_task()
        if self._watchdog is not None:
            self.device.remove_watchdog(self._watchdog.watchdog)
            self._watchdog = None
        if self.watchdog_s is not None:
            w = Watchdog(channel_map.device.name, self.watchdog_s,
                         ao_states={c.physical_channel: 0.0 for c in channel_map.ao},
                         do_states={d.physical_channel: False for d in channel_map.do})
            self._watchdog = SimTask("watchdog", watchdog=w)
            self.device.add_watchdog(w)
            self.device.start(self._watchdog, [])

    def _new_ao_task(self) -> None:
        """A fresh AO task on the AI sample clock, idle output 0 V: nothing written yet."""
        cm = self.channel_map
        fs = cm.sample_rate_hz
        ring = self.ao_ring_samples
        self._ao = SimTask(
            "ao", [SimChannel(c.name, "ao", [c.physical_channel], *c.range_v,
                              idle_behavior=IDLE_ZERO_VOLTS) for c in cm.ao],
            rate_hz=fs, clock_source=f"/{cm.device.name}/ai/SampleClock",
            sample_mode=MODE_CONTINUOUS,
            buffer_samples=ring if ring is not None else max(int(round(self.buffer_s * fs)), 2),
            regen_mode=REGEN_DONT_ALLOW if ring is None else REGEN_ALLOW,
            write_relative_to=WRITE_REL_CURR_POS if ring is None else WRITE_REL_FIRST_SAMPLE)
        self._prefill = None if ring is None else np.zeros((len(cm.ao), ring))
        self._written_end = 0
        self._cut_at = None

    @property
    def ao_ring_samples(self) -> int | None:
        if self.ao_ring_s is None:
            return None
        return ring_samples(self.ao_ring_s, self.sample_rate_hz)

    @property
    def ao_min_lead(self) -> int:
        """A write lands at once, nothing between it and the generation."""
        return 0

    def ao_generated(self) -> int:
        """AO samples generated since the start: the AO runs on the AI sample clock from the AI
        start, so the samples that clock has produced (counted, not simulated: asked every
        block, simulating the few samples since the last call would cost a rig step each)."""
        if not self._running:
            return 0
        return self._board().samples_due()

    def start(self) -> None:
        """Start the generation and the acquisition: a new run counts its samples from 0, as a
        board's tasks do (the rig itself keeps moving from where the last run left it)."""
        dev, ai, ao = self._board(), self._ai, self._ao
        assert ai is not None and ao is not None
        if self._prefill is not None:  # the ring: written whole, in order, before the start
            ao.write_offset = 0
            dev.write_ao(ao, self._prefill, False, WRITE_TIMEOUT_S, [ai])
            self._prefill = None
        if ao.channels:
            dev.start(ao, [ai])
        dev.start(ai, [ao])
        self._running = True
        self._read = 0
        self._played = []

    def write_ao(self, block: np.ndarray, at: int | None = None) -> None:
        cm = self.channel_map
        arr = np.asarray(block, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] != len(cm.ao):
            raise ValueError(f"AO block must have shape ({len(cm.ao)}, n), got {arr.shape}")
        dev, ai, ao = self._board(), self._ai, self._ao
        assert ai is not None and ao is not None
        if not self._running:  # a run's first write: the operator's decision to drive
            if self.estop_pressed():
                raise EmergencyStopError("the emergency stop is pressed: nothing is driven")
            self.rearm_estop()
            self._clear_watchdog()
        if arr.size:  # each row's extremes, in two passes over the block
            low, high = arr.min(axis=1), arr.max(axis=1)
            for row, ch in enumerate(cm.ao):
                if low[row] < ch.range_v[0] or high[row] > ch.range_v[1]:
                    raise error_for_code(
                        f"{ch.name}: AO sample outside the channel range {ch.range_v} V", -200561
                    )
        if self._cut_at is not None or arr.shape[1] == 0:
            return  # the generation has stopped: nothing written now plays
        ring = self.ao_ring_samples
        if ring is not None:
            at = self._written_end if at is None else int(at)
            if arr.shape[1] > ring:
                raise ValueError(f"AO write of {arr.shape[1]} samples is longer than the "
                                 f"{ring}-sample ring")
            if at < 0:
                raise ValueError(f"AO write position must be >= 0, got {at}")
            if self._prefill is not None:
                idx = (at + np.arange(arr.shape[1])) % ring
                self._prefill[:, idx] = arr
            else:
                ao.write_offset = at % ring
                dev.write_ao(ao, arr, False, WRITE_TIMEOUT_S, [ai], in_range=True)
            self._written_end = max(self._written_end, at + arr.shape[1])
            return
        if at is not None and at != self._written_end:
            raise ValueError(f"a non-regenerating AO stream writes at sample "
                             f"{self._written_end}, not {at}")
        dev.write_ao(ao, arr, False, WRITE_TIMEOUT_S, [ai], in_range=True)  # checked above
        self._written_end += arr.shape[1]

    def read_ai(self, n: int, timeout_s: float = 10.0) -> np.ndarray:
        dev, ai, ao = self._board(), self._ai, self._ao
        assert ai is not None and ao is not None
        if not self._running:
            raise DaqError("read_ai before start()")
        if n <= 0:
            raise ValueError(f"read_ai: n must be positive, got {n}")
        self.check_estop()
        with dev.lock:
            dev.watchdog_timer.check()
        out = dev.read(ai, n, timeout_s, [ao])
        self._read += n
        self._take_played(n)
        if ao.error is not None and ao.error.code == OUTPUT_UNDERFLOW:
            raise ao.error  # the generation ran dry (a board reports it on the next write)
        w = self._watchdog
        if w is not None:
            with dev.lock:  # a read feeds the watchdog, as the board backend's
                dev.watchdog_timer.check()
                if not w.watchdog.expired:
                    dev.feed_watchdog(w)
        return out

    def _on_terminals(self, first: int, terminals: np.ndarray) -> None:
        """The board's hook: every AO terminal at AI samples ``first..``; kept in map rows."""
        self._played.append(terminals[self._ao_index])

    def _take_played(self, n: int) -> np.ndarray:
        """What the AO terminals showed at the ``n`` samples just read (map rows)."""
        parts, got = [], 0
        while got < n and self._played:
            chunk = self._played[0]
            take = min(n - got, chunk.shape[1])
            parts.append(chunk[:, :take])
            if take == chunk.shape[1]:
                self._played.pop(0)
            else:
                self._played[0] = chunk[:, take:]
            got += take
        if not parts:
            return np.zeros((len(self.channel_map.ao), 0))
        return np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]

    def ai_on_host(self) -> int:
        """Never reads ahead: in process a read costs no round trip."""
        return 0

    def set_do(self, name: str, value: bool) -> None:
        relay = self.channel_map.relay(name)  # KeyError names the missing relay
        dev = self._board()
        if value:
            self._clear_watchdog()  # switching a relay on: the operator's decision
        elif self.watchdog_expired:
            return  # the expired watchdog holds the line low already
        dev.write_lines([relay.physical_channel], [bool(value)])

    def ao_backlog(self) -> int:
        """Samples written and not yet generated (regenerating: negative once the generation
        has passed the last sample written)."""
        if not self._running:
            return self._written_end
        if self.ao_ring_samples is None and self._cut_at is not None:
            return 0  # a stopped generation: what was queued was dropped
        return self._written_end - self.ao_generated()

    def cut_ao(self) -> AoCut:
        """Drop the AO queued beyond the generation (see the module doc)."""
        if not self._running:
            return AoCut(self._written_end, True)
        if self._cut_at is not None:
            return AoCut(self._cut_at, False)
        dev, ao = self._board(), self._ao
        assert ao is not None
        with dev.lock:
            dev.catch_up()
            generated = ao.ao.generated
            if self.cut_stops:
                dev.stop(ao)  # idle output 0 V from the next sample on
                self._cut_at = generated
                return AoCut(generated, False)
            margin = int(CUT_MARGIN_S * self.sample_rate_hz) if self.realtime else 0
            if self.ao_ring_samples is not None:
                return AoCut(generated + margin, True)
            keep = min(margin, ao.ao.queued)
            ao.ao.keep_queued(keep)
            self._written_end = generated + keep
            return AoCut(self._written_end, True)

    def feed_watchdog(self) -> None:
        """Reset the watchdog timer (``watchdog_s``; no-op without one); raises
        `daq.errors.DaqWatchdogExpiredError` (-200644) once it has expired."""
        if self._watchdog is not None:
            self._board().feed_watchdog(self._watchdog)

    def _clear_watchdog(self) -> None:
        if self._watchdog is not None and self.watchdog_expired:
            self._board().clear_expiration(self._watchdog)

    @property
    def watchdog_expired(self) -> bool:
        """Whether the watchdog has expired (what the board's own state says)."""
        if self._watchdog is None:
            return False
        dev = self._board()
        with dev.lock:
            dev.watchdog_timer.check()
            return bool(self._watchdog.watchdog.expired)

    def press_estop(self, pressed: bool) -> None:
        """A hand on the wiring's emergency-stop button (simulation only)."""
        self._board().press_estop(pressed)

    def estop_pressed(self) -> bool:
        """Whether the map's emergency-stop line reads pressed: the wiring's button (the map's
        own without a wiring) sets its level; a line the wiring leaves open reads low."""
        cm, dev = self._map, self.device
        if cm is None or cm.estop is None or dev is None:
            return False
        with dev.lock:
            level = dev.inputs.get(cm.estop.physical_channel, False)
        return level == cm.estop.pressed_level

    def stop(self) -> None:
        """Stop both tasks: what was written and not generated is dropped (a board's buffer
        is), and the next run primes the AO again and counts from sample 0."""
        dev = self.device
        if dev is not None and self._ai is not None and self._ao is not None:
            dev.stop(self._ai)
            dev.stop(self._ao)
        self._running = False
        if self._map is not None:
            self._new_ao_task()

    def close(self) -> None:
        if self.device is not None and not self._closed:
            if self._running:
                self.stop()
            self.device.shutdown()
        self._running = False
        self._closed = True

    # --- simulation-only helpers ----------------------------------------------------------
    @property
    def samples_read(self) -> int:
        return self._read

    def _board(self) -> SimDevice:
        if self.device is None or self._map is None:
            raise DaqError("backend not configured: call configure(channel_map) first")
        if self._closed:
            raise DaqError("backend is closed")
        return self.device

