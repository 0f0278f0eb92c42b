"""A simulated NI-DAQmx gRPC Device Server: the rig behind the official ``nidaqmx`` client.

The servicer subclasses the one shipped in the pinned ``nidaqmx`` package, so the official
client (``nidaqmx.Task(grpc_options=...)``) drives it exactly as it would drive NI's own server.
It serves one device (``Dev1`` by default: ai0..ai15, ao0..ao1, port0/line0..7) wired to one
`simulated_hw.rig.RigModel`: each AI terminal carries the sensor the wiring map puts there, each
AO terminal drives the shaker of its axis, and the relay line switches the oil pump.

Supported: hardware-timed continuous (or finite) AI on the onboard clock; buffered,
non-regenerating AO on ``/Dev1/ai/SampleClock`` armed on ``/Dev1/ai/StartTrigger`` (AI sample
``k`` is taken while AO sample ``k`` is generated); software-timed DO lines and on-demand AO.

Time: paced (default), samples become available as the wall clock advances (a read waits;
too long -> DAQmx -200284; a reader more than the input buffer behind -> -200279; an AO writer
behind the generation -> -200290, the output then holds its last value). ``fast=True``
generates samples the moment they are read (no timeouts, no overflow; AO still underflows when
a read needs samples that were never written).

Errors go back as NI's server sends them: gRPC status UNKNOWN with trailing metadata
``ni-error: <code>`` (plus ``ni-samps-per-chan-read`` on reads), so the client raises
``nidaqmx.errors.DaqError`` with the real DAQmx code. One decorator, `_reports_daq_errors`, does
that for every RPC; handlers just raise `daq.errors.DaqError`.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent import futures
from dataclasses import dataclass, field
from typing import Any

import grpc
import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nidaqmx._stubs import nidaqmx_pb2_grpc as pb_grpc
from nidaqmx.utils import unflatten_channel_string
from session_pb2 import Session

from daq.channels import AnalogInput, ChannelMap, DeviceSpec, default_channel_map
from daq.errors import (
    DEVICE_NOT_FOUND,
    INPUT_BUFFER_OVERWRITTEN,
    INVALID_ATTRIBUTE_VALUE,
    OUTPUT_UNDERFLOW,
    READ_TIMEOUT,
    RESOURCE_RESERVED,
    SAMPLE_RATE_TOO_HIGH,
    DaqError,
    error_for_code,
)
from simulated_hw.params import RigParams
from simulated_hw.rig import RigModel

_log = logging.getLogger(__name__)

# --- NI-DAQmx codes and constants the server uses (values as in nidaqmx.error_codes/constants) --
UNKNOWN_ERROR = -200000  # no better code; the message says what happened
SAMPLE_RATE_TOO_LOW = -200331
INVALID_TASK = -200088
DUPLICATE_TASK = -200089
PHYSICAL_CHAN_DOES_NOT_EXIST = -200170
REPEATED_PHYSICAL_CHAN = -200371
ATTR_NOT_SUPPORTED = -200197
READ_BUFFER_TOO_SMALL = -200229
SAMPLES_CAN_NOT_YET_BE_WRITTEN = -200292
INVALID_AO_DATA_WRITE = -200561
TASK_NOT_RUNNING = -200475  # CANNOT_PERFORM_OP_WHEN_TASK_NOT_RUNNING
NO_CHANS_IN_TASK = -200478
NO_CHANS_OF_GIVEN_TYPE = -200611
INVALID_ROUTING_SOURCE = -200040
WRITE_NUM_CHANS_MISMATCH = -200524
ATTR_INCONSISTENT = -200128  # ATTRIBUTE_INCONSISTENT_ACROSS_REPEATED_PHYSICAL_CHANNELS

_ERROR_TEXT = {
    READ_TIMEOUT: "Wait Until Done did not indicate all samples were acquired/generated in the "
    "specified timeout: samples not yet available",
    INPUT_BUFFER_OVERWRITTEN: "The application is not able to keep up with the hardware "
    "acquisition: attempted to read samples that are no longer available",
    OUTPUT_UNDERFLOW: "Generation stopped to prevent the regeneration of old samples: the "
    "application is not able to write samples to the buffer fast enough",
    SAMPLE_RATE_TOO_HIGH: "Sample clock rate is higher than the maximum the device supports",
    SAMPLE_RATE_TOO_LOW: "Sample clock rate is lower than the minimum the device supports",
    DEVICE_NOT_FOUND: "Device identifier is invalid",
    PHYSICAL_CHAN_DOES_NOT_EXIST: "Physical channel specified does not exist on this device",
    RESOURCE_RESERVED: "The specified resource is reserved",
    INVALID_TASK: "Task specified is invalid or does not exist",
    DUPLICATE_TASK: "Task cannot be created because a task with this name already exists",
    INVALID_AO_DATA_WRITE: "Data written is outside the range of the output channel",
}

# channel types, measurement/output types, enums
CHAN_AI, CHAN_AO, CHAN_DO = 10100, 10102, 10153
MEAS_VOLTAGE = 10322
REGEN_ALLOW, REGEN_DONT_ALLOW = 10097, 10158
MODE_FINITE, MODE_CONTINUOUS = 10178, 10123
FILL_GROUP_BY_CHANNEL = 0
LINES_PER_CHAN_ALL = 1  # LineGrouping.CHAN_FOR_ALL_LINES
INIT_AUTO, INIT_NEW, INIT_ATTACH = 0, 1, 2

# attribute ids (nidaqmx task/_in_stream.py, _out_stream.py, _timing.py, system/_system.py)
ATTR_DRIVER_MAJOR, ATTR_DRIVER_MINOR, ATTR_DRIVER_UPDATE = 0x1272, 0x1923, 0x2F22
ATTR_SYS_DEVICES = 0x193B
ATTR_TASK_NAME, ATTR_TASK_CHANNELS, ATTR_TASK_NUM_CHANS = 0x1276, 0x1273, 0x2181
ATTR_CHAN_TYPE, ATTR_AI_MEAS_TYPE, ATTR_AO_OUTPUT_TYPE = 0x187F, 0x0695, 0x1108
ATTR_READ_CHANNELS, ATTR_READ_NUM_CHANS, ATTR_READ_AVAIL = 0x1823, 0x217B, 0x1223
ATTR_READ_POS = 0x1221
ATTR_WRITE_NUM_CHANS, ATTR_DO_BOOLS_PER_CHAN = 0x217E, 0x217F
ATTR_WRITE_REGEN, ATTR_WRITE_GENERATED, ATTR_WRITE_SPACE = 0x1453, 0x192B, 0x1460
ATTR_SAMP_CLK_RATE = 0x1344
ATTR_INPUT_BUF_SIZE, ATTR_OUTPUT_BUF_SIZE = 0x186C, 0x186D

DRIVER_VERSION = (24, 8, 0)
SERVICE_NAME = "nidaqmx_grpc.NiDAQmx"


MAX_CHUNK = 100_000  # samples the rig runs in one go (bounds memory when a reader lags)


def daq_error(code: int, message: str, samps_per_chan_read: int | None = None) -> DaqError:
    """Our typed error, with the sample count NI reports alongside a failed read."""
    err = error_for_code(message, code)
    err.samps_per_chan_read = samps_per_chan_read  # type: ignore[attr-defined]
    err.bare_message = message  # type: ignore[attr-defined]
    return err


def default_input_buffer(rate_hz: float) -> int:
    """NI's default continuous input buffer for a sample rate [samples per channel]."""
    if rate_hz <= 100:
        return 1_000
    if rate_hz <= 10_000:
        return 10_000
    if rate_hz <= 1_000_000:
        return 100_000
    return 1_000_000


