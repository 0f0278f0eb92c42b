"""The PXIe-6358's four counters (``Dev1/ctr0..3``) as they behave on this rig, where nothing is
wired to their inputs and their outputs drive nothing.

Counter input:
- count edges: nothing arrives, so an on-demand read is the initial count at once;
- frequency, period, pulse width, semi-period, two-edge separation, duty cycle and pulse
  (frequency, time, ticks) measurements: no edge arrives, so a read waits its timeout and ends
  as the board's does: on demand DAQmx -200474 (the operation timed out), buffered (implicit
  timing) -200284 (samples not yet acquired);
- an edge count sampled on the AI sample clock: the initial count at each AI sample, paced by
  it (-200284 past the timeout, e.g. before the AI task starts);
- a sample clock or terminal on a PFI line: accepted, and the task waits for ever
  (`simulated_hw.board.triggers`); other sample-clocked measurements, encoders, velocity and
  GPS are not simulated (-201380).

Counter output (pulses by frequency, time or ticks): the pulse times are coerced to whole ticks
of the fastest counter timebase (100 MHz, 20 MHz, 100 kHz) whose 32-bit count holds them, as
the board does. Without timing the task makes one pulse; with implicit timing a finite or
continuous train; buffered trains take written ``CtrFreq``/``CtrTime``/``CtrTick`` samples. A
finite generation is done (``is_task_done``, ``wait_until_done``, the done event) once its last
pulse has ended: initial delay + (N - 1) periods + the active time. The output terminal
(``co_pulse_term``) drives nothing on the rig.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb

from daq.errors import ATTR_NOT_SUPPORTED, ATTR_NOT_SUPPORTED_IN_TASK, INVALID_ATTRIBUTE_VALUE
from simulated_hw.board import triggers
from simulated_hw.board.codes import (
    DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION,
    DEVICE_NOT_FOUND,
    MODE_CONTINUOUS,
    MODE_FINITE,
    PHYSICAL_CHAN_DOES_NOT_EXIST,
    REPEATED_PHYSICAL_CHAN,
    WRITE_NUM_CHANS_MISMATCH,
    daq_error,
)
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.tasks import SimChannel, SimTask
from simulated_hw.board.wire import reports_daq_errors

COUNTERS = 4  # a PXIe-6358 has ctr0..ctr3
#: the counter timebases [Hz], fastest first: a pulse time is a whole number of ticks of the
#: fastest whose 32-bit count holds it
TIMEBASES_HZ = (100e6, 20e6, 100e3)
MIN_TICKS = 2  # the shortest high or low time the counter makes [ticks]
OPERATION_TIMED_OUT = -200474
READ_CHAN_TYPE_MISMATCH = -200525
CHAN_CI, CHAN_CO = 10131, 10132  # ChannelType

# UsageTypeCI / UsageTypeCO
CI_COUNT_EDGES, CI_FREQ, CI_PERIOD, CI_PULSE_WIDTH, CI_SEMI_PERIOD = 10125, 10179, 10256, 10359, \
    10289
CI_TWO_EDGE_SEP, CI_DUTY_CYCLE = 10267, 16070
CI_PULSE_FREQ, CI_PULSE_TIME, CI_PULSE_TICKS = 15864, 15865, 15866
CO_PULSE_TIME, CO_PULSE_FREQ, CO_PULSE_TICKS = 10269, 10119, 10268
LEVEL_HIGH = 10192

ATTR_CI_MEAS_TYPE, ATTR_CO_OUTPUT_TYPE = 0x18A0, 0x18B5
#: the terminal attributes (ci_count_edges_term, ci_freq_term, ..., co_pulse_term)
TERMINAL_ATTRS = {0x18C7, 0x18A2, 0x18A4, 0x2F04, 0x2F0C, 0x2F14, 0x18AA, 0x18B0, 0x308D,
                  0x18AD, 0x18AE, 0x18E1}

_COUNTER = re.compile(r"/?(?P<dev>[^/]+)/ctr(?P<n>\d+)$", re.IGNORECASE)

#: Create*Chan RPC -> the measurement (UsageTypeCI) or output (UsageTypeCO) it makes
CI_RPCS = {
    "CreateCICountEdgesChan": CI_COUNT_EDGES, "CreateCIFreqChan": CI_FREQ,
    "CreateCIPeriodChan": CI_PERIOD, "CreateCIPulseWidthChan": CI_PULSE_WIDTH,
    "CreateCISemiPeriodChan": CI_SEMI_PERIOD, "CreateCITwoEdgeSepChan": CI_TWO_EDGE_SEP,
    "CreateCIDutyCycleChan": CI_DUTY_CYCLE, "CreateCIPulseChanFreq": CI_PULSE_FREQ,
    "CreateCIPulseChanTime": CI_PULSE_TIME, "CreateCIPulseChanTicks": CI_PULSE_TICKS,
}
CO_RPCS = {"CreateCOPulseChanFreq": CO_PULSE_FREQ, "CreateCOPulseChanTime": CO_PULSE_TIME,
           "CreateCOPulseChanTicks": CO_PULSE_TICKS}


@dataclass
class Counter:
    """What a counter channel was made to do."""

    usage: int  # UsageTypeCI or UsageTypeCO
    terminal: str = ""  # its input (CI) or output (CO) terminal
    initial_count: int = 0  # count edges
    high_s: float = 0.0  # CO: the pulse's high and low times, coerced to timebase ticks [s]
    low_s: float = 0.0
    initial_delay_s: float = 0.0
    idle_high: bool = False
    implicit: bool = False  # timed by its own measurements (CI) or pulses (CO)

    @property
    def period_s(self) -> float:
        return self.high_s + self.low_s


def counter_names(device: Any, name: str, where: str) -> list[str]:
    """The canonical counters (``Dev1/ctr0``) in a channel string; -200220 for another device,
    -200170 for a counter the board lacks."""
    out = []
    for part in [p.strip() for p in name.split(",") if p.strip()]:
        found = _COUNTER.fullmatch(part)
        dev = part.lstrip("/").split("/", 1)[0]
        if dev.lower() != device.spec.name.lower():
            raise daq_error(DEVICE_NOT_FOUND, f"{where}: device {dev!r} in {part!r} does not "
                            f"exist (this server has {device.spec.name})")
        if found is None or int(found["n"]) >= COUNTERS:
            raise daq_error(PHYSICAL_CHAN_DOES_NOT_EXIST,
                            f"{where}: physical channel {part!r} does not exist on "
                            f"{device.spec.name} ({device.spec.product}; counters are "
                            f"ctr0..ctr{COUNTERS - 1})")
        out.append(f"{device.spec.name}/ctr{int(found['n'])}")
    if not out:
        raise daq_error(PHYSICAL_CHAN_DOES_NOT_EXIST, f"{where}: no counter given")
    return out


def coerced(seconds: float, what: str, where: str) -> float:
    """``seconds`` as whole ticks of the fastest timebase whose 32-bit count holds it; -200077
    for a time no timebase makes."""
    for rate in TIMEBASES_HZ if math.isfinite(seconds) else ():
        ticks = round(seconds * rate)
        if ticks < 2 ** 32:
            if ticks < MIN_TICKS:
                break
            return ticks / rate
    raise daq_error(INVALID_ATTRIBUTE_VALUE,
                    f"{where}: {what} of {seconds:g} s is outside what the counter makes "
                    f"({MIN_TICKS} ticks of {TIMEBASES_HZ[0] / 1e6:g} MHz = "
                    f"{MIN_TICKS / TIMEBASES_HZ[0] * 1e9:g} ns to 2^32 ticks of "
                    f"{TIMEBASES_HZ[-1] / 1e3:g} kHz = {2 ** 32 / TIMEBASES_HZ[-1]:g} s)")


def pulse_times(freq: float, duty: float, where: str) -> tuple[float, float]:
    """(high, low) [s] of a pulse by frequency and duty cycle."""
    if not (math.isfinite(freq) and freq > 0):
        raise daq_error(INVALID_ATTRIBUTE_VALUE, f"{where}: frequency {freq:g} Hz must be > 0")
    if not 0.0 < duty < 1.0:
        raise daq_error(INVALID_ATTRIBUTE_VALUE,
                        f"{where}: duty cycle {duty:g} must be between 0 and 1 (exclusive)")
    return (coerced(duty / freq, "high time", where),
            coerced((1.0 - duty) / freq, "low time", where))


def _counter_of(rpc: str, request: Any, where: str) -> Counter:
    if rpc in CI_RPCS:
        usage = CI_RPCS[rpc]
        lo, hi = getattr(request, "min_val", 0.0), getattr(request, "max_val", 1.0)
        if usage != CI_COUNT_EDGES and not 0 < lo < hi:
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"{where}: the expected range [{lo:g}, {hi:g}] must have 0 < min < "
                            "max")
        return Counter(usage, initial_count=int(getattr(request, "initial_count", 0)))
    usage = CO_RPCS[rpc]
    delay = request.initial_delay
    if usage == CO_PULSE_FREQ:
        high, low = pulse_times(request.freq, request.duty_cycle, where)
    elif usage == CO_PULSE_TIME:
        high = coerced(request.high_time, "high time", where)
        low = coerced(request.low_time, "low time", where)
    else:  # ticks of the source terminal: the onboard 100 MHz timebase
        if request.source_terminal and "100mhz" not in request.source_terminal.lower():
            raise daq_error(DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION,
                            f"{where}: pulses counted on {request.source_terminal!r} are not "
                            "simulated (use the onboard 100MHzTimebase)")
        high = coerced(request.high_ticks / TIMEBASES_HZ[0], "high time", where)
        low = coerced(request.low_ticks / TIMEBASES_HZ[0], "low time", where)
        delay = request.initial_delay / TIMEBASES_HZ[0]
    if not (math.isfinite(delay) and delay >= 0):
        raise daq_error(INVALID_ATTRIBUTE_VALUE, f"{where}: initial delay {delay:g} s must be "
                        ">= 0")
    return Counter(usage, high_s=high, low_s=low, initial_delay_s=delay,
                   idle_high=request.idle_state_raw == LEVEL_HIGH)


def _create_handler(rpc: str) -> Callable[..., Any]:
    kind = "ci" if rpc in CI_RPCS else "co"

    @reports_daq_errors
    def handler(self: Any, request: Any, context: Any) -> Any:
        task = self._task(request.task)
        where = f"{rpc} on task {task.name!r}"
        if task.running:
            raise daq_error(ATTR_NOT_SUPPORTED, f"{where}: cannot add channels to a running task")
        if task.kind not in (None, kind):
            raise daq_error(ATTR_NOT_SUPPORTED, f"{where}: task already has "
                            f"{task.kind.upper()} channels; use one task per type")
        physical = counter_names(self.device, request.counter, where)
        used = {p for c in task.channels for p in c.physical}
        if used & set(physical):
            raise daq_error(REPEATED_PHYSICAL_CHAN,
                            f"{where}: {sorted(used & set(physical))} already in this task")
        for i, p in enumerate(physical):
            name = request.name_to_assign_to_channel
            name = (f"{name}{i}" if len(physical) > 1 else name) if name else p
            task.channels.append(SimChannel(name, kind, [p], counter=_counter_of(rpc, request,
                                                                                 where)))
        if kind == "co":  # no timing: one pulse
            task.sample_mode, task.samps_per_chan = MODE_FINITE, 1
            task.rate_hz = 1.0 / task.channels[0].counter.period_s
        return getattr(pb, f"{rpc}Response")(status=0)

    handler.__name__ = rpc
    return handler


# --- the device's hooks ---------------------------------------------------------------------
def start(device: Any, task: SimTask) -> None:
    """A counter task starts: a generation's pulses count from now; an edge count sampled on
    the AI sample clock samples from the AI task's start (`SimDevice._start_ai` sets it when
    that comes later). Another sample clock (the onboard clock): -201380."""
    task.di_read = 0  # samples read since the start
    if task.kind == "ci" and task.rate_hz is not None:
        if task.clock_source.lower() != device.terminal("SampleClock").lower() \
                or task.channels[0].counter.usage != CI_COUNT_EDGES:
            raise daq_error(DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION,
                            f"start {task.name!r}: a counter input sampled on "
                            f"{task.clock_source or 'the onboard clock'} is not simulated (an "
                            "edge count on /Dev1/ai/SampleClock or a PFI line, implicit "
                            "timing, or on demand are)")
        task.t_start = device.t0 if device.ai_task is not None else None
        return
    task.t_start = device.now()


def end_time(task: SimTask) -> float | None:
    """Device time a running finite pulse generation ends (its last pulse's active time)."""
    if not task.running or task.sample_mode != MODE_FINITE or task.t_start is None \
            or task.external:
        return None
    c = task.channels[0].counter
    return (task.t_start + c.initial_delay_s + (task.samps_per_chan - 1) * c.period_s
            + c.high_s)


def generation_done(device: Any, task: SimTask) -> bool:
    """DAQmx IsTaskDone of a counter output task."""
    end = end_time(task)
    if end is not None and device.now() >= end - 1e-12:
        task.done = True
    return task.done or not task.running


def buffered(task: SimTask) -> bool:
    """Whether a counter task is timed (implicitly or by a sample clock), not on demand."""
    return task.kind in ("ci", "co") and (
        task.rate_hz is not None and task.kind == "ci" or task.channels[0].counter.implicit)


def chan_int32(ch: SimChannel, attr: int) -> int | None:
    """A counter channel's int32 attribute (type, measurement/output type); None: not one."""
    if ch.counter is None:
        return None
    if attr == 0x187F:  # ATTR_CHAN_TYPE
        return CHAN_CI if ch.kind == "ci" else CHAN_CO
    if (attr == ATTR_CI_MEAS_TYPE and ch.kind == "ci") or (
            attr == ATTR_CO_OUTPUT_TYPE and ch.kind == "co"):
        return int(ch.counter.usage)
    return None


# --- the RPCs -------------------------------------------------------------------------------
class CounterRpcs(ServicerParts):
    """Counter channels, their terminals, implicit timing, reads and writes."""

    @reports_daq_errors
    def SetChanAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        where = f"SetChanAttributeString 0x{request.attribute_raw:04X} on task {task.name!r}"
        chans = self._channels(task, request.channel)
        if request.attribute_raw not in TERMINAL_ATTRS or any(c.counter is None for c in chans):
            raise daq_error(ATTR_NOT_SUPPORTED, f"{where}: the attribute is not supported by "
                            "the simulated device")
        terminal = triggers.check_external(self.device, request.value, where, "terminal")
        for ch in chans:
            ch.counter.terminal = terminal
        return pb.SetChanAttributeStringResponse(status=0)

    @reports_daq_errors
    def GetChanAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        chans = self._channels(task, request.channel)
        if request.attribute_raw in TERMINAL_ATTRS and chans and chans[0].counter is not None:
            return pb.GetChanAttributeStringResponse(value=chans[0].counter.terminal)
        return super().GetChanAttributeString(request, context)  # type: ignore[misc]

    @reports_daq_errors
    def CfgImplicitTiming(self, request, context):  # noqa: N802
        task = self._task(request.task)
        where = f"CfgImplicitTiming on task {task.name!r}"
        if task.kind not in ("ci", "co"):
            raise daq_error(ATTR_NOT_SUPPORTED_IN_TASK, f"{where}: implicit timing needs a "
                            f"counter task (the task has {task.kind or 'no channels'})")
        if request.sample_mode_raw not in (MODE_CONTINUOUS, MODE_FINITE):
            raise daq_error(INVALID_ATTRIBUTE_VALUE,
                            f"{where}: sample mode {request.sample_mode_raw} not supported")
        if task.kind == "ci" and task.channels[0].counter.usage == CI_COUNT_EDGES:
            raise daq_error(INVALID_ATTRIBUTE_VALUE, f"{where}: an edge count has no implicit "
                            "timing (it needs a sample clock)")
        task.sample_mode = request.sample_mode_raw
        task.samps_per_chan = int(request.samps_per_chan)
        for ch in task.channels:
            ch.counter.implicit = True
        task.external.pop("sample clock", None)
        return pb.CfgImplicitTimingResponse(status=0)

    # --- reads ----------------------------------------------------------------------------
    def _read_counts(self, request: Any, n: int, pulse: bool = False) -> np.ndarray:
        """The next ``n`` samples of a counter input task (n_ch, n), or its timeout; ``pulse``:
        a read of pulse measurements (frequency and duty cycle, high and low time or ticks)."""
        task = self._task(request.task)
        task.kind_or_raise("ci")
        is_pulse = task.channels[0].counter.usage in (CI_PULSE_FREQ, CI_PULSE_TIME,
                                                      CI_PULSE_TICKS)
        if pulse != is_pulse:
            raise daq_error(READ_CHAN_TYPE_MISMATCH,
                            f"read from {task.name!r}: this read does not match the type of "
                            "the task's counter channels (pulse measurements read as "
                            "CtrFreq/CtrTime/CtrTick, the others as numbers)")
        others = self._others()
        if not task.running:
            self.device.start(task, others)
            task.auto_started = True
        counters = [ch.counter for ch in task.channels]
        timed = buffered(task)
        try:
            if triggers.waits_on_external(task):
                return triggers.read_times_out(self.device, task, n, request.timeout)
            if counters[0].usage == CI_COUNT_EDGES and task.rate_hz is not None:
                return self._sampled_counts(task, n, request.timeout)
            if counters[0].usage == CI_COUNT_EDGES:  # on demand
                return np.array([[c.initial_count] * max(n, 1) for c in counters], dtype=float)
            if n == 0 or (n < 0 and timed and task.sample_mode == MODE_CONTINUOUS):
                return np.zeros((len(counters), 0))  # what is available: nothing
            triggers.wait_out(self.device, task, request.timeout)
            why = (f"no edge arrived on {counters[0].terminal or 'its default terminal'} "
                   f"(nothing on the rig drives the {self.device.spec.product}'s counter inputs)")
            if timed:
                raise triggers.samples_not_acquired(task, n, request.timeout, why)
            raise daq_error(
                OPERATION_TIMED_OUT,
                f"Specified operation did not complete, because the specified timeout expired. "
                f"Read of {task.name!r} after {request.timeout:g} s: {why}",
                samps_per_chan_read=0)
        finally:
            if task.auto_started and task.running and not timed:  # on demand: one read
                self.device.stop(task)

    def _sampled_counts(self, task: SimTask, n: int, timeout_s: float) -> np.ndarray:
        """``n`` edge counts sampled on the AI sample clock (nothing counted: the initial
        count): they wait for the clock, -200284 past the timeout."""
        device = self.device
        assert task.rate_hz is not None
        with device.lock:
            if task.t_start is None and device.ai_task is not None:
                task.t_start = device.t0
            t_start = task.t_start
            taken = (0 if t_start is None
                     else max(math.floor((device.now() - t_start) * task.rate_hz), 0))
            if n < 0:
                n = taken - task.di_read
            ready_at = math.inf if t_start is None else t_start + (task.di_read + n) / task.rate_hz
        if not device.fast and n > 0:
            now = device.now()
            if timeout_s >= 0 and ready_at > now + timeout_s:
                device.sleep(timeout_s)
                raise triggers.samples_not_acquired(task, n, timeout_s, "the AI sample clock "
                                                    "it counts on has not produced them")
            while now < ready_at and not device.stopping() and task.running:
                device.sleep(ready_at - now)
                now = device.now()
        task.di_read += max(n, 0)
        return np.array([[ch.counter.initial_count] * max(n, 0) for ch in task.channels],
                        dtype=float)

    @reports_daq_errors
    def ReadCounterF64Ex(self, request, context):  # noqa: N802
        data = self._read_counts(request, request.num_samps_per_chan)
        return pb.ReadCounterF64ExResponse(read_array=data.ravel(),
                                           samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def ReadCounterF64(self, request, context):  # noqa: N802
        data = self._read_counts(request, request.num_samps_per_chan)
        return pb.ReadCounterF64Response(read_array=data[0], samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def ReadCounterU32Ex(self, request, context):  # noqa: N802
        data = self._read_counts(request, request.num_samps_per_chan)
        return pb.ReadCounterU32ExResponse(read_array=data.ravel().astype(np.uint32),
                                           samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def ReadCounterU32(self, request, context):  # noqa: N802
        data = self._read_counts(request, request.num_samps_per_chan)
        return pb.ReadCounterU32Response(read_array=data[0].astype(np.uint32),
                                         samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def ReadCounterScalarF64(self, request, context):  # noqa: N802
        return pb.ReadCounterScalarF64Response(value=float(self._read_counts(request, 1)[0, 0]))

    @reports_daq_errors
    def ReadCounterScalarU32(self, request, context):  # noqa: N802
        return pb.ReadCounterScalarU32Response(value=int(self._read_counts(request, 1)[0, 0]))

    # pulse measurements: no pulse arrives, so these only ever time out (or read nothing)
    @reports_daq_errors
    def ReadCtrFreq(self, request, context):  # noqa: N802
        data = self._read_counts(request, request.num_samps_per_chan, pulse=True)
        return pb.ReadCtrFreqResponse(samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def ReadCtrTime(self, request, context):  # noqa: N802
        data = self._read_counts(request, request.num_samps_per_chan, pulse=True)
        return pb.ReadCtrTimeResponse(samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def ReadCtrTicks(self, request, context):  # noqa: N802
        data = self._read_counts(request, request.num_samps_per_chan, pulse=True)
        return pb.ReadCtrTicksResponse(samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def ReadCtrFreqScalar(self, request, context):  # noqa: N802
        self._read_counts(request, 1, pulse=True)  # never returns: no pulse arrives
        return pb.ReadCtrFreqScalarResponse()

    @reports_daq_errors
    def ReadCtrTimeScalar(self, request, context):  # noqa: N802
        self._read_counts(request, 1, pulse=True)
        return pb.ReadCtrTimeScalarResponse()

    @reports_daq_errors
    def ReadCtrTicksScalar(self, request, context):  # noqa: N802
        self._read_counts(request, 1, pulse=True)
        return pb.ReadCtrTicksScalarResponse()

    # --- writes ---------------------------------------------------------------------------
    def _write_pulses(self, request: Any, usage: int, highs: np.ndarray, lows: np.ndarray
                      ) -> int:
        """Buffered pulse specifications (high and low times [s]) for a CO task."""
        task = self._task(request.task)
        task.kind_or_raise("co")
        where = f"write to {task.name!r}"
        n = int(request.num_samps_per_chan)
        if n <= 0 or highs.size != n * len(task.channels) or lows.size != highs.size:
            raise daq_error(WRITE_NUM_CHANS_MISMATCH, f"{where}: {highs.size} samples for {n} "
                            f"samples x {len(task.channels)} channels")
        if any(ch.counter.usage != usage for ch in task.channels):
            raise daq_error(ATTR_NOT_SUPPORTED_IN_TASK, f"{where}: the samples' type does not "
                            "match the channel's output type")
        for h, lo in zip(highs, lows, strict=True):
            coerced(float(h), "high time", where)
            coerced(float(lo), "low time", where)
        if request.auto_start and not task.running:
            self.device.start(task, self._others())
        return n

    @reports_daq_errors
    def WriteCtrFreq(self, request, context):  # noqa: N802
        freq = np.asarray(request.frequency, dtype=float)
        duty = np.asarray(request.duty_cycle, dtype=float)
        where = f"write to task {request.task.name!r}"
        if freq.size != duty.size:
            raise daq_error(WRITE_NUM_CHANS_MISMATCH, f"{where}: {freq.size} frequencies for "
                            f"{duty.size} duty cycles")
        times = [pulse_times(float(f), float(d), where) for f, d in zip(freq, duty, strict=True)]
        highs = np.array([t[0] for t in times])
        lows = np.array([t[1] for t in times])
        n = self._write_pulses(request, CO_PULSE_FREQ, highs, lows)
        return pb.WriteCtrFreqResponse(num_samps_per_chan_written=n)

    @reports_daq_errors
    def WriteCtrTime(self, request, context):  # noqa: N802
        n = self._write_pulses(request, CO_PULSE_TIME, np.asarray(request.high_time, float),
                               np.asarray(request.low_time, float))
        return pb.WriteCtrTimeResponse(num_samps_per_chan_written=n)

    @reports_daq_errors
    def WriteCtrTicks(self, request, context):  # noqa: N802
        n = self._write_pulses(request, CO_PULSE_TICKS,
                               np.asarray(request.high_ticks, float) / TIMEBASES_HZ[0],
                               np.asarray(request.low_ticks, float) / TIMEBASES_HZ[0])
        return pb.WriteCtrTicksResponse(num_samps_per_chan_written=n)


for _rpc in (*CI_RPCS, *CO_RPCS):
    setattr(CounterRpcs, _rpc, _create_handler(_rpc))
