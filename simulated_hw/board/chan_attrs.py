"""Channel, device and timing attributes generic nidaqmx code asks for, and the analog scalar and
raw (int16) reads and writes; mixed into the servicer (needs ``device``, ``_task``,
``_others``, ``_find_channels``).

- channel: ``ai_max`` / ``ai_min`` / ``ao_max`` / ``ao_min`` (read and set: the board takes the
  smallest of its ranges that holds [min, max], as DAQmx does when it picks the gain, and
  refuses with -200077 what no range holds), ``physical_channel``, ``ai_raw_samp_size`` (16),
  ``do_num_lines`` / ``di_num_lines``;
- device: ``product_category`` (X Series DAQ), ``product_num``, ``serial_num``;
- task: ``devices`` (the devices of its channels);
- timing: the reference clock (``ref_clk_src`` PXIe_Clk100, PXI_Clk10 or OnboardClock,
  ``ref_clk_rate`` its rate), which does not change the simulated clock;
- raw reads and writes: the 16-bit code of each sample over the device range the channel
  uses (``ai_rng_high``: the smallest of +/-1, 2, 5, 10 V that holds [min, max];
  ``code = round(v / (range / 32768))``);
- ``is_simulated``: True (nidaqmx's gRPC client drops a StopTask status, so the driver's
  warnings, e.g. stopped before done, never reach it, as with NI's simulated devices).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from nidaqmx._stubs import nidaqmx_pb2 as pb

from daq.errors import ATTR_NOT_SUPPORTED, INVALID_ATTRIBUTE_VALUE
from simulated_hw.board.codes import (
    AI_RANGES_V,
    AO_RANGES_V,
    ATTR_INCONSISTENT,
    FILL_GROUP_BY_CHANNEL,
    READ_BUFFER_TOO_SMALL,
    WRITE_NUM_CHANS_MISMATCH,
    daq_error,
)
from simulated_hw.board.device_rpcs import attribute
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.tasks import SimChannel, SimTask
from simulated_hw.board.wire import reports_daq_errors

ATTR_AI_MAX, ATTR_AI_MIN, ATTR_AO_MAX, ATTR_AO_MIN = 0x17DD, 0x17DE, 0x1186, 0x1187
ATTR_AI_RNG_HIGH, ATTR_AI_RNG_LOW = 0x1815, 0x1816  # the device range the channel uses
ATTR_DEV_IS_SIMULATED = 0x22CA
ATTR_PHYSICAL_CHAN_NAME = 0x18F5
ATTR_AI_RAW_SAMP_SIZE = 0x22DA
ATTR_DO_NUM_LINES, ATTR_DI_NUM_LINES = 0x2179, 0x2178
ATTR_DEV_PRODUCT_CATEGORY, ATTR_DEV_PRODUCT_NUM, ATTR_DEV_SERIAL_NUM = 0x29A9, 0x231D, 0x0632
ATTR_TASK_DEVICES = 0x230E
ATTR_REF_CLK_SRC, ATTR_REF_CLK_RATE = 0x1316, 0x1315
PRODUCT_CATEGORY_X_SERIES = 15858
PRODUCT_NUM_PXIE_6358 = 0x7429  # as MAX reports it for a PXIe-6358
REF_CLOCKS = {"pxie_clk100": 100e6, "pxi_clk10": 10e6, "onboardclock": 100e6}
RAW_BITS = 16


def device_range_v(ch: SimChannel) -> float:
    """The smallest of the device's bipolar ranges that holds the channel's [min, max]."""
    ranges = AI_RANGES_V if ch.kind == "ai" else AO_RANGES_V
    need = max(abs(ch.min_v), abs(ch.max_v))
    return next((r for r in ranges if r >= need), ranges[-1])


def raw_codes(task: SimTask, data: np.ndarray) -> np.ndarray:
    """The 16-bit ADC codes of AI samples (n_ch, n), over each channel's device range."""
    lsb = np.array([[device_range_v(c) / 2 ** (RAW_BITS - 1)] for c in task.channels])
    return np.clip(np.round(data / lsb), -(2 ** 15), 2 ** 15 - 1).astype(np.int16)


def _range_for(ch: SimChannel, lo: float, hi: float) -> tuple[float, float]:
    ranges = AI_RANGES_V if ch.kind == "ai" else AO_RANGES_V
    for r in ranges:
        if -r <= lo < hi <= r:
            return lo, hi
    raise daq_error(INVALID_ATTRIBUTE_VALUE,
                    f"Requested value is not a supported value for this property: range "
                    f"[{lo:g}, {hi:g}] V on {ch.name} is not within any of the device's ranges "
                    f"(+/-{', +/-'.join(f'{r:g}' for r in ranges)} V)")