# --- tasks and channels ---------------------------------------------------------------------
@dataclass
class SimChannel:
    name: str  # virtual channel name, as the client derives it
    kind: str  # "ai" | "ao" | "do"
    physical: list[str]  # canonical physical names (one, or several lines for a DO channel)
    min_v: float = -10.0
    max_v: float = 10.0


@dataclass
class SimTask:
    """One DAQmx task on the server, found by its session (task) name."""

    name: str
    channels: list[SimChannel] = field(default_factory=list)
    rate_hz: float | None = None  # None: on-demand (software-timed)
    clock_source: str = ""
    sample_mode: int = MODE_CONTINUOUS
    samps_per_chan: int = 0
    buffer_samples: int | None = None
    trigger_source: str = ""
    regen_mode: int = REGEN_ALLOW
    running: bool = False
    error: DaqError | None = None  # sticky asynchronous error (overflow, underflow)
    # AO: samples written and not yet generated, as (n_ch, k) chunks
    ao_chunks: list[np.ndarray] = field(default_factory=list)
    ao_queued: int = 0
    ao_written: int = 0
    ao_generated: int = 0
    ao_hold: np.ndarray | None = None  # last value generated, per channel (volts)

    @property
    def kind(self) -> str | None:
        return self.channels[0].kind if self.channels else None

    def kind_or_raise(self, wanted: str) -> None:
        if self.kind != wanted:
            have = self.kind or "no channels"
            raise daq_error(
                NO_CHANS_OF_GIVEN_TYPE if self.channels else NO_CHANS_IN_TASK,
                f"task {self.name!r} has {have}; this operation needs {wanted.upper()} channels",
            )

    def input_buffer(self) -> int:
        if self.buffer_samples is not None:
            return self.buffer_samples
        assert self.rate_hz is not None
        if self.sample_mode == MODE_FINITE:
            return max(self.samps_per_chan, 1)
        return max(self.samps_per_chan, default_input_buffer(self.rate_hz))

    def output_buffer(self) -> int:
        if self.buffer_samples is not None:
            return self.buffer_samples
        return max(self.samps_per_chan, 1)


class _AiRing:
    """The AI input buffer: the newest ``capacity`` samples per channel."""

    def __init__(self, n_ch: int, capacity: int) -> None:
        self.data = np.zeros((n_ch, capacity))
        self.capacity = capacity
        self.written = 0  # samples ever put in

    def put(self, block: np.ndarray) -> None:
        n = block.shape[1]
        keep = min(n, self.capacity)
        start = (self.written + n - keep) % self.capacity
        first = min(keep, self.capacity - start)
        self.data[:, start:start + first] = block[:, n - keep:n - keep + first]
        self.data[:, : keep - first] = block[:, n - keep + first:]
        self.written += n

    def grow(self, capacity: int) -> None:
        """Enlarge the buffer, keeping what it holds."""
        if capacity <= self.capacity:
            return
        held = min(self.written, self.capacity)
        old = self.get(self.written - held, held)
        self.data = np.zeros((self.data.shape[0], capacity))
        self.capacity, self.written = capacity, self.written - held
        self.put(old)

    def get(self, first: int, n: int) -> np.ndarray:
        start = first % self.capacity
        if start + n <= self.capacity:
            return self.data[:, start:start + n].copy()
        return self.data[:, np.arange(start, start + n) % self.capacity]


