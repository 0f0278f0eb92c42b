"""`NidaqmxBackend`: the `DaqBackend` protocol on the official ``nidaqmx`` package.

Runs against the local NI-DAQmx driver, or against an NI gRPC Device Server when the channel
map names one (``ChannelMap.grpc_target = "host:port"``). Three tasks:

- AI: one voltage channel per analog input (with its range), hardware-timed, continuous, on the
  onboard clock; read with `AnalogMultiChannelReader` (no per-read attribute round trips).
- AO: one voltage channel per shaker drive on ``/<dev>/ai/SampleClock`` and armed on
  ``/<dev>/ai/StartTrigger``, so AO sample ``k`` is generated as AI sample ``k`` is taken;
  written with `AnalogMultiChannelWriter`. Non-regenerating, or (``ao_ring_s``) a regenerating
  ring of that many seconds (DAQmx ALLOW_REGENERATION, buffer = the ring): each block is
  written at its absolute sample ``k`` through the write position (``out_stream.relative_to =
  FIRST_SAMPLE``, ``out_stream.offset = k mod B``), the generation count is
  ``TotalSampPerChanGenerated``, and a late host makes the board repeat the ring instead of
  underflowing. The device's on-board FIFO holds samples ahead of the generation that a write
  can no longer change, so the backend shrinks it (``out_stream.output_onbrd_buf_size``, where
  the device lets it) and names what is left in `ao_min_lead`. A ring repeats its drive for as
  long as a hung host leaves it: it needs the watchdog (below), whose expiry sets the drives to
  0 V; without AO expiration states the backend falls back to the non-regenerating stream.
- DO: one line per relay, software-timed.
- DI: the optional emergency-stop line, read once per `read_ai` (software-timed).

Safe states the board keeps on its own when this program stops looking after it:

- AO idle output behaviour 0 V (where the device supports it; `ao_idle_zero` says whether it
  does): when the generation stops for any reason (underflow, stop, a crashed client whose tasks
  are cleared) the shaker drives go to 0 V instead of holding the last sample.
- A DAQmx watchdog timer task (``watchdog_timeout_s``): unless `feed_watchdog` (called by
  `read_ai`, and by the daemon while idle) resets it in time, the board turns every relay line
  off and, where the device has AO expiration states, sets the drives to 0 V, and holds them
  there (writes fail with -200678) until a new run's first write or a relay switched on (both
  the operator's decisions) clears the expiration.

Task names carry a uuid, and gRPC sessions are created with ``INITIALIZE_SERVER_SESSION``, so
a stale task left on a server by a crashed client is never re-attached. Every nidaqmx
``DaqError`` reaches the caller as `daq.errors.DaqError` (the subclass for its code, via
`daq.errors.error_for_code`); gRPC failures and a missing driver as `DaqConnectionError`.
"""

from __future__ import annotations

import logging
import math
import time
import uuid
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from daq.backend import AoCut, BackendBase, ring_samples
from daq.board import NIDAQMX, Board
from daq.channels import ChannelMap, TerminalConfig
from daq.errors import (
    ATTR_NOT_SUPPORTED,
    ATTR_NOT_SUPPORTED_IN_TASK,
    WATCHDOG_TIMER_NOT_SUPPORTED,
    ChannelConfigError,
    DaqError,
    EmergencyStopError,
    error_for_code,
)
from daq.nidaqmx_packed import PackedWriter, packed_reads
from daq.nidaqmx_session import NidaqmxSession, _nidaqmx, close_task, translate_errors

__all__ = ["NidaqmxBackend", "terminal_configuration", "translate_errors"]

_log = logging.getLogger(__name__)

