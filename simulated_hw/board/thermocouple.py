"""Thermocouple channels on the simulated board (DAQmx ``CreateAIThrmcplChan``).

The channel is measured on the +/-1 V range and read as a temperature. On the input the wiring
map names a thermocouple (the rig's oil thermocouple, ``t_oil`` on ai12), it reads the rig's
temperature through that input's calibration (``(v - offset_v) / gain_v_per_unit``). Any other
input reads as a thermocouple would with that voltage on it: the cold junction at 25 C plus the
voltage over a type K Seebeck coefficient (41 uV/C), an approximation that makes an input at
rest read 25 C.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from daq.channels import ChannelMap
from daq.errors import INVALID_ATTRIBUTE_VALUE
from simulated_hw.board.codes import daq_error
from simulated_hw.board.tasks import SimChannel

DEG_C, DEG_F, KELVIN, DEG_R = 10143, 10144, 10325, 10145  # nidaqmx TemperatureUnits
CJC_C = 25.0  # the cold junction's temperature [C]
SEEBECK_V_PER_C = 41e-6  # type K near room temperature


def units(request: Any, where: str) -> int:
    unit = request.units_raw or DEG_C
    if unit not in (DEG_C, DEG_F, KELVIN, DEG_R):
        raise daq_error(INVALID_ATTRIBUTE_VALUE,
                        f"{where}: temperature units {unit} are not supported (C, F, K, R)")
    return int(unit)


def to_temperature(wiring: ChannelMap, ch: SimChannel, volts: np.ndarray) -> np.ndarray:
    """Volts on the channel's input -> its temperature in the channel's units."""
    wired = {c.physical_channel: c for c in wiring.ai}.get(ch.physical[0])
    if wired is not None and wired.kind == "thermocouple":
        celsius = (volts - wired.offset_v) / wired.gain_v_per_unit
    else:
        celsius = CJC_C + volts / SEEBECK_V_PER_C
    if ch.temperature_units == DEG_F:
        return celsius * 9 / 5 + 32
    if ch.temperature_units == KELVIN:
        return celsius + 273.15
    if ch.temperature_units == DEG_R:
        return (celsius + 273.15) * 9 / 5
    return celsius


def scale(wiring: ChannelMap, channels: list[SimChannel], data: np.ndarray) -> np.ndarray:
    """An AI read (n_ch, n) in volts, with its thermocouple channels' rows in temperature."""
    if not any(ch.temperature_units for ch in channels):
        return data
    out = data.copy()
    for row, ch in enumerate(channels):
        if ch.temperature_units:
            out[row] = to_temperature(wiring, ch, data[row])
    return out
