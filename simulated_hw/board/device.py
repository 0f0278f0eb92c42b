"""`SimDevice`: one simulated board, its clock, and the rig wired to it."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np
from nidaqmx.utils import unflatten_channel_string

from daq.channels import AnalogInput, ChannelMap, DeviceSpec
from daq.errors import (
    DEVICE_NOT_FOUND,
    INPUT_BUFFER_OVERWRITTEN,
    INVALID_ATTRIBUTE_VALUE,
    OUTPUT_UNDERFLOW,
    READ_TIMEOUT,
    RESOURCE_RESERVED,
    SAMPLE_RATE_TOO_HIGH,
)
from simulated_hw.board.codes import (
    ATTR_NOT_SUPPORTED,
    INVALID_AO_DATA_WRITE,
    MAX_CHUNK,
    MODE_FINITE,
    NO_CHANS_IN_TASK,
    PHYSICAL_CHAN_DOES_NOT_EXIST,
    REGEN_DONT_ALLOW,
    SAMPLE_RATE_TOO_LOW,
    SAMPLES_CAN_NOT_YET_BE_WRITTEN,
    TASK_NOT_RUNNING,
    daq_error,
)
from simulated_hw.board.tasks import AiRing, SimTask
from simulated_hw.params import RigParams
from simulated_hw.rig import RigModel

_log = logging.getLogger(__name__)


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
        self.ring: AiRing | None = None
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
        self.ring = AiRing(len(task.channels), task.input_buffer())
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
