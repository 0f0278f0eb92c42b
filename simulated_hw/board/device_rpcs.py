"""What the device says about itself (nidaqmx ``system.Device`` and ``PhysicalChannel``): its
product, physical channels and lines, voltage ranges and AI terminal configurations; mixed into
the servicer. A device named otherwise answers DAQmx -200220, as the driver does."""

from __future__ import annotations

from typing import Any

from nidaqmx._stubs import nidaqmx_pb2 as pb

from daq.errors import ATTR_NOT_SUPPORTED, DEVICE_NOT_FOUND
from simulated_hw.board.codes import (
    AI_RANGES_V,
    AI_TERM_CFGS,
    AO_RANGES_V,
    ATTR_DEV_AI_PHYSICAL_CHANS,
    ATTR_DEV_AI_VOLTAGE_RNGS,
    ATTR_DEV_AO_PHYSICAL_CHANS,
    ATTR_DEV_AO_VOLTAGE_RNGS,
    ATTR_DEV_DI_LINES,
    ATTR_DEV_DO_LINES,
    ATTR_DEV_IS_SIMULATED,
    ATTR_DEV_PRODUCT_TYPE,
    ATTR_PHYS_AI_TERM_CFGS,
    TERM_BITS,
    daq_error,
)
from simulated_hw.board.parts import ServicerParts
from simulated_hw.board.wire import reports_daq_errors


def ranges_within(ranges: tuple[float, ...], largest_v: float) -> list[float]:
    """The device's bipolar ranges up to its largest, flattened as DAQmx gives them."""
    return [v for r in ranges if r <= largest_v for v in (-r, r)]


def term_cfg_bits() -> int:
    """The AI terminal configurations every AI physical channel allows, as DAQmx's bitfield."""
    bits = 0
    for cfg in AI_TERM_CFGS:
        bits |= TERM_BITS[cfg]
    return bits


def attribute(values: dict[int, Any], group: str, attribute_id: int) -> Any:
    """``values[attribute_id]``, or the DAQmx error of an attribute the device lacks."""
    if attribute_id not in values:
        raise _unsupported(group, attribute_id)
    return values[attribute_id]


class DeviceRpcs(ServicerParts):
    """GetDeviceAttributeString, GetDeviceAttributeBool, GetDeviceAttributeDoubleArray,
    GetPhysicalChanAttributeInt32."""

    def _check_device(self, name: str) -> None:
        if name.lower() != self.device.spec.name.lower():
            raise daq_error(DEVICE_NOT_FOUND, f"device {name!r} does not exist "
                                              f"(this server has {self.device.spec.name})")

    @reports_daq_errors
    def GetDeviceAttributeString(self, request, context):  # noqa: N802
        self._check_device(request.device_name)
        spec = self.device.spec
        values = {
            ATTR_DEV_PRODUCT_TYPE: spec.product,
            ATTR_DEV_AI_PHYSICAL_CHANS: ", ".join(spec.ai_channels()),
            ATTR_DEV_AO_PHYSICAL_CHANS: ", ".join(spec.ao_channels()),
            ATTR_DEV_DO_LINES: ", ".join(spec.do_lines()),
            ATTR_DEV_DI_LINES: ", ".join(spec.do_lines()),  # port lines are inputs or outputs
        }
        return pb.GetDeviceAttributeStringResponse(
            value=attribute(values, "device", request.attribute_raw))

    @reports_daq_errors
    def GetDeviceAttributeBool(self, request, context):  # noqa: N802
        """Is the device simulated: yes, as an NI simulated device answers (a real board: no),
        so a client can name the board it is on."""
        self._check_device(request.device_name)
        return pb.GetDeviceAttributeBoolResponse(
            value=attribute({ATTR_DEV_IS_SIMULATED: True}, "device", request.attribute_raw))

    @reports_daq_errors
    def GetDeviceAttributeDoubleArray(self, request, context):  # noqa: N802
        self._check_device(request.device_name)
        spec = self.device.spec
        values = {ATTR_DEV_AI_VOLTAGE_RNGS: ranges_within(AI_RANGES_V, spec.ai_range_v),
                  ATTR_DEV_AO_VOLTAGE_RNGS: ranges_within(AO_RANGES_V, spec.ao_range_v)}
        return pb.GetDeviceAttributeDoubleArrayResponse(
            value=attribute(values, "device", request.attribute_raw))

    @reports_daq_errors
    def GetPhysicalChanAttributeInt32(self, request, context):  # noqa: N802
        bits = attribute({ATTR_PHYS_AI_TERM_CFGS: term_cfg_bits()}, "physical channel",
                         request.attribute_raw)
        self.device.physical(request.physical_channel, "ai",
                             f"physical channel {request.physical_channel!r}")
        return pb.GetPhysicalChanAttributeInt32Response(value_raw=bits)


def _unsupported(group: str, attribute: int) -> Any:
    return daq_error(
        ATTR_NOT_SUPPORTED,
        f"{group} attribute 0x{attribute:04X} is not supported by the simulated device",
    )
