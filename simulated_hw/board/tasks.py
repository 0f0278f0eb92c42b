"""The simulated board's tasks and channels, and its AI input buffer."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from daq.errors import DaqError
from simulated_hw.board.ao_generation import AoStream
from simulated_hw.board.codes import (
    IDLE_MAINTAIN,
    MODE_CONTINUOUS,
    MODE_FINITE,
    NO_CHANS_IN_TASK,
    NO_CHANS_OF_GIVEN_TYPE,
    REGEN_ALLOW,
    WRITE_REL_CURR_POS,
    daq_error,
)


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
    kind: str  # "ai" | "ao" | "do" | "di" | "ci" | "co"
    physical: list[str]  # canonical physical names (one, or several lines for a DO channel)
    min_v: float = -10.0
    max_v: float = 10.0
    idle_behavior: int = IDLE_MAINTAIN  # AO: what the terminal does when no generation runs
    temperature_units: int | None = None  # AI thermocouple: read in these (TemperatureUnits)
    counter: Any = None  # CI/CO: its `simulated_hw.board.counters.Counter`


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
    write_relative_to: int = WRITE_REL_CURR_POS  # where a write starts: out_stream.relative_to
    write_offset: int = 0  # ... and the offset from there (out_stream.offset)
    onboard_samples: int | None = None  # AO: the on-board FIFO in use (None: the whole FIFO)
    running: bool = False
    error: DaqError | None = None  # sticky asynchronous error (overflow, underflow)
    ao: AoStream = field(default_factory=AoStream)  # AO/DO: the generation's samples
    done: bool = False  # a finite generation/acquisition has ended
    t_start: float | None = None  # AO on its own clock: device time of sample 0
    first_sample: int = 0  # AO on the AI clock: the AI sample its sample 0 is generated at
    wired_rows: list[tuple[int, int]] = field(default_factory=list)  # (task row, rig drive row)
    wired_slice: slice | None = None  # the terminals of ``wired_rows`` when they are in order
    auto_started: bool = False  # started implicitly by a read (stops at the end of a finite one)
    watchdog: Any = None  # a `simulated_hw.board.watchdog.Watchdog` for a watchdog task
    run_id: int = 0  # counts the task's starts (event streams restart their counts with it)
    di_read: int = 0  # hardware-timed DI: samples read since the start
    #: role ("start trigger", "reference trigger", "sample clock") -> the external line it is
    #: on: nothing on the rig drives those, so the task waits (`simulated_hw.board.triggers`)
    external: dict[str, str] = field(default_factory=dict)
    retriggerable: bool = False  # start trigger: a finite task rearms after each
    reserved: bool = False  # committed / reserved (TaskControl): its resources held until cleared
    sync_type: int = 10230  # DAQmx_Trigger_SyncType: None (10230), Master, Slave (skew only)
    tdms_log: Any = None  # AI: its `simulated_hw.board.tdms_logging.TdmsLog`, if it logs

    @property
    def kind(self) -> str | None:
        if self.watchdog is not None:
            return "watchdog"
        return self.channels[0].kind if self.channels else None

    @property
    def ao_generated(self) -> int:
        """AO/DO: samples generated since the start (DAQmx TotalSampPerChanGenerated)."""
        return self.ao.generated

    @property
    def finite(self) -> bool:
        return self.rate_hz is not None and self.sample_mode == MODE_FINITE

    @property
    def regenerating(self) -> bool:
        return self.regen_mode == REGEN_ALLOW

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


class AiRing:
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

    def skip(self, n: int) -> None:
        """Count ``n`` samples the reader took straight from the acquisition (never read from
        here: their place holds older samples)."""
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
