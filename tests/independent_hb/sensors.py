"""What the instruments make of the balanced motion: gain, delay, offset, noise, quantisation.

Every channel is a truncated Fourier series of the dwell's period, so it is evaluated exactly at
any time: a delay is ``clean(t - tau)``, never an interpolation. In order: the anti-alias
filter's group delay (the same on every channel, so no relative phase), a channel's own gain
and delay (the hidden probe faults), the probe's offset (its gap voltage left in), white noise,
then the board's quantisation (16 bits over +-10 V through each sensor's sensitivity).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: the canonical CSV's channels (what ``sfdrig import`` reads), in order
CHANNELS = ("fx_N", "fy_N", "x_m", "y_m", "ax_mps2", "ay_mps2", "oil_temp_C")
_LSB_V = 20.0 / 2**16


@dataclass(frozen=True)
class SensorModel:
    """Noise (standard deviation, channel units), quantisation step, offsets and probe faults.

    Probes: eddy-current, 7.87 V/mm, 0.25 um rms; load cells 22.5 mV/N, 0.3 N rms;
    accelerometers 100 mV/g, 0.08 m/s^2 rms; thermocouple 0.05 degC rms, 0.01 degC steps."""

    noise: dict[str, float] = field(default_factory=lambda: {
        "fx_N": 0.3, "fy_N": 0.3, "x_m": 0.25e-6, "y_m": 0.25e-6, "ax_mps2": 0.08,
        "ay_mps2": 0.08, "oil_temp_C": 0.05})
    step: dict[str, float] = field(default_factory=lambda: {
        "fx_N": _LSB_V / 22.5e-3, "fy_N": _LSB_V / 22.5e-3, "x_m": _LSB_V / 7.87e3,
        "y_m": _LSB_V / 7.87e3, "ax_mps2": _LSB_V / (0.1 / 9.80665),
        "ay_mps2": _LSB_V / (0.1 / 9.80665), "oil_temp_C": 0.01})
    offset: dict[str, float] = field(default_factory=lambda: {"x_m": 1.5e-6, "y_m": -0.8e-6})
    anti_alias_delay_s: float = 60e-6
    gain: dict[str, float] = field(default_factory=dict)
    delay_s: dict[str, float] = field(default_factory=dict)

    def sigma_total(self, name: str) -> float:
        """The channel's noise with its quantisation (uniform, step^2 / 12) [units]."""
        return float(np.hypot(self.noise.get(name, 0.0), self.step.get(name, 0.0) / 12**0.5))

    def lag_s(self, name: str) -> float:
        return self.anti_alias_delay_s + self.delay_s.get(name, 0.0)

    def measured_phasor(self, name: str, phasor: complex, omega: float) -> complex:
        """The fundamental the channel records of a true fundamental ``phasor``."""
        return complex(self.gain.get(name, 1.0) * phasor * np.exp(-1j * omega * self.lag_s(name)))

    def record(self, name: str, t_s: np.ndarray, harmonics: np.ndarray, omega: float,
               rng: np.random.Generator, extra: np.ndarray | None = None) -> np.ndarray:
        """Samples at ``t_s`` (the dwell's own time, phase 0 at 0) of the true series
        ``Re(sum_n harmonics[n] exp(i n omega t))``: a polynomial in exp(i omega t), summed by
        Horner's rule (one complex exponential a sample, not one a sample and harmonic);
        ``extra``: true samples added to it (an input at another frequency)."""
        z = np.exp(1j * omega * (t_s - self.lag_s(name)))
        clean = np.polyval(np.asarray(harmonics, dtype=np.complex128)[::-1], z).real
        if extra is not None:
            clean = clean + extra
        values = self.gain.get(name, 1.0) * clean + self.offset.get(name, 0.0)
        return self.finish(name, values, rng)

    def finish(self, name: str, values: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noise and quantisation on clean ``values``."""
        if sigma := self.noise.get(name, 0.0):
            values = values + rng.normal(0.0, sigma, size=values.shape)
        if step := self.step.get(name, 0.0):
            values = np.round(values / step) * step
        return values
