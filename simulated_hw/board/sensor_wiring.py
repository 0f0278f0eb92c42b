"""What the wiring puts on the AI terminals a task reads: the rig's sensor where the wiring has
one (with the range the task reads it with), the board's noise about 0 V where it has none."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from daq.channels import AnalogInput, ChannelMap, DeviceSpec


def sensors_on(wiring: ChannelMap, terminals: Sequence[tuple[str, tuple[float, float]]]
               ) -> tuple[list[AnalogInput], list[int | None]]:
    """The wiring's sensors on ``terminals`` (physical name, range read [V]) as the inputs a
    rig must produce, and per terminal its row among them (None: nothing wired there)."""
    wired = {c.physical_channel: c for c in wiring.ai}
    ai: list[AnalogInput] = []
    rows: list[int | None] = []
    for terminal, range_v in terminals:
        sensor = wired.get(terminal)
        rows.append(None if sensor is None else len(ai))
        if sensor is not None:
            ai.append(sensor.model_copy(update={"range_v": range_v}))
    return ai, rows


def floating(spec: DeviceSpec, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` samples of a terminal nothing is wired to: the board's noise about 0 V, one LSB
    rms, quantised to the LSB [V]."""
    lsb = 2 * spec.ai_range_v / 2**spec.ai_bits
    return np.round(rng.normal(0.0, lsb, n) / lsb) * lsb