# --- the device -----------------------------------------------------------------------------
class SimDevice:
    """One simulated board and the rig wired to it. All methods hold the device lock briefly;
    waits for the clock happen outside it, so a relay can switch during a blocking read."""

    def __init__(
        self,
        wiring: ChannelMap,
        params: RigParams,
        seed: int = 0,
        fast: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        self.spec: DeviceSpec = wiring.device
        self.wiring = wiring
        self.params = params
        self.seed = seed
        self.fast = fast
        self._clock = clock
        self._stopping = threading.Event()
        self._sleep = sleep if sleep is not None else self._stopping.wait
        self.lock = threading.RLock()
        self.lines: dict[str, bool] = {}  # DO line states, by canonical physical name
        self.ao_hold: dict[str, float] = {}  # on-demand AO output values
        self._physical = self._physical_names()
        self._reset_acquisition()
        # load the compiled physics now, not during the first paced read (it takes ~0.5 s)
        RigModel(params, wiring, seed).process(np.zeros((len(wiring.ao), 16)))

    def _physical_names(self) -> dict[str, tuple[str, str]]:
        """lower-case physical name -> (canonical name, kind)."""
        names: dict[str, tuple[str, str]] = {}
        for kind, chans in (("ai", self.spec.ai_channels()), ("ao", self.spec.ao_channels()),
                            ("do", self.spec.do_lines())):
            for c in chans:
                names[c.lower()] = (c, kind)
        return names

    def _reset_acquisition(self) -> None:
        self.rig: RigModel | None = None
        self.ai_task: SimTask | None = None
        self.ao_tasks: list[SimTask] = []
        self.t0 = 0.0
        self.generated = 0  # samples taken since the AI start trigger
        self.read_pos = 0
        self.ring: _AiRing | None = None
        self._rows: list[int | None] = []  # per AI task channel: row in rig output or None
        self._ao_rows: list[list[tuple[int, int]]] = []  # per linked AO task: (task row, rig row)
        self._floating_rng = np.random.default_rng(self.seed + 1)

    def shutdown(self) -> None:
        self._stopping.set()

    # --- lookups --------------------------------------------------------------------------
    def physical(self, name: str, kind: str, where: str) -> list[str]:
        """Canonical physical names for a (possibly list or range) channel string."""
        try:
            parts = unflatten_channel_string(name)
        except Exception as err:  # nidaqmx raises DaqError for bad range syntax
            raise daq_error(PHYSICAL_CHAN_DOES_NOT_EXIST, f"{where}: {err}") from None
        if not parts:
            raise daq_error(PHYSICAL_CHAN_DOES_NOT_EXIST, f"{where}: no physical channel given")
        out = []
        for part in parts:
            dev = part.split("/", 1)[0]
            if dev.lower() != self.spec.name.lower():
                raise daq_error(
                    DEVICE_NOT_FOUND,
                    f"{where}: device {dev!r} in {part!r} does not exist "
                    f"(this server has {self.spec.name})",
                )
            found = self._physical.get(part.lower())
            if found is None or found[1] != kind:
                have = {"ai": "ai0..ai", "ao": "ao0..ao", "do": "port0/line0.."}[kind]
                count = {"ai": self.spec.ai_count, "ao": self.spec.ao_count,
                         "do": self.spec.do_lines_per_port}[kind]
                raise daq_error(
                    PHYSICAL_CHAN_DOES_NOT_EXIST,
                    f"{where}: physical channel {part!r} does not exist on {self.spec.name} "
                    f"({self.spec.product}; {kind.upper()} channels are {have}{count - 1})",
                )
            out.append(found[0])
        return out

    def check_rate(self, rate_hz: float, where: str) -> None:
        if not math.isfinite(rate_hz) or rate_hz > self.spec.max_rate_hz:
            raise daq_error(
                SAMPLE_RATE_TOO_HIGH,
                f"{where}: sample rate {rate_hz:g} S/s is above the {self.spec.product} maximum "
                f"of {self.spec.max_rate_hz:g} S/s",
            )
        if rate_hz < self.spec.min_rate_hz:
            raise daq_error(
                SAMPLE_RATE_TOO_LOW,
                f"{where}: sample rate {rate_hz:g} S/s is below the {self.spec.product} minimum "
                f"of {self.spec.min_rate_hz:g} S/s",
            )

    def terminal(self, name: str) -> str:
        """The device's AI timing terminal, e.g. ``/Dev1/ai/SampleClock`` (compare lower-case)."""
        return f"/{self.spec.name}/ai/{name}"

    # --- start / stop ---------------------------------------------------------------------
    def start(self, task: SimTask, others: list[SimTask]) -> None:
        with self.lock:
            if task.running:
                return
            for other in others:
                if other is task or not other.running:
                    continue
                busy = {p for c in other.channels for p in c.physical}
                clash = busy & {p for c in task.channels for p in c.physical}
                if clash:
                    raise daq_error(
                        RESOURCE_RESERVED,
                        f"start {task.name!r}: {sorted(clash)} in use by running task "
                        f"{other.name!r}",
                    )
            if task.kind == "ai":
                self._start_ai(task)
            elif task.kind == "ao" and task.rate_hz is not None:
                self._arm_ao(task)
            elif task.kind is None:
                raise daq_error(NO_CHANS_IN_TASK, f"start {task.name!r}: the task has no channels")
            task.error = None
            task.running = True

    def _arm_ao(self, task: SimTask) -> None:
        if task.clock_source.lower() != self.terminal("SampleClock").lower():
            raise daq_error(
                ATTR_NOT_SUPPORTED,
                f"start {task.name!r}: the simulated {self.spec.name} generates hardware-timed "
                f"AO only on {self.terminal('SampleClock')} (got source "
                f"{task.clock_source or 'OnboardClock'!r})",
            )
        if task.regen_mode != REGEN_DONT_ALLOW:
            raise daq_error(
                ATTR_NOT_SUPPORTED,
                f"start {task.name!r}: the simulated {self.spec.name} supports only "
                "non-regenerating AO (set out_stream.regen_mode = DONT_ALLOW_REGENERATION)",
            )
        if self.ai_task is not None:
            raise daq_error(
                RESOURCE_RESERVED,
                f"start {task.name!r}: AI task {self.ai_task.name!r} is already running, so "
                "its start trigger has passed; start AO first",
            )
        task.ao_generated = 0
        self.ao_tasks.append(task)

    def _start_ai(self, task: SimTask) -> None:
        if task.rate_hz is None:
            raise daq_error(
                ATTR_NOT_SUPPORTED,
                f"start {task.name!r}: the simulated {self.spec.name} supports only "
                "hardware-timed AI; call cfg_samp_clk_timing first",
            )
        if self.ai_task is not None:
            raise daq_error(
                RESOURCE_RESERVED,
                f"start {task.name!r}: the AI timing engine is in use by task "
                f"{self.ai_task.name!r}",
            )
        wired_ai = {c.physical_channel: c for c in self.wiring.ai}
        ai: list[AnalogInput] = []
        self._rows = []
        for ch in task.channels:
            w = wired_ai.get(ch.physical[0])
            if w is None:
                self._rows.append(None)  # an unwired terminal: floating input
                continue
            self._rows.append(len(ai))
            ai.append(w.model_copy(update={"range_v": (ch.min_v, ch.max_v)}))
        # the rig sees every wired shaker; a linked AO task drives the ones on its channels
        wired_ao = [c.physical_channel for c in self.wiring.ao]
        self._ao_rows = [
            [(row, wired_ao.index(ch.physical[0])) for row, ch in enumerate(t.channels)
             if ch.physical[0] in wired_ao]
            for t in self.ao_tasks
        ]
        try:
            rig_map = ChannelMap(device=self.spec, sample_rate_hz=task.rate_hz, ai=tuple(ai),
                                 ao=self.wiring.ao, do=self.wiring.do)
        except ValueError as err:
            raise daq_error(INVALID_ATTRIBUTE_VALUE, f"start {task.name!r}: {err}") from None
        self.rig = RigModel(self.params, rig_map, self.seed)
        for d in self.wiring.do:
            if self.lines.get(d.physical_channel):
                self.rig.set_relay(d.name, True)
        self.ai_task = task
        self.ring = _AiRing(len(task.channels), task.input_buffer())
        self.generated = self.read_pos = 0
        self.t0 = self._clock()

    def stop(self, task: SimTask) -> None:
        """Stop ``task``; its pending samples and its error go (it can be restarted)."""
        with self.lock:
            task.running = False
            task.error = None
            if task is self.ai_task:
                for ao_task in self.ao_tasks:
                    ao_task.running = False
                self._reset_acquisition()
            elif task in self.ao_tasks:
                idx = self.ao_tasks.index(task)
                self.ao_tasks.pop(idx)
                if self._ao_rows:
                    self._ao_rows.pop(idx)
            task.ao_chunks, task.ao_queued = [], 0

    # --- the clock ------------------------------------------------------------------------
    def _due(self) -> int:
        """Samples the AI clock has produced by now (paced mode)."""
        return int((self._clock() - self.t0) * self.ai_rate)

    @property
    def ai_rate(self) -> float:
        assert self.ai_task is not None and self.ai_task.rate_hz is not None
        return self.ai_task.rate_hz

    def catch_up(self) -> None:
        """Run the rig up to the present (paced mode); no-op in fast mode or when idle."""
        with self.lock:
            if self.ai_task is not None and not self.fast:
                self._advance(self._due())

    def _advance(self, target: int) -> None:
        """Take samples ``generated..target``: consume AO, run the rig, fill the AI buffer."""
        task, ring, rig = self.ai_task, self.ring, self.rig
        assert task is not None and ring is not None and rig is not None
        if task.error is not None:  # overwritten: the acquisition is dead until restarted
            self.generated = max(self.generated, target)
            return
        while self.generated < target:
            n = min(target - self.generated, MAX_CHUNK)
            hold = [self.ao_hold.get(c.physical_channel, 0.0) for c in self.wiring.ao]
            drive = np.repeat(np.array(hold)[:, None], n, axis=1)
            for ao_task, pairs in zip(self.ao_tasks, self._ao_rows, strict=True):
                block = self._take_ao(ao_task, n)
                for row, rig_row in pairs:
                    drive[rig_row] = block[row]
            wired = rig.process(drive)
            out = np.empty((len(self._rows), n))
            lsb = 2 * self.spec.ai_range_v / 2**self.spec.ai_bits
            for i, wired_row in enumerate(self._rows):
                if wired_row is None:
                    out[i] = np.round(self._floating_rng.normal(0.0, lsb, n) / lsb) * lsb
                else:
                    out[i] = wired[wired_row]
            self.generated += n
            ring.put(out)
            behind = self.generated - self.read_pos
            if behind > ring.capacity and task.error is None:
                task.error = daq_error(
                    INPUT_BUFFER_OVERWRITTEN,
                    f"task {task.name!r}: the reader fell {behind} samples behind the "
                    f"acquisition; the input buffer holds {ring.capacity} (samples "
                    f"{self.read_pos}..{self.generated - ring.capacity - 1} were overwritten)",
                    samps_per_chan_read=0,
                )

    def _take_ao(self, task: SimTask, n: int) -> np.ndarray:
        """The next ``n`` AO samples; past the end of the data, hold the last value and flag
        the underflow on the task (NI stops the generation at this point)."""
        n_ch = len(task.channels)
        if task.ao_hold is None:
            task.ao_hold = np.zeros(n_ch)
        out = np.empty((n_ch, n))
        got = 0
        while got < n and task.ao_chunks:
            chunk = task.ao_chunks[0]
            take = min(n - got, chunk.shape[1])
            out[:, got:got + take] = chunk[:, :take]
            if take == chunk.shape[1]:
                task.ao_chunks.pop(0)
            else:
                task.ao_chunks[0] = chunk[:, take:]
            got += take
        task.ao_queued -= got
        task.ao_generated += got
        if got:
            task.ao_hold = out[:, got - 1].copy()
        if got < n:
            out[:, got:] = task.ao_hold[:, None]
            if task.error is None:
                task.error = daq_error(
                    OUTPUT_UNDERFLOW,
                    f"task {task.name!r}: the AO generation reached sample "
                    f"{task.ao_generated} but only {task.ao_written} samples were written; "
                    "the outputs hold their last value",
                )
        return out

    # --- reading --------------------------------------------------------------------------
    def read(self, task: SimTask, n: int, timeout_s: float) -> np.ndarray:
        """The next ``n`` samples of the running AI task, shape (n_ch, n)."""
        with self.lock:
            if task is not self.ai_task or not task.running:
                raise daq_error(
                    TASK_NOT_RUNNING,
                    f"read from {task.name!r}: the task is not running; start it first",
                    samps_per_chan_read=0,
                )
            if task.error is not None:
                raise task.error
            if n < 0:  # DAQmx_Val_Auto / read all available
                self.catch_up()
                n = self.generated - self.read_pos
            need = self.read_pos + n
            if task.sample_mode == MODE_FINITE and need > task.samps_per_chan:
                raise daq_error(
                    READ_TIMEOUT,
                    f"read from {task.name!r}: asked for samples past the end of the finite "
                    f"acquisition ({task.samps_per_chan} samples)",
                    samps_per_chan_read=0,
                )
            assert self.ring is not None
            self.ring.grow(n)  # a read larger than the buffer enlarges it
            if not self.fast:
                ready_at = self.t0 + need / self.ai_rate
        if not self.fast:
            self._wait_until(ready_at, timeout_s, task, n)
        with self.lock:
            if task is not self.ai_task:
                raise daq_error(TASK_NOT_RUNNING, f"read from {task.name!r}: task stopped "
                                "while waiting", samps_per_chan_read=0)
            self._advance(need if self.fast else max(need, self._due()))
            if task.error is not None:
                raise task.error
            assert self.ring is not None
            data = self.ring.get(self.read_pos, n)
            self.read_pos = need
            return data

    def _wait_until(self, ready_at: float, timeout_s: float, task: SimTask, n: int) -> None:
        now = self._clock()
        deadline = math.inf if timeout_s < 0 else now + timeout_s
        if ready_at > deadline:
            self._sleep(max(0.0, deadline - now))
            self.catch_up()
            raise daq_error(
                READ_TIMEOUT,
                f"read of {n} samples from {task.name!r} timed out after {timeout_s:g} s "
                f"({self.generated - self.read_pos} available; none were consumed)",
                samps_per_chan_read=0,
            )
        while now < ready_at and not self._stopping.is_set():
            self._sleep(ready_at - now)
            now = self._clock()

    def available(self, task: SimTask) -> int:
        with self.lock:
            if task is not self.ai_task:
                return 0
            self.catch_up()
            return self.generated - self.read_pos

    # --- writing --------------------------------------------------------------------------
    def write_ao(self, task: SimTask, block: np.ndarray, auto_start: bool, timeout_s: float,
                 others: list[SimTask]) -> int:
        for row, ch in enumerate(task.channels):
            if block.size and (block[row].min() < ch.min_v or block[row].max() > ch.max_v):
                raise daq_error(
                    INVALID_AO_DATA_WRITE,
                    f"write to {task.name!r}: channel {ch.name} ({ch.physical[0]}) sample "
                    f"range [{block[row].min():g}, {block[row].max():g}] V is outside its range "
                    f"[{ch.min_v:g}, {ch.max_v:g}] V",
                )
        if task.rate_hz is None:  # on-demand: the outputs take the last value at once
            if not task.running and not auto_start:
                raise daq_error(TASK_NOT_RUNNING, f"write to {task.name!r}: task not running")
            with self.lock:
                self.catch_up()
                for row, ch in enumerate(task.channels):
                    self.ao_hold[ch.physical[0]] = float(block[row, -1])
            return block.shape[1]
        n = block.shape[1]
        deadline = self._clock() + (math.inf if timeout_s < 0 else timeout_s)
        while True:
            with self.lock:
                self.catch_up()
                if task.error is not None:
                    raise task.error
                space = task.output_buffer() - task.ao_queued
                if not task.running and task.ao_written == 0:
                    space = max(space, n)  # the first write sizes the buffer (NI behaviour)
                if n <= space:
                    task.ao_chunks.append(block.copy())
                    task.ao_queued += n
                    task.ao_written += n
                    if task.buffer_samples is None and not task.running:
                        task.buffer_samples = max(task.output_buffer(), task.ao_queued)
                    break
                linked = task in self.ao_tasks and self.ai_task is not None
            now = self._clock()
            if self.fast or not linked or now >= deadline:
                raise daq_error(
                    SAMPLES_CAN_NOT_YET_BE_WRITTEN,
                    f"write of {n} samples to {task.name!r}: only {max(space, 0)} of "
                    f"{task.output_buffer()} buffer samples free after {timeout_s:g} s",
                )
            self._sleep(min(deadline - now, (n - space) / self.ai_rate))
        if auto_start and not task.running:
            self.start(task, others)
        return n

    def write_lines(self, lines: list[str], values: list[bool]) -> None:
        with self.lock:
            self.catch_up()  # the relay switches at this instant of the acquisition
            for line, value in zip(lines, values, strict=True):
                self.lines[line] = value
                for d in self.wiring.do:
                    if d.physical_channel == line and self.rig is not None:
                        self.rig.set_relay(d.name, value)

    def generated_by(self, task: SimTask) -> int:
        with self.lock:
            self.catch_up()
            return task.ao_generated


# --- the servicer ---------------------------------------------------------------------------
def _bare_message(err: DaqError) -> str:
    return getattr(err, "bare_message", None) or str(err)


def _reports_daq_errors(method: Callable[..., Any]) -> Callable[..., Any]:
    """The one place where our `DaqError` becomes NI's wire format: status UNKNOWN, trailing
    metadata ``ni-error`` (and ``ni-samps-per-chan-read`` for reads)."""

    @functools.wraps(method)
    def wrapper(self: SimulatedDaqmxServicer, request: Any, context: grpc.ServicerContext) -> Any:
        try:
            return method(self, request, context)
        except DaqError as err:
            metadata = [("ni-error", str(err.code or UNKNOWN_ERROR))]
            samps = getattr(err, "samps_per_chan_read", None)
            if samps is not None:
                metadata.append(("ni-samps-per-chan-read", str(samps)))
            context.set_trailing_metadata(metadata)
            context.abort(grpc.StatusCode.UNKNOWN, _bare_message(err))

    return wrapper


def _chan_handler(kind: str, channel_field: str, name_field: str) -> Callable[..., Any]:
    """One handler for the whole Create*Chan family: the request names the physical channel(s),
    the virtual name and (for analog channels) the range in volts."""

    @_reports_daq_errors
    def handler(self: SimulatedDaqmxServicer, request: Any, context: grpc.ServicerContext) -> Any:
        task = self._task(request.task)
        rpc = type(request).__name__.removesuffix("Request")
        where = f"{rpc} on task {task.name!r}"
        if task.running:
            raise daq_error(ATTR_NOT_SUPPORTED, f"{where}: cannot add channels to a running task")
        if task.kind not in (None, kind):
            raise daq_error(
                ATTR_NOT_SUPPORTED,
                f"{where}: task already has {task.kind.upper()} channels; use one task per type",
            )
        physical = self.device.physical(getattr(request, channel_field), kind, where)
        used = {p for c in task.channels for p in c.physical}
        repeated = sorted(used & set(physical))
        if repeated:
            raise daq_error(REPEATED_PHYSICAL_CHAN, f"{where}: {repeated} already in this task")
        name = getattr(request, name_field)
        if kind == "do" and request.line_grouping_raw == LINES_PER_CHAN_ALL:
            groups = [physical]
        else:
            groups = [[p] for p in physical]
        if name and len(groups) > 1:
            names = [f"{name}{i}" for i in range(len(groups))]
        elif name:
            names = [name]
        else:
            names = [g[0] if len(g) == 1 else ",".join(g) for g in groups]
        lo, hi = (request.min_val, request.max_val) if kind != "do" else (0.0, 1.0)
        if kind != "do":
            limit = self.device.spec.ai_range_v if kind == "ai" else self.device.spec.ao_range_v
            if not (-limit <= lo < hi <= limit):
                raise daq_error(
                    INVALID_ATTRIBUTE_VALUE,
                    f"{where}: range [{lo:g}, {hi:g}] V for {physical} is not within the "
                    f"device's +/-{limit:g} V (or min >= max)",
                )
        for n, g in zip(names, groups, strict=True):
            task.channels.append(SimChannel(n, kind, g, lo, hi))
        return type(self)._responses[rpc](status=0)

    return handler


# Which Create*Chan RPCs the simulated device serves: rpc -> (kind, channel field, name field).
CREATE_CHAN_RPCS: dict[str, tuple[str, str, str]] = {
    "CreateAIVoltageChan": ("ai", "physical_channel", "name_to_assign_to_channel"),
    "CreateAOVoltageChan": ("ao", "physical_channel", "name_to_assign_to_channel"),
    "CreateDOChan": ("do", "lines", "name_to_assign_to_lines"),
}


class SimulatedDaqmxServicer(pb_grpc.NiDAQmxServicer):
    """The NI-DAQmx gRPC service on a `SimDevice`. RPCs not defined here answer UNIMPLEMENTED
    (the base class), which the client reports as ``nidaqmx.errors.RpcError``."""

    _responses = {rpc: getattr(pb, f"{rpc}Response") for rpc in CREATE_CHAN_RPCS}

    def __init__(self, device: SimDevice) -> None:
        self.device = device
        self.tasks: dict[str, SimTask] = {}
        self._unnamed = itertools.count()
        self._tasks_lock = threading.Lock()

    # --- helpers --------------------------------------------------------------------------
    def _task(self, session: Session) -> SimTask:
        task = self.tasks.get(session.name)
        if task is None:
            raise daq_error(INVALID_TASK, f"task {session.name!r} does not exist on this server")
        return task

    def _others(self) -> list[SimTask]:
        return list(self.tasks.values())

    def reset(self) -> None:
        """Stop and clear every task; relays off (as ResetDevice does)."""
        with self._tasks_lock:
            for task in list(self.tasks.values()):
                self.device.stop(task)
            self.tasks.clear()
        with self.device.lock:
            self.device.lines.clear()
            self.device.ao_hold.clear()

    # --- session and version --------------------------------------------------------------
    @_reports_daq_errors
    def GetSystemInfoAttributeUInt32(self, request, context):  # noqa: N802
        versions = dict(zip((ATTR_DRIVER_MAJOR, ATTR_DRIVER_MINOR, ATTR_DRIVER_UPDATE),
                            DRIVER_VERSION, strict=True))
        if request.attribute_raw not in versions:
            raise _unsupported("system", request.attribute_raw)
        return pb.GetSystemInfoAttributeUInt32Response(value=versions[request.attribute_raw])

    @_reports_daq_errors
    def GetSystemInfoAttributeString(self, request, context):  # noqa: N802
        if request.attribute_raw != ATTR_SYS_DEVICES:
            raise _unsupported("system", request.attribute_raw)
        return pb.GetSystemInfoAttributeStringResponse(value=self.device.spec.name)

    @_reports_daq_errors
    def CreateTask(self, request, context):  # noqa: N802
        with self._tasks_lock:
            name = request.session_name or f"_unnamedTask<{next(self._unnamed)}>"
            behaviour = request.initialization_behavior
            existing = self.tasks.get(name)
            if existing is not None:
                if behaviour == INIT_NEW:
                    raise daq_error(DUPLICATE_TASK, f"task {name!r} already exists")
                return pb.CreateTaskResponse(task=Session(name=name),
                                             new_session_initialized=False)
            if behaviour == INIT_ATTACH:
                raise daq_error(INVALID_TASK, f"no task {name!r} to attach to")
            self.tasks[name] = SimTask(name)
            return pb.CreateTaskResponse(task=Session(name=name), new_session_initialized=True)

    @_reports_daq_errors
    def ClearTask(self, request, context):  # noqa: N802
        with self._tasks_lock:
            task = self.tasks.pop(request.task.name, None)
        if task is None:
            raise daq_error(INVALID_TASK, f"task {request.task.name!r} does not exist")
        self.device.stop(task)
        return pb.ClearTaskResponse(status=0)

    @_reports_daq_errors
    def StartTask(self, request, context):  # noqa: N802
        self.device.start(self._task(request.task), self._others())
        return pb.StartTaskResponse(status=0)

    @_reports_daq_errors
    def StopTask(self, request, context):  # noqa: N802
        self.device.stop(self._task(request.task))
        return pb.StopTaskResponse(status=0)

    @_reports_daq_errors
    def ResetDevice(self, request, context):  # noqa: N802
        if request.device_name.lower() != self.device.spec.name.lower():
            raise daq_error(DEVICE_NOT_FOUND, f"reset: no device {request.device_name!r}")
        self.reset()
        return pb.ResetDeviceResponse(status=0)

    @_reports_daq_errors
    def GetErrorString(self, request, context):  # noqa: N802
        text = _ERROR_TEXT.get(request.error_code, f"NI-DAQmx status {request.error_code}")
        return pb.GetErrorStringResponse(error_string=text)

    # --- timing and triggers --------------------------------------------------------------
    @_reports_daq_errors
    def CfgSampClkTiming(self, request, context):  # noqa: N802
        task = self._task(request.task)
        where = f"CfgSampClkTiming on task {task.name!r}"
        self.device.check_rate(request.rate, where)
        source = request.source
        clock = self.device.terminal("SampleClock").lower()
        if source and source.lower() not in ("onboardclock", clock):
            raise daq_error(
                INVALID_ROUTING_SOURCE,
                f"{where}: sample clock source {source!r} is not available on the simulated "
                f"{self.device.spec.name} (use OnboardClock or "
                f"{self.device.terminal('SampleClock')})",
            )
        if request.sample_mode_raw not in (MODE_CONTINUOUS, MODE_FINITE):
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"{where}: sample mode {request.sample_mode_raw} not supported")
        task.rate_hz = request.rate
        task.clock_source = "" if source.lower() == "onboardclock" else source
        task.sample_mode = request.sample_mode_raw
        task.samps_per_chan = int(request.samps_per_chan)
        return pb.CfgSampClkTimingResponse(status=0)

    @_reports_daq_errors
    def CfgDigEdgeStartTrig(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.trigger_source.lower() != self.device.terminal("StartTrigger").lower():
            raise daq_error(
                INVALID_ROUTING_SOURCE,
                f"CfgDigEdgeStartTrig on task {task.name!r}: trigger source "
                f"{request.trigger_source!r} is not available on the simulated "
                f"{self.device.spec.name} (use {self.device.terminal('StartTrigger')})",
            )
        task.trigger_source = request.trigger_source
        return pb.CfgDigEdgeStartTrigResponse(status=0)

    @_reports_daq_errors
    def CfgInputBuffer(self, request, context):  # noqa: N802
        self._task(request.task).buffer_samples = int(request.num_samps_per_chan)
        return pb.CfgInputBufferResponse(status=0)

    @_reports_daq_errors
    def CfgOutputBuffer(self, request, context):  # noqa: N802
        self._task(request.task).buffer_samples = int(request.num_samps_per_chan)
        return pb.CfgOutputBufferResponse(status=0)

    # --- attributes -----------------------------------------------------------------------
    @_reports_daq_errors
    def GetTaskAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_TASK_NAME:
            return pb.GetTaskAttributeStringResponse(value=task.name)
        if request.attribute_raw == ATTR_TASK_CHANNELS:
            return pb.GetTaskAttributeStringResponse(value=_channel_list(task))
        raise _unsupported("task", request.attribute_raw)

    @_reports_daq_errors
    def GetTaskAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_TASK_NUM_CHANS:
            raise _unsupported("task", request.attribute_raw)
        return pb.GetTaskAttributeUInt32Response(value=len(task.channels))

    @_reports_daq_errors
    def GetChanAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        types = {"ai": CHAN_AI, "ao": CHAN_AO, "do": CHAN_DO}
        attr = request.attribute_raw
        values = set()
        for ch in _find_channels(task, request.channel):
            if attr == ATTR_CHAN_TYPE:
                values.add(types[ch.kind])
            elif (attr == ATTR_AI_MEAS_TYPE and ch.kind == "ai") or (
                    attr == ATTR_AO_OUTPUT_TYPE and ch.kind == "ao"):
                values.add(MEAS_VOLTAGE)
            else:
                raise _unsupported("channel", attr)
        if len(values) != 1:
            raise daq_error(ATTR_INCONSISTENT,
                            f"channel attribute 0x{attr:04X} differs across {request.channel!r}")
        return pb.GetChanAttributeInt32Response(value_raw=values.pop())

    @_reports_daq_errors
    def GetReadAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_READ_CHANNELS:
            raise _unsupported("read", request.attribute_raw)
        return pb.GetReadAttributeStringResponse(value=_channel_list(task))

    @_reports_daq_errors
    def GetReadAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_READ_NUM_CHANS:
            value = len(task.channels)
        elif request.attribute_raw == ATTR_READ_AVAIL:
            value = self.device.available(task)
        else:
            raise _unsupported("read", request.attribute_raw)
        return pb.GetReadAttributeUInt32Response(value=value)

    @_reports_daq_errors
    def GetReadAttributeUInt64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_READ_POS:
            raise _unsupported("read", request.attribute_raw)
        with self.device.lock:
            value = self.device.read_pos if task is self.device.ai_task else 0
        return pb.GetReadAttributeUInt64Response(value=value)

    @_reports_daq_errors
    def GetWriteAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        attr = request.attribute_raw
        if attr == ATTR_WRITE_NUM_CHANS:
            value = len(task.channels)
        elif attr == ATTR_DO_BOOLS_PER_CHAN:
            value = max((len(c.physical) for c in task.channels), default=0)
        elif attr == ATTR_WRITE_SPACE:
            self.device.catch_up()
            value = max(task.output_buffer() - task.ao_queued, 0)
        else:
            raise _unsupported("write", attr)
        return pb.GetWriteAttributeUInt32Response(value=value)

    @_reports_daq_errors
    def GetWriteAttributeUInt64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_WRITE_GENERATED:
            raise _unsupported("write", request.attribute_raw)
        return pb.GetWriteAttributeUInt64Response(value=self.device.generated_by(task))

    @_reports_daq_errors
    def GetWriteAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_WRITE_REGEN:
            raise _unsupported("write", request.attribute_raw)
        return pb.GetWriteAttributeInt32Response(value_raw=task.regen_mode)

    @_reports_daq_errors
    def SetWriteAttributeInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_WRITE_REGEN:
            raise _unsupported("write", request.attribute_raw)
        if request.value_raw not in (REGEN_ALLOW, REGEN_DONT_ALLOW):
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"regeneration mode {request.value_raw} is not a valid value")
        task.regen_mode = request.value_raw
        return pb.SetWriteAttributeInt32Response(status=0)

    @_reports_daq_errors
    def GetTimingAttributeDouble(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_SAMP_CLK_RATE or task.rate_hz is None:
            raise _unsupported("timing", request.attribute_raw)
        return pb.GetTimingAttributeDoubleResponse(value=task.rate_hz)

    @_reports_daq_errors
    def GetBufferAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw == ATTR_INPUT_BUF_SIZE and task.rate_hz is not None:
            value = task.input_buffer()
        elif request.attribute_raw == ATTR_OUTPUT_BUF_SIZE:
            value = task.output_buffer()
        else:
            raise _unsupported("buffer", request.attribute_raw)
        return pb.GetBufferAttributeUInt32Response(value=value)

    @_reports_daq_errors
    def SetBufferAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw not in (ATTR_INPUT_BUF_SIZE, ATTR_OUTPUT_BUF_SIZE):
            raise _unsupported("buffer", request.attribute_raw)
        task.buffer_samples = int(request.value)
        return pb.SetBufferAttributeUInt32Response(status=0)

    # --- data -----------------------------------------------------------------------------
    @_reports_daq_errors
    def ReadAnalogF64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ai")
        n = request.num_samps_per_chan
        n_ch = len(task.channels)
        if n >= 0 and request.array_size_in_samps < n * n_ch:
            raise daq_error(
                READ_BUFFER_TOO_SMALL,
                f"read of {n} samples x {n_ch} channels from {task.name!r}: the client buffer "
                f"holds only {request.array_size_in_samps} samples",
                samps_per_chan_read=0,
            )
        data = self.device.read(task, n, request.timeout)
        samps = data.shape[1]
        if request.fill_mode_raw != FILL_GROUP_BY_CHANNEL:
            data = data.T
        return _read_reply(data, samps)  # bytes: see SimulatedDeviceServer

    @_reports_daq_errors
    def WriteAnalogF64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ao")
        n, n_ch = request.num_samps_per_chan, len(task.channels)
        flat = np.asarray(request.write_array, dtype=np.float64)
        if n <= 0 or flat.size != n * n_ch:
            raise daq_error(
                WRITE_NUM_CHANS_MISMATCH,
                f"write to {task.name!r}: {flat.size} values for {n} samples x {n_ch} channels",
            )
        block = (flat.reshape(n_ch, n) if request.data_layout_raw == FILL_GROUP_BY_CHANNEL
                 else flat.reshape(n, n_ch).T)
        written = self.device.write_ao(task, block, request.auto_start, request.timeout,
                                       self._others())
        return pb.WriteAnalogF64Response(samps_per_chan_written=written)

    @_reports_daq_errors
    def WriteDigitalLines(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("do")
        if not task.running:
            if not request.auto_start:
                raise daq_error(TASK_NOT_RUNNING, f"write to {task.name!r}: task not running")
            self.device.start(task, self._others())
        n = request.num_samps_per_chan
        raw = np.frombuffer(request.write_array, dtype=np.uint8)
        lines = [p for c in task.channels for p in c.physical]
        if n <= 0 or raw.size != n * len(lines):
            raise daq_error(
                WRITE_NUM_CHANS_MISMATCH,
                f"write to {task.name!r}: {raw.size} line values for {n} samples x "
                f"{len(lines)} lines",
            )
        # software-timed: only the last sample stays on the lines
        if request.data_layout_raw == FILL_GROUP_BY_CHANNEL:
            last: list[int] = []
            pos = 0
            for c in task.channels:
                k = len(c.physical)
                last.extend(raw[pos + (n - 1) * k: pos + n * k])
                pos += n * k
        else:
            last = list(raw[(n - 1) * len(lines):])
        self.device.write_lines(lines, [bool(v) for v in last])
        return pb.WriteDigitalLinesResponse(samps_per_chan_written=n)


for _rpc, (_kind, _chan_field, _name_field) in CREATE_CHAN_RPCS.items():
    setattr(SimulatedDaqmxServicer, _rpc, _chan_handler(_kind, _chan_field, _name_field))


def _unsupported(group: str, attribute: int) -> DaqError:
    return daq_error(
        ATTR_NOT_SUPPORTED,
        f"{group} attribute 0x{attribute:04X} is not supported by the simulated device",
    )


def _channel_list(task: SimTask) -> str:
    return ", ".join(c.name for c in task.channels)


def _find_channels(task: SimTask, names: str) -> list[SimChannel]:
    """The task's channels named in a channel string ("a, b", "probe0:2"; "" is all)."""
    if not names:
        return list(task.channels)
    found = []
    for name in unflatten_channel_string(names):
        for ch in task.channels:
            physical = ch.physical[0].lower() if len(ch.physical) == 1 else None
            if name in (ch.name, physical) or physical == name.lower():
                found.append(ch)
                break
        else:
            raise daq_error(
                PHYSICAL_CHAN_DOES_NOT_EXIST,
                f"task {task.name!r} has no channel {name!r} (has {_channel_list(task)})",
            )
    return found


_READ_ARRAY_TAG = b"\x12"  # field 2 (read_array), wire type 2 (packed)
_SAMPS_READ_TAG = b"\x18"  # field 3 (samps_per_chan_read), varint


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _read_reply(data: np.ndarray, samps_per_chan: int) -> bytes:
    """The serialized ``ReadAnalogF64Response``, encoded straight from numpy: status 0 (the
    default, omitted), packed ``read_array``, ``samps_per_chan_read``. Building the message
    field by field costs ~40-100 ns per sample, more than the rest of the read."""
    payload = np.ascontiguousarray(data, dtype="<f8").tobytes()
    return (_READ_ARRAY_TAG + _varint(len(payload)) + payload
            + _SAMPS_READ_TAG + _varint(samps_per_chan))


def _serialize(reply: bytes | Any) -> bytes:
    return reply if isinstance(reply, bytes) else reply.SerializeToString()


# --- the server -----------------------------------------------------------------------------
class SimulatedDeviceServer:
    """A gRPC server on ``host:port`` (port 0: any free port) serving one `SimDevice`.

    Use as a context manager, or ``start()`` / ``stop()``. ``address`` is ``"host:port"``.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        params: RigParams | None = None,
        seed: int = 0,
        fast: bool = False,
        wiring: ChannelMap | None = None,
        max_message_bytes: int = 256 * 1024 * 1024,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] | None = None,
        max_workers: int = 8,
    ) -> None:
        self.device = SimDevice(wiring or default_channel_map(), params or RigParams(), seed,
                                fast, clock, sleep)
        self.servicer = SimulatedDaqmxServicer(self.device)
        options = [("grpc.max_send_message_length", max_message_bytes),
                   ("grpc.max_receive_message_length", max_message_bytes),
                   ("grpc.so_reuseport", 0)]
        self._executor = futures.ThreadPoolExecutor(max_workers=max_workers,
                                                    thread_name_prefix="sim-daqmx")
        self._server = grpc.server(self._executor, options=options)
        # ReadAnalogF64 answers with pre-encoded bytes (`_read_reply`); this handler, added
        # before the package's, passes them through. Every other RPC is the package's.
        raw_reads = grpc.method_handlers_generic_handler(SERVICE_NAME, {
            "ReadAnalogF64": grpc.unary_unary_rpc_method_handler(
                self.servicer.ReadAnalogF64,
                request_deserializer=pb.ReadAnalogF64Request.FromString,
                response_serializer=_serialize,
            ),
        })
        self._server.add_generic_rpc_handlers((raw_reads,))
        pb_grpc.add_NiDAQmxServicer_to_server(self.servicer, self._server)
        self.host = host
        self.port = self._server.add_insecure_port(f"{host}:{port}")
        if self.port == 0:
            raise OSError(f"cannot bind the simulated device server to {host}:{port}")

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def start(self) -> SimulatedDeviceServer:
        self._server.start()
        _log.info("simulated NI-DAQmx device server on %s", self.address)
        return self

    def stop(self, grace_s: float | None = 1.0) -> None:
        self.device.shutdown()
        self._server.stop(grace_s).wait()
        self._executor.shutdown(wait=True)

    def wait(self) -> None:
        self._server.wait_for_termination()

    def reset(self) -> None:
        """Clear every task on the server (a fresh device, as after ResetDevice)."""
        self.servicer.reset()

    def __enter__(self) -> SimulatedDeviceServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