#: how much longer than the watchdog timeout the AO ring must be [s]
RING_OVER_WATCHDOG_S = 0.2
#: what the backend asks the on-board AO FIFO to hold in ring mode [s]; the writer's margin
#: covers it and a transfer
ONBOARD_S = 0.002
#: a write's transfer to the device's buffer, beyond the FIFO [s]
TRANSFER_S = 0.003
#: A reader behind the board takes at most this much in one gRPC read [s] (14 channels at
#: 10 kS/s: 280 kB, well under gRPC's 4 MB message limit).
AI_CATCH_UP_S = 0.25
#: `NidaqmxBackend.ao_generated` asks the board this often at most [s], and estimates the count
#: in between from the answers of the last `GEN_OFFSET_WINDOW_S` (short: the board's clock and
#: the host's drift apart by tens of ppm).
GEN_QUERY_S = 0.05
GEN_OFFSET_WINDOW_S = 1.0

class NidaqmxBackend(BackendBase):
    """Hardware-timed AI, streaming AO on the AI clock and relay lines, through nidaqmx.

    Parameters
    ----------
    buffer_s : float
        Size of the AI and AO buffers on the device [s of samples]. A reader more than this
        behind loses data (DAQmx -200279); the AO writer may run at most this far ahead.
    connect_timeout_s : float
        How long ``configure`` waits for a gRPC server to answer [s].
    grpc_target : str, optional
        ``"host:port"`` of an NI gRPC Device Server; overrides ``ChannelMap.grpc_target``.
    watchdog_timeout_s : float or None
        The board's watchdog timer [s]: relays off and drives to 0 V if it is not fed for
        this long. None: no watchdog.
    ao_ring_s : float or None
        The regenerating AO ring [s]; None: non-regenerating. Needs the watchdog, at least
        ``RING_OVER_WATCHDOG_S`` shorter than the ring (a hung host is stopped by it before an
        abort's fade could come round again).
    clock : callable
        The host's monotonic clock [s] (default `time.monotonic`): the watchdog's feeding, the
        AI read-ahead and the AO generation estimate count on it (tests pass the fake clock
        of a sim-server paced on it).
    """

    def __init__(self, buffer_s: float = 10.0, connect_timeout_s: float = 5.0,
                 grpc_target: str | None = None,
                 watchdog_timeout_s: float | None = 1.0,
                 ao_ring_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if buffer_s <= 0:
            raise ValueError(f"buffer_s must be positive, got {buffer_s}")
        if ao_ring_s is not None:
            if not ao_ring_s > 0:
                raise ValueError(f"ao_ring_s must be positive or None, got {ao_ring_s}")
            if watchdog_timeout_s is None or \
                    watchdog_timeout_s + RING_OVER_WATCHDOG_S > ao_ring_s:
                raise ValueError(
                    f"ao_ring_s = {ao_ring_s:g} s needs a watchdog_timeout_s of at most "
                    f"{ao_ring_s - RING_OVER_WATCHDOG_S:g} s, got {watchdog_timeout_s}: a ring "
                    "repeats its drive for as long as a hung host leaves it")
        self._clock = clock
        self.ao_ring_s = ao_ring_s
        self._ring: int | None = None  # the ring in use (samples), once configured
        self._written_end = 0
        #: the on-board FIFO samples a write cannot change any more (ring mode)
        self._onboard = 0
        if watchdog_timeout_s is not None and not 0 < watchdog_timeout_s <= 60:
            raise ValueError(f"watchdog_timeout_s must be in (0, 60] s or None, got "
                             f"{watchdog_timeout_s}")
        self.watchdog_timeout_s = watchdog_timeout_s
        self._watchdog: Any = None
        self._fed_at = 0.0
        #: whether the device took AO idle output 0 V (None: not configured yet)
        self.ao_idle_zero: bool | None = None
        #: whether the watchdog sets the drives to 0 V on expiry (not only the relays)
        self.watchdog_sets_ao: bool | None = None
        self.buffer_s = buffer_s
        self.connect_timeout_s = connect_timeout_s
        self._grpc_override = grpc_target
        super().__init__()
        self._ai_started_at = 0.0  # host monotonic time of the AI start
        self._ai_taken = 0  # AI samples handed out since the start
        self._ai_ahead: np.ndarray | None = None  # read from the board, not yet handed out
        #: the board's AO counts of the last `GEN_OFFSET_WINDOW_S`: (host time before, count)
        self._gen_answers: deque[tuple[float, int]] = deque()
        self._session: NidaqmxSession | None = None
        self._ai: Any = None
        self._ao: Any = None
        self._do: Any = None
        self._estop_task: Any = None
        self._estop_reader: Any = None
        self._reader: Any = None
        self._writer: Any = None
        self._packed: PackedWriter | None = None  # the AO write with packed samples (gRPC)
        self._do_writer: Any = None
        self._do_state: np.ndarray = np.zeros(0, dtype=bool)
        self._ao_written = 0
        self._running = False
        #: the device said it is simulated (DevIsSimulated, asked at `configure`): a rehearsal
        #: on an NI simulated device or `sfdrig sim-server` never reads as the rig
        self._simulated = False

    # --- protocol -------------------------------------------------------------------------
    @property
    def board(self) -> Board:
        """The map's device, through the local driver or the gRPC device server."""
        return Board(NIDAQMX, self.channel_map.device.name, self.grpc_target,
                     simulated=self._simulated)

    @property
    def grpc_target(self) -> str | None:
        if self._grpc_override is not None:
            return self._grpc_override
        return self._map.grpc_target if self._map is not None else None

    @property
    def ao_ring_samples(self) -> int | None:
        """The regenerating ring in use [samples] (None: non-regenerating; before configure:
        what ``ao_ring_s`` asks for)."""
        if self._ao is None and self._map is not None and self.ao_ring_s is not None:
            return ring_samples(self.ao_ring_s, self._map.sample_rate_hz)
        return self._ring

    @property
    def ao_min_lead(self) -> int:
        """The on-board FIFO plus a transfer [samples]: a ring write closer to the generation
        than this may not play."""
        fs = self._map.sample_rate_hz if self._map is not None else 0.0
        return self._onboard + int(math.ceil(TRANSFER_S * fs))

    def ao_generated(self) -> int:
        """AO samples generated since the start (DAQmx TotalSampPerChanGenerated).

        The board is asked at most every `GEN_QUERY_S`; in between, the count is the host's
        monotonic clock since the start times the rate, plus the offset the board's answers of
        the last second give (each answer paired with the time *before* the question: the
        count was read after it, so the offset is never too small and neither is the count,
        which only errs towards a later generation: a write lands further ahead, a fade starts
        a little later). Through gRPC a question is a round trip: asked every 10 ms block it
        was a sixth of the daemon's time. Cuts (`cut_ao`) always ask the board."""
        if self._ao is None or not self._running:
            return 0
        now = self._clock()
        fs = self.channel_map.sample_rate_hz
        answers = self._gen_answers
        if answers and now - answers[-1][0] < GEN_QUERY_S and self._gen_paced(fs):
            offset = min(count - t * fs for t, count in answers)
            # never below the board's last answer, nor below the AI samples it has handed over
            # (AO and AI share the sample clock and the start)
            have = 0 if self._ai_ahead is None else self._ai_ahead.shape[1]
            return max(int(math.ceil(now * fs + offset)), answers[-1][1],
                       self._ai_taken + have)
        with translate_errors("asking for the AO samples generated"):
            count = int(self._ao.out_stream.total_samp_per_chan_generated)
        self._gen_answers.append((now, count))
        while now - self._gen_answers[0][0] > GEN_OFFSET_WINDOW_S:
            self._gen_answers.popleft()
        return count

    def configure(self, channel_map: ChannelMap) -> None:
        """Create the AI, AO and DO tasks for ``channel_map``; nothing starts yet.

        Raises `DaqConnectionError` when no driver or server answers, and the typed
        `DaqError` for what the device refuses (e.g. -200170 for a physical channel it lacks,
        -200332 for a rate above its maximum); the message names the channel or setting.
        """
        if self._running:
            raise DaqError("cannot reconfigure while running; stop first")
        self.close()
        self._map = channel_map
        self._ao_written = self._written_end = 0
        try:
            self._create_tasks(channel_map)
            self._simulated = self._connection().device_is_simulated(channel_map.device.name)
        except BaseException:
            self.close()
            self._map = channel_map
            raise

    def start(self) -> None:
        """Arm AO on the AI start trigger, then start AI (write the AO prefill first)."""
        self._require_tasks()
        if self._ao is not None:
            with translate_errors("starting the AO task"):
                self._ao.start()
        with translate_errors("starting the AI task"):
            self._ai.start()
        self._running = True
        self._gen_answers.clear()
        self._ai_started_at = self._clock()
        self._ai_taken = 0
        self._ai_ahead = None

    def write_ao(self, block: np.ndarray, at: int | None = None) -> None:
        """Queue the next AO samples, volts, shape ``(n_ao, n)``; in ring mode write them at
        absolute sample ``at`` (None: after the last written), split at the ring's end."""
        cm = self.channel_map
        arr = np.ascontiguousarray(block, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] != len(cm.ao) or arr.shape[1] == 0:
            raise ValueError(f"AO block must have shape ({len(cm.ao)}, n>0), got {arr.shape}")
        if self._writer is None:
            raise DaqError("write_ao: no AO task (configure a channel map with AO channels)")
        if not self._running and self._ao_written == 0:  # a new run's prefill
            if self.estop_pressed():
                raise EmergencyStopError(f"the emergency stop ({self.estop_where()}) is "
                                         "pressed: release it before starting")
            self.rearm_estop()
            self._clear_expired_watchdog()  # the operator's decision
        if self._ring is None:
            if at is not None and at != self._ao_written:
                raise ValueError(f"a non-regenerating AO stream writes at sample "
                                 f"{self._ao_written}, not {at}")
            self._write_many(arr)
            return
        at = self._written_end if at is None else int(at)
        if arr.shape[1] > self._ring or at < 0:
            raise ValueError(f"AO write of {arr.shape[1]} samples at {at}: the ring holds "
                             f"{self._ring}, positions start at 0")
        first = at % self._ring
        split = min(arr.shape[1], self._ring - first)
        for offset, part in ((first, arr[:, :split]), (0, arr[:, split:])):
            if part.shape[1]:
                with translate_errors(f"setting the AO write position to {offset}"):
                    self._ao.out_stream.offset = offset
                self._write_many(np.ascontiguousarray(part))
        self._written_end = max(self._written_end, at + arr.shape[1])

    def _write_many(self, arr: np.ndarray) -> None:
        with translate_errors(f"writing {arr.shape[1]} AO samples"):
            if self._packed is not None and self._packed.available:
                written = self._packed.write(arr, self.buffer_s)
            else:
                written = self._writer.write_many_sample(arr, timeout=self.buffer_s)
        self._ao_written += int(written)
        if written != arr.shape[1]:
            raise error_for_code(
                f"writing AO: only {written} of {arr.shape[1]} samples were written", -200292
            )

    def read_ai(self, n: int, timeout_s: float = 10.0) -> np.ndarray:
        """The next ``n`` AI samples per channel, volts, shape ``(n_ai, n)``."""
        if n <= 0:
            raise ValueError(f"read_ai: n must be positive, got {n}")
        self._require_tasks()
        ahead = self._ai_ahead
        have = 0 if ahead is None else ahead.shape[1]
        if have < n:  # a read from the board (the e-stop is read with each)
            if self._estop_task is not None:
                self.check_estop()
            m = self._ai_read_size(n - have, have)
            fresh = np.empty((len(self.channel_map.ai), m))
            with translate_errors(f"reading {m} AI samples"):
                got = self._reader.read_many_sample(fresh, number_of_samples_per_channel=m,
                                                    timeout=timeout_s)
            if got != m:  # never hand back a short block silently
                raise error_for_code(f"reading AI: got {got} of {m} samples", -200284)
            ahead = fresh if ahead is None or not have else np.hstack([ahead, fresh])
        assert ahead is not None  # have >= n > 0, or just read (for mypy)
        out, rest = ahead[:, :n], ahead[:, n:]
        self._ai_ahead = rest if rest.shape[1] else None
        self._ai_taken += n
        if self._watchdog is not None and self.watchdog_timeout_s is not None and \
                self._clock() - self._fed_at > self.watchdog_timeout_s / 4:
            self.feed_watchdog()
        return out

    def ai_on_host(self) -> int:
        """AI samples read ahead from the board (a host that was behind), not handed out."""
        return 0 if self._ai_ahead is None else int(self._ai_ahead.shape[1])

    def _gen_paced(self, fs: float) -> bool:
        """Whether the board's answers of the last second count at its sample rate on the
        host's clock (a real board does; the sim-server's fast mode does not: it generates as
        fast as it is read, and the count is then always asked)."""
        (t0, c0), (t1, c1) = self._gen_answers[0], self._gen_answers[-1]
        return t1 - t0 >= 0.2 and abs((c1 - c0) / (t1 - t0) - fs) < 0.1 * fs

    def _gen_unpaced(self, fs: float) -> bool:
        """Whether the board's answers, over at least 0.2 s, are seen not to follow the host's
        clock (the sim-server's fast mode)."""
        if not self._gen_answers:
            return False
        (t0, _), (t1, _) = self._gen_answers[0], self._gen_answers[-1]
        return t1 - t0 >= 0.2 and not self._gen_paced(fs)

    def _ai_read_size(self, need: int, have: int) -> int:
        """How many samples the next gRPC read takes: ``need``, or, when the board holds
        more (its sample clock, counted on the host's monotonic clock, has run ahead of the
        reads), whole multiples of ``need`` more, up to `AI_CATCH_UP_S` and less one
        ``need`` for the two clocks' offset: a host that fell behind catches up in a few
        calls instead of one per block (the e-stop and the gRPC round trip with each). What
        is read ahead is handed out by the next `read_ai` calls without a call.

        Not on a board whose generation count is seen not to follow the host's clock (the
        sim-server's fast mode): there a read moves the board's clock, and reading ahead of
        what a late host has written underflows the AO. Until the count is seen to follow it
        (the first 0.2 s of a run, or a host that never asks it), a host whose clock says it
        is behind asks the board's count (AO and AI share the sample clock), which says what
        the board holds: a busy host's first read on the fast board ran the generation past
        what was written (-200290)."""
        fs = self.channel_map.sample_rate_hz
        if self._gen_unpaced(fs):
            return need
        held = int((self._clock() - self._ai_started_at) * fs) - self._ai_taken - have
        if held < 3 * need:  # on time: no read-ahead, no question
            return need
        if not self._gen_answers or not self._gen_paced(fs):
            held = min(held, self.ao_generated() - self._ai_taken - have)
        extra = min(held - 2 * need, int(AI_CATCH_UP_S * fs))
        return need + need * max(extra // need, 0)

    def estop_pressed(self) -> bool:
        """Whether the emergency-stop input reads pressed (False when there is none)."""
        if self._estop_task is None or self._map is None or self._map.estop is None:
            return False
        with translate_errors(f"reading the emergency stop ({self.estop_where()})"):
            level = bool(self._estop_reader.read_one_sample_one_line(
                timeout=self.connect_timeout_s))
        return level == self._map.estop.pressed_level

    def feed_watchdog(self) -> None:
        """Reset the board's watchdog timer (no-op without one). Raises
        `DaqWatchdogExpiredError` once it has expired."""
        if self._watchdog is None:
            return
        with translate_errors("resetting the watchdog timer"):
            self._watchdog.reset_timer()
        self._fed_at = self._clock()

    def _clear_expired_watchdog(self) -> None:
        if self._watchdog is None:
            return
        with translate_errors("reading the watchdog state"):
            expired = bool(self._watchdog.expired)
        if expired:
            _log.warning("the board's watchdog timer had expired (relays off, drives 0 V); "
                         "clearing it to start")
            with translate_errors("clearing the watchdog expiration"):
                self._watchdog.clear_expiration()
        self.feed_watchdog()

    def set_do(self, name: str, value: bool) -> None:
        """Set the relay line called ``name`` in the channel map (software-timed, at once)."""
        cm = self.channel_map
        cm.relay(name)  # KeyError names the missing relay
        index = [d.name for d in cm.do].index(name)
        self._require_tasks()
        if value:
            self._clear_expired_watchdog()  # switching a relay on: the operator's decision
        state = self._do_state.copy()
        state[index] = bool(value)
        with translate_errors(f"setting relay {name} ({cm.do[index].physical_channel})"):
            self._do_writer.write_one_sample_one_line(state, timeout=self.connect_timeout_s)
        self._do_state = state

    def ao_backlog(self) -> int:
        """Samples written to AO but not yet generated (DAQmx TotalSampPerChanGenerated)."""
        if self._ao is None:
            return 0
        end = self._ao_written if self._ring is None else self._written_end
        if not self._running:
            return end
        return end - self.ao_generated()

    def cut_ao(self) -> AoCut:
        """A trip: stop the AO task at once (DAQmx Stop Task: the samples written but not
        generated are never generated) and, with AO idle output 0 V, the drives are at 0 V from
        the next sample of the AI clock; AI keeps acquiring. Without idle output 0 V a stopped
        task would hold its last sample on the amplifiers, so nothing is dropped: the queue
        plays out and the caller's fade follows it."""
        if self._ao is None or not self._running or not self.ao_idle_zero:
            return AoCut(self._ao_written if self._ring is None else self._written_end, True)
        out = self._ao.out_stream
        with translate_errors("stopping the AO task (a trip: drives to 0 V at once)"):
            before = int(out.total_samp_per_chan_generated)
            self._ao.stop()
        try:  # the exact count once stopped; a device that answers only while running: before
            with translate_errors("asking for the AO samples generated"):
                generated = int(out.total_samp_per_chan_generated)
        except DaqError:
            generated = before
        return AoCut(generated, False)

    def stop(self) -> None:
        """Stop AI, then AO; the last AO samples written stay on the outputs."""
        first: DaqError | None = None
        for task, what in ((self._ai, "AI"), (self._ao, "AO")):
            if task is None:
                continue
            try:
                with translate_errors(f"stopping the {what} task"):
                    task.stop()
            except DaqError as err:
                first = first or err
        self._running = False
        self._ao_written = self._written_end = 0  # a restart counts from zero again
        self._ai_ahead = None
        if first is not None:
            raise first

    def close(self) -> None:
        """Clear every task and close the gRPC channel; safe to call twice. Failures (e.g.
        the server is gone) are logged, not raised: there is nothing left to release."""
        for attr in ("_ai", "_ao", "_do", "_estop_task", "_watchdog"):
            task = getattr(self, attr)
            setattr(self, attr, None)
            if task is None:
                continue
            close_task(task)
        self._reader = self._writer = self._do_writer = self._estop_reader = None
        self._packed = None
        self._running = False
        self._ring = None
        if self._session is not None:
            self._session.close()
            self._session = None

    # --- internals ------------------------------------------------------------------------
    def _require_tasks(self) -> None:
        if self._map is None:
            raise DaqError("backend not configured: call configure(channel_map) first")
        if self._ai is None:
            raise DaqError("backend is closed (or its configuration failed); configure again")

    def _connection(self) -> NidaqmxSession:
        if self._session is None:
            self._session = NidaqmxSession(self.grpc_target, self.connect_timeout_s)
        return self._session

    def _new_task(self, nidaqmx: Any, role: str) -> Any:
        return self._connection().new_task(role)

    def _create_tasks(self, cm: ChannelMap) -> None:
        nidaqmx = _nidaqmx()
        from nidaqmx.constants import AcquisitionType, LineGrouping

        dev = cm.device.name
        fs = cm.sample_rate_hz
        buffer = max(int(round(self.buffer_s * fs)), 2)
        # AI
        self._ai = self._new_task(nidaqmx, "ai")
        for ch in cm.ai:
            lo, hi = ch.range_v
            with translate_errors(f"AI channel {ch.name} on {ch.physical_channel}"):
                self._ai.ai_channels.add_ai_voltage_chan(
                    ch.physical_channel, name_to_assign_to_channel=ch.name,
                    terminal_config=terminal_configuration(ch.terminal_config), min_val=lo,
                    max_val=hi)
        with translate_errors(f"AI sample clock at {fs:g} S/s"):
            self._ai.timing.cfg_samp_clk_timing(
                fs, sample_mode=AcquisitionType.CONTINUOUS, samps_per_chan=buffer)
            actual = float(self._ai.timing.samp_clk_rate)
        if abs(actual - fs) > 1e-6 * fs:
            raise ChannelConfigError(
                f"sample_rate_hz = {fs:g}: the device coerced it to {actual:.9g} S/s; "
                "choose a rate its timebase divides exactly"
            )
        self._reader = nidaqmx.stream_readers.AnalogMultiChannelReader(self._ai.in_stream)
        self._reader.verify_array_shape = False
        packed_reads(self._ai)  # through gRPC: the samples as one array, not a float each
        # AO, on the AI clock and start trigger
        if cm.ao:
            self._ao = self._new_task(nidaqmx, "ao")
            for ao in cm.ao:
                lo, hi = ao.range_v
                with translate_errors(f"AO channel {ao.name} on {ao.physical_channel}"):
                    self._ao.ao_channels.add_ao_voltage_chan(
                        ao.physical_channel, name_to_assign_to_channel=ao.name, min_val=lo,
                        max_val=hi)
            with translate_errors(f"AO timing on /{dev}/ai/SampleClock"):
                self._ao.timing.cfg_samp_clk_timing(
                    fs, source=f"/{dev}/ai/SampleClock",
                    sample_mode=AcquisitionType.CONTINUOUS, samps_per_chan=buffer)
                self._ao.triggers.start_trigger.cfg_dig_edge_start_trig(f"/{dev}/ai/StartTrigger")
            self._set_ao_idle_zero()
            self._writer = nidaqmx.stream_writers.AnalogMultiChannelWriter(
                self._ao.out_stream, auto_start=False)
            self._writer.verify_array_shape = False
            self._packed = PackedWriter(self._ao)
        # DO, one channel per relay line
        if cm.do:
            self._do = self._new_task(nidaqmx, "do")
            for d in cm.do:
                with translate_errors(f"relay {d.name} on {d.physical_channel}"):
                    self._do.do_channels.add_do_chan(
                        d.physical_channel, name_to_assign_to_lines=d.name,
                        line_grouping=LineGrouping.CHAN_PER_LINE)
            self._do_writer = nidaqmx.stream_writers.DigitalMultiChannelWriter(
                self._do.out_stream, auto_start=True)
            self._do_writer.verify_array_shape = False
            self._do_state = np.zeros(len(cm.do), dtype=bool)
        if cm.estop is not None:
            self._estop_task = self._new_task(nidaqmx, "estop")
            with translate_errors(f"emergency stop {cm.estop.name} on "
                                  f"{cm.estop.physical_channel}"):
                self._estop_task.di_channels.add_di_chan(
                    cm.estop.physical_channel, name_to_assign_to_lines=cm.estop.name,
                    line_grouping=LineGrouping.CHAN_PER_LINE)
            self._estop_reader = nidaqmx.stream_readers.DigitalSingleChannelReader(
                self._estop_task.in_stream)
        if self.watchdog_timeout_s is not None:
            self._create_watchdog(nidaqmx, cm)
        if self._ao is not None:
            self._set_regeneration(cm)

    def _set_regeneration(self, cm: ChannelMap) -> None:
        """The AO's mode: the ring (``ao_ring_s``) where the watchdog sets the drives to 0 V on
        expiry, otherwise non-regenerating."""
        from nidaqmx.constants import RegenerationMode, WriteRelativeTo

        ring = None
        if self.ao_ring_s is not None:
            if self.watchdog_sets_ao:
                ring = ring_samples(self.ao_ring_s, cm.sample_rate_hz)
            else:
                _log.warning("the watchdog cannot set the drives to 0 V on this device: a "
                             "ring would repeat for as long as a hung host left it, so the AO "
                             "streams without regeneration")
        out = self._ao.out_stream
        if ring is None:
            with translate_errors("setting the AO to non-regenerating"):
                out.regen_mode = RegenerationMode.DONT_ALLOW_REGENERATION
            self._ring = None
            return
        with translate_errors(f"setting up the regenerating AO ring of {ring} samples"):
            out.regen_mode = RegenerationMode.ALLOW_REGENERATION
            out.output_buf_size = ring
            out.relative_to = WriteRelativeTo.FIRST_SAMPLE
            out.offset = 0
        self._onboard = self._shrink_onboard(int(math.ceil(ONBOARD_S * cm.sample_rate_hz)))
        self._ring = ring

    def _shrink_onboard(self, wanted: int) -> int:
        """Ask the device's on-board AO FIFO to hold ``wanted`` samples; answer what it holds
        (the samples ahead of the generation a write can no longer change)."""
        out = self._ao.out_stream
        try:
            with translate_errors(f"setting the on-board AO buffer to {wanted} samples"):
                out.output_onbrd_buf_size = wanted
            with translate_errors("reading the on-board AO buffer size"):
                return int(out.output_onbrd_buf_size)
        except DaqError as err:
            if err.code not in (ATTR_NOT_SUPPORTED_IN_TASK, ATTR_NOT_SUPPORTED):
                raise
            _log.warning("%s: assuming the device's FIFO is %d samples ahead", err, wanted)
            return wanted

    def _set_ao_idle_zero(self) -> None:
        """AO idle output 0 V, where the device has the property (-200452 where not)."""
        from nidaqmx.constants import AOIdleOutputBehavior

        try:
            with translate_errors("setting the AO idle output behaviour to 0 V"):
                self._ao.ao_channels.all.ao_idle_output_behavior = AOIdleOutputBehavior.ZERO_VOLTS
            self.ao_idle_zero = True
        except DaqError as err:
            if err.code not in (ATTR_NOT_SUPPORTED_IN_TASK, ATTR_NOT_SUPPORTED):
                raise
            self.ao_idle_zero = False
            _log.warning("%s: the drives hold their last sample when a generation stops; "
                         "the stop path writes zeros first", err)

    def _create_watchdog(self, nidaqmx: Any, cm: ChannelMap) -> None:
        """The board's watchdog timer task: relays off and drives 0 V on expiry."""
        from nidaqmx.constants import Level, WatchdogAOExpirState
        from nidaqmx.system.watchdog import WatchdogTask
        from nidaqmx.types import AOExpirationState, DOExpirationState

        name = f"sfdrig-watchdog-{uuid.uuid4().hex[:12]}"
        options = self._connection().grpc_options()
        with translate_errors(f"creating the watchdog task {name} on {cm.device.name}"):
            self._watchdog = WatchdogTask(cm.device.name, name, self.watchdog_timeout_s,
                                          grpc_options=options)
            if cm.do:
                self._watchdog.cfg_watchdog_do_expir_states(
                    [DOExpirationState(d.physical_channel, Level.LOW) for d in cm.do])
        self.watchdog_sets_ao = False
        if cm.ao:
            try:
                with translate_errors("setting the watchdog's AO expiration states (0 V)"):
                    self._watchdog.cfg_watchdog_ao_expir_states(
                        [AOExpirationState(a.physical_channel, 0.0,
                                           WatchdogAOExpirState.VOLTAGE) for a in cm.ao])
                self.watchdog_sets_ao = True
            except DaqError as err:
                if err.code != WATCHDOG_TIMER_NOT_SUPPORTED:
                    raise
                _log.warning("%s: on expiry the watchdog turns the relays off; the drives "
                             "rely on their idle output and the AO underflow", err)
        with translate_errors("starting the watchdog timer"):
            self._watchdog.start()
        self._fed_at = self._clock()


def terminal_configuration(config: TerminalConfig) -> Any:
    """nidaqmx's ``TerminalConfiguration`` for a channel map's `TerminalConfig`."""
    from nidaqmx.constants import TerminalConfiguration as Tc

    return {TerminalConfig.DEFAULT: Tc.DEFAULT, TerminalConfig.DIFFERENTIAL: Tc.DIFF,
            TerminalConfig.RSE: Tc.RSE, TerminalConfig.NRSE: Tc.NRSE,
            TerminalConfig.PSEUDO_DIFFERENTIAL: Tc.PSEUDO_DIFF}[config]
