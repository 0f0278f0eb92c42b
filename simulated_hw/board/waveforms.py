"""The waveform API over gRPC (``task.read_waveform``, ``task.write(AnalogWaveform |
DigitalWaveform)``): nidaqmx's ReadAnalogWaveforms, WriteAnalogWaveforms, ReadDigitalWaveforms
and WriteDigitalWaveforms, on the same reads and writes as the plain arrays.

A read's waveform holds, as DAQmx gives it, the samples (analog: in the channel's units;
digital: one signal per line of the channel, in its line order), its timing when the mode asks
for it (t0: the wall-clock time of the first sample read, dt: the sample clock's period; an
on-demand read has t0 only) and its extended properties (``NI_ChannelName``,
``NI_UnitDescription`` or ``NI_LineNames``). A write takes one waveform per channel, all of one
length; their timing is not used (the task's clock generates them), as on the board.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
from ni.protobuf.types.waveform_conversion import (
    digital_waveform_from_protobuf,
    digital_waveform_to_protobuf,
    float64_analog_waveform_from_protobuf,
    float64_analog_waveform_to_protobuf,
)
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nitypes.waveform import AnalogWaveform, DigitalWaveform, Timing

from simulated_hw.board import digital, tdms_logging
from simulated_hw.board.codes import WRITE_NUM_CHANS_MISMATCH, daq_error
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.tasks import SimTask
from simulated_hw.board.wire import reports_daq_errors

MODE_TIMING, MODE_EXTENDED_PROPERTIES = 1, 2  # WaveformAttributeMode bits
#: NI's unit descriptions of the channels the board reads (TemperatureUnits -> text)
TEMPERATURE_UNITS = {10143: "Deg C", 10144: "Deg F", 10325: "Kelvins", 10145: "Deg R"}


def first_sample_time(device: Any, task: SimTask) -> float:
    """Device time of the next sample a read of ``task`` returns (a task the read starts: now)."""
    with device.lock:
        if task.kind == "ai" and task is device.ai_task and task.rate_hz is not None:
            return float(device.t0 + device.read_pos / task.rate_hz)
        if task.kind == "di" and task.running and task.rate_hz is not None \
                and task.t_start is not None:
            return float(task.t_start + task.di_read / task.rate_hz)
        return float(device.now())


def _timing(device: Any, task: SimTask, t_device: float, mode: int) -> Timing[Any, Any, Any]:
    if not mode & MODE_TIMING:
        return Timing.empty
    # the board stamps t0 on the wall clock: device time maps to it through now
    t0 = datetime.now(UTC) - timedelta(seconds=device.now() - t_device)
    if task.rate_hz is None:  # on demand: a time, no sample clock
        return Timing.create_with_no_interval(t0)
    return Timing.create_with_regular_interval(timedelta(seconds=1.0 / task.rate_hz), t0)


def _check_counts(task: SimTask, lengths: list[int]) -> int:
    if len(lengths) != len(task.channels) or len(set(lengths)) != 1 or lengths[0] <= 0:
        raise daq_error(WRITE_NUM_CHANS_MISMATCH,
                        f"write to {task.name!r}: {len(lengths)} waveforms of {lengths} samples "
                        f"for {len(task.channels)} channels (one waveform per channel, all of "
                        "one length)")
    return lengths[0]


class WaveformRpcs(ServicerParts):
    """The waveform reads and writes, analog and digital (t0, dt and the channels' names)."""

    @reports_daq_errors
    def ReadAnalogWaveforms(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ai")
        tdms_logging.check_read(task)
        t_first = first_sample_time(self.device, task)
        data = self.device.read(task, request.num_samps_per_chan, request.timeout,
                                self._others())
        tdms_logging.write(self.device, task, data, t_first)
        mode = request.waveform_attribute_mode_raw
        timing = _timing(self.device, task, t_first, mode)
        out = []
        for ch, samples in zip(task.channels, data, strict=True):
            props = {}
            if mode & MODE_EXTENDED_PROPERTIES:
                props = {"NI_ChannelName": ch.name, "NI_UnitDescription": TEMPERATURE_UNITS.get(
                    ch.temperature_units or 0, "Volts")}
            wave = AnalogWaveform.from_array_1d(np.ascontiguousarray(samples, dtype=np.float64),
                                                timing=timing, extended_properties=props)
            out.append(float64_analog_waveform_to_protobuf(wave))
        return pb.ReadAnalogWaveformsResponse(waveforms=out, samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def WriteAnalogWaveforms(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ao")
        waves = [float64_analog_waveform_from_protobuf(w).scaled_data for w in request.waveforms]
        _check_counts(task, [len(w) for w in waves])
        written = self.device.write_ao(task, np.vstack(waves), request.auto_start,
                                       request.timeout, self._others())
        return pb.WriteAnalogWaveformsResponse(samps_per_chan_written=written)

    @reports_daq_errors
    def ReadDigitalWaveforms(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if task.kind != "do":
            task.kind_or_raise("di")
        t_first = first_sample_time(self.device, task)
        data = digital.read(self.device, task, request.num_samps_per_chan, request.timeout,
                            self._others())
        mode = request.waveform_attribute_mode_raw
        timing = _timing(self.device, task, t_first, mode)
        out = []
        for ch, values in zip(task.channels, data, strict=True):
            k = len(ch.physical)
            lines = np.zeros((values.size, k), dtype=np.uint8)
            for j, p in enumerate(ch.physical):  # signal j (line j) is column k - 1 - j
                lines[:, k - 1 - j] = (values >> np.uint32(digital.line_bit(p))) & 1
            props = {}
            if mode & MODE_EXTENDED_PROPERTIES:
                # NI_LineNames runs in column order: the highest line first
                props = {"NI_ChannelName": ch.name,
                         "NI_LineNames": ", ".join(reversed(ch.physical))}
            wave = DigitalWaveform.from_lines(lines, signal_count=k, timing=timing,
                                              extended_properties=props)
            out.append(digital_waveform_to_protobuf(wave))
        return pb.ReadDigitalWaveformsResponse(waveforms=out, samps_per_chan_read=data.shape[1])

    @reports_daq_errors
    def WriteDigitalWaveforms(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("do")
        waves = [digital_waveform_from_protobuf(w) for w in request.waveforms]
        n = _check_counts(task, [w.sample_count for w in waves])
        block = np.zeros((len(task.channels), n), dtype=np.uint32)
        for i, (ch, wave) in enumerate(zip(task.channels, waves, strict=True)):
            if wave.signal_count != len(ch.physical):
                raise daq_error(WRITE_NUM_CHANS_MISMATCH,
                                f"write to {task.name!r}: a waveform of {wave.signal_count} "
                                f"signals for channel {ch.name} of {len(ch.physical)} lines")
            for j, p in enumerate(ch.physical):
                bits = np.asarray(wave.signals[j].data, dtype=np.uint32) & 1
                block[i] |= bits << np.uint32(digital.line_bit(p))
        written = digital.write(self.device, task, block, request.auto_start, request.timeout,
                                self._others())
        return pb.WriteDigitalWaveformsResponse(samps_per_chan_written=written)
