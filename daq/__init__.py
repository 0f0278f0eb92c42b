"""Hardware boundary: channel map and calibration, the DaqBackend protocol, the nidaqmx backend."""

from daq.backend import AoCut, DaqBackend
from daq.channels import (
    AnalogInput,
    AnalogOutput,
    ChannelKind,
    ChannelMap,
    DeviceSpec,
    DigitalOutput,
    EmergencyStopInput,
    default_channel_map,
    load_channel_map,
)
from daq.errors import (
    ChannelConfigError,
    DaqBufferOverflowError,
    DaqConnectionError,
    DaqError,
    DaqTimeoutError,
    DaqUnderflowError,
    EmergencyStopError,
)

__all__ = [
    "AnalogInput", "AnalogOutput", "AoCut", "ChannelConfigError", "ChannelKind", "ChannelMap",
    "DaqBackend", "DaqBufferOverflowError", "DaqConnectionError", "DaqError", "DaqTimeoutError",
    "DaqUnderflowError", "DeviceSpec", "DigitalOutput", "EmergencyStopError",
    "EmergencyStopInput", "default_channel_map", "load_channel_map",
]