class ChannelAttrRpcs(ServicerParts):
    """Channel, device and timing attributes, analog scalars and raw reads."""

    @reports_daq_errors
    def GetChanAttributeDouble(self, request, context):  # noqa: N802
        task = self._task(request.task)
        values = set()
        for ch in self._channels(task, request.channel):
            if request.attribute_raw in (ATTR_AI_MAX, ATTR_AO_MAX) and \
                    ch.kind == ("ai" if request.attribute_raw == ATTR_AI_MAX else "ao"):
                values.add(ch.max_v)
            elif request.attribute_raw in (ATTR_AI_MIN, ATTR_AO_MIN) and \
                    ch.kind == ("ai" if request.attribute_raw == ATTR_AI_MIN else "ao"):
                values.add(ch.min_v)
            elif request.attribute_raw in (ATTR_AI_RNG_HIGH, ATTR_AI_RNG_LOW) and ch.kind == "ai":
                r = device_range_v(ch)
                values.add(r if request.attribute_raw == ATTR_AI_RNG_HIGH else -r)
            else:
                raise _unsupported_chan(request.attribute_raw)
        return pb.GetChanAttributeDoubleResponse(value=_one(values, request))

    @reports_daq_errors
    def SetChanAttributeDouble(self, request, context):  # noqa: N802
        task = self._task(request.task)
        attr, value = request.attribute_raw, request.value
        for ch in self._channels(task, request.channel):
            kind = "ai" if attr in (ATTR_AI_MAX, ATTR_AI_MIN) else "ao"
            if attr not in (ATTR_AI_MAX, ATTR_AI_MIN, ATTR_AO_MAX, ATTR_AO_MIN) \
                    or ch.kind != kind:
                raise _unsupported_chan(attr)
            if task.running:
                raise daq_error(ATTR_NOT_SUPPORTED, f"task {task.name!r} is running: its "
                                "channels' ranges cannot change")
            high = attr in (ATTR_AI_MAX, ATTR_AO_MAX)
            lo, hi = (ch.min_v, value) if high else (value, ch.max_v)
            ch.min_v, ch.max_v = _range_for(ch, lo, hi)
        return pb.SetChanAttributeDoubleResponse(status=0)

    @reports_daq_errors
    def GetChanAttributeUInt32(self, request, context):  # noqa: N802
        task = self._task(request.task)
        values = set()
        for ch in self._channels(task, request.channel):
            if request.attribute_raw == ATTR_AI_RAW_SAMP_SIZE and ch.kind == "ai":
                values.add(RAW_BITS)
            elif request.attribute_raw == ATTR_DO_NUM_LINES and ch.kind == "do" or \
                    request.attribute_raw == ATTR_DI_NUM_LINES and ch.kind == "di":
                values.add(len(ch.physical))
            else:
                raise _unsupported_chan(request.attribute_raw)
        return pb.GetChanAttributeUInt32Response(value=_one(values, request))

    @reports_daq_errors
    def GetChanAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_PHYSICAL_CHAN_NAME:
            raise _unsupported_chan(request.attribute_raw)
        names = [", ".join(ch.physical) for ch in self._channels(task, request.channel)]
        return pb.GetChanAttributeStringResponse(value=", ".join(names))

    @reports_daq_errors
    def GetDeviceAttributeInt32(self, request, context):  # noqa: N802
        self._check_device(request.device_name)
        return pb.GetDeviceAttributeInt32Response(value_raw=attribute(
            {ATTR_DEV_PRODUCT_CATEGORY: PRODUCT_CATEGORY_X_SERIES}, "device",
            request.attribute_raw))

    @reports_daq_errors
    def GetDeviceAttributeUInt32(self, request, context):  # noqa: N802
        self._check_device(request.device_name)
        return pb.GetDeviceAttributeUInt32Response(value=attribute(
            {ATTR_DEV_PRODUCT_NUM: PRODUCT_NUM_PXIE_6358, ATTR_DEV_SERIAL_NUM: 0}, "device",
            request.attribute_raw))

    @reports_daq_errors
    def SetTimingAttributeString(self, request, context):  # noqa: N802
        task = self._task(request.task)
        if request.attribute_raw != ATTR_REF_CLK_SRC:
            raise daq_error(ATTR_NOT_SUPPORTED, f"timing attribute 0x{request.attribute_raw:04X}"
                            " is not supported by the simulated device")
        source = request.value.strip().removeprefix("/")
        if source.lower() not in REF_CLOCKS:
            raise daq_error(INVALID_ATTRIBUTE_VALUE, f"reference clock source {request.value!r}"
                            f" is not available (PXIe_Clk100, PXI_Clk10, OnboardClock)")
        self.ref_clock[task.name] = (source, REF_CLOCKS[source.lower()])
        return pb.SetTimingAttributeStringResponse(status=0)

    @reports_daq_errors
    def SetTimingAttributeDouble(self, request, context):  # noqa: N802
        task = self._task(request.task)
        source, rate = self.ref_clock.get(task.name, ("OnboardClock", 100e6))
        if request.attribute_raw != ATTR_REF_CLK_RATE:
            raise daq_error(ATTR_NOT_SUPPORTED, f"timing attribute 0x{request.attribute_raw:04X}"
                            " is not supported by the simulated device")
        if request.value != rate:
            raise daq_error(INVALID_ATTRIBUTE_VALUE, f"reference clock {source} runs at "
                            f"{rate:g} Hz, not {request.value:g}")
        return pb.SetTimingAttributeDoubleResponse(status=0)

    # --- analog scalars and raw samples ---------------------------------------------------
    @reports_daq_errors
    def ReadAnalogScalarF64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ai")
        data = self.device.read(task, 1, request.timeout, self._others())
        return pb.ReadAnalogScalarF64Response(value=float(data[0, 0]))

    @reports_daq_errors
    def WriteAnalogScalarF64(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ao")
        self.device.write_ao(task, np.array([[request.value]]), request.auto_start,
                             request.timeout, self._others())
        return pb.WriteAnalogScalarF64Response(status=0)

    @reports_daq_errors
    def ReadBinaryI16(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ai")
        n = request.num_samps_per_chan
        if n >= 0 and request.array_size_in_samps < n * len(task.channels):
            raise daq_error(READ_BUFFER_TOO_SMALL, f"read of {n} samples from {task.name!r}: "
                            f"the client buffer holds only {request.array_size_in_samps}",
                            samps_per_chan_read=0)
        data = self.device.read(task, n, request.timeout, self._others())
        codes = raw_codes(task, data).astype(np.int64)
        samps = codes.shape[1]
        if request.fill_mode_raw != FILL_GROUP_BY_CHANNEL:
            codes = codes.T
        return pb.ReadBinaryI16Response(read_array=codes.ravel().tolist(),
                                        samps_per_chan_read=samps)

    @reports_daq_errors
    def ReadRaw(self, request, context):  # noqa: N802
        """Raw samples as the board stores them: int16, interleaved by sample."""
        task = self._task(request.task)
        task.kind_or_raise("ai")
        n = request.num_samps_per_chan
        n_ch = len(task.channels)
        if n >= 0 and request.array_size_in_bytes < n * n_ch * 2:
            raise daq_error(READ_BUFFER_TOO_SMALL, f"read of {n} raw samples from "
                            f"{task.name!r}: the client buffer holds only "
                            f"{request.array_size_in_bytes} bytes", samps_per_chan_read=0)
        data = self.device.read(task, n, request.timeout, self._others())
        codes = raw_codes(task, data)
        return pb.ReadRawResponse(read_array=codes.T.astype("<i2").tobytes(),
                                  samps_read=codes.shape[1], num_bytes_per_samp=2)

    @reports_daq_errors
    def GetDeviceAttributeBool(self, request, context):  # noqa: N802
        self._check_device(request.device_name)
        return pb.GetDeviceAttributeBoolResponse(value=attribute(
            {ATTR_DEV_IS_SIMULATED: True}, "device", request.attribute_raw))

    @reports_daq_errors
    def WriteBinaryI16(self, request, context):  # noqa: N802
        task = self._task(request.task)
        task.kind_or_raise("ao")
        n, n_ch = request.num_samps_per_chan, len(task.channels)
        flat = np.asarray(request.write_array, dtype=np.float64)
        if n <= 0 or flat.size != n * n_ch:
            raise daq_error(WRITE_NUM_CHANS_MISMATCH, f"write to {task.name!r}: {flat.size} "
                            f"values for {n} samples x {n_ch} channels")
        block = (flat.reshape(n_ch, n) if request.data_layout_raw == FILL_GROUP_BY_CHANNEL
                 else flat.reshape(n, n_ch).T)
        lsb = np.array([[device_range_v(c) / 2 ** (RAW_BITS - 1)] for c in task.channels])
        written = self.device.write_ao(task, np.clip(block * lsb, [[c.min_v] for c in
                                                                   task.channels],
                                                     [[c.max_v] for c in task.channels]),
                                       request.auto_start, request.timeout, self._others())
        return pb.WriteBinaryI16Response(samps_per_chan_written=written)


def task_devices(device: Any, task: SimTask) -> str:
    """DAQmx_Task_Devices: the devices of the task's channels (one board here)."""
    return device.spec.name if task.channels else ""


def _one(values: set[Any], request: Any) -> Any:
    if len(values) != 1:
        raise daq_error(ATTR_INCONSISTENT, f"channel attribute 0x{request.attribute_raw:04X} "
                        f"differs across {request.channel!r}")
    return values.pop()


def _unsupported_chan(attr: int) -> Any:
    return daq_error(ATTR_NOT_SUPPORTED,
                     f"channel attribute 0x{attr:04X} is not supported by the simulated device")
