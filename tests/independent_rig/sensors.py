"""Sensors of the independent rig: what the instruments make of the true motion.

A sensor transform takes the sample times and a function that evaluates the clean channel at any
time, and returns the recorded samples: ``transform(t, clean) -> values``. Because ``clean`` can be
evaluated between samples, a delay is exact (``clean(t - tau)``), not an interpolation. Transforms
chain in the order given (``Sensors.transforms["x_m"] = [gain(1.05), delay(2e-4)]``). Noise is
added after every transform, from one seeded generator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

CleanSignal = Callable[[np.ndarray], np.ndarray]
SensorTransform = Callable[[np.ndarray, CleanSignal], np.ndarray]

#: The canonical CSV columns, in order.
COLUMNS = ("time_s", "freq_hz", "fx_N", "fy_N", "x_m", "y_m", "ax_mps2", "ay_mps2", "oil_temp_C")
SIGNALS = COLUMNS[2:]


def gain(ratio: float) -> SensorTransform:
    """Recorded = ratio x true (a calibration error)."""
    return lambda t, clean: ratio * clean(t)


def delay(tau_s: float) -> SensorTransform:
    """Recorded at t = true at t - tau (an inter-channel delay, e.g. an anti-alias filter)."""
    return lambda t, clean: clean(t - tau_s)


def offset(value: float) -> SensorTransform:
    """Recorded = true + a constant (a probe's gap voltage left in)."""
    return lambda t, clean: clean(t) + value


@dataclass
class Sensors:
    """Noise (standard deviation per channel, in the channel's units) and transforms.

    Defaults are of the order of the rig's instruments: probes 0.1 um, load cells 0.2 N,
    accelerometers 0.05 m/s^2, thermocouple 0.02 degC.
    """

    noise: dict[str, float] = field(default_factory=lambda: {
        "fx_N": 0.2, "fy_N": 0.2, "x_m": 1e-7, "y_m": 1e-7, "ax_mps2": 0.05, "ay_mps2": 0.05,
        "oil_temp_C": 0.02})
    transforms: dict[str, list[SensorTransform]] = field(default_factory=dict)
    seed: int = 0

    def record(self, name: str, t: np.ndarray, clean: CleanSignal,
               rng: np.random.Generator) -> np.ndarray:
        """Samples of channel ``name`` at times ``t`` [s]."""
        fn = clean
        for transform in self.transforms.get(name, []):
            fn = _bind(transform, fn)
        values = np.asarray(fn(t), dtype=np.float64)
        sigma = self.noise.get(name, 0.0)
        if sigma:
            values = values + rng.normal(0.0, sigma, size=values.shape)
        return values


def _bind(transform: SensorTransform, inner: CleanSignal) -> CleanSignal:
    return lambda tt: transform(tt, inner)
