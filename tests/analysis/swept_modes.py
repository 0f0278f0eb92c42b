"""An independent generator of swept-sine and multisine records of a structure with several modes
on one axis: two of them 0.2 Hz apart, and one that softens by 5 % from the lowest force level to
the highest (its stiffness lower at a higher force: a linear structure per level). Written from
the textbook with numpy alone; it shares no code with diagnose or the rig model (a test checks
its imports), and writes the canonical CSV an operator imports (``time_s, fx_N, x_m``).

The response is modal superposition, the receptance

    H(w) = sum_r 1 / (m_r (w_r^2 - w^2 + 2 i zeta_r w_r w)),

applied to the force's transform:
- a sweep (a linear chirp of constant amplitude, between quiet stretches, starting at rest): its
  transform over the record padded with zeros to four times its length, times H, back to time
  and cut to the record (the force is zero outside the record, so this is the structure's
  response from rest, not a periodic one; the tail after the sweep is ``TAIL_DECAYS`` times the
  slowest mode's decay time);
- a periodic multisine (every line of the band, random phases): each line times H over one
  period, the period repeated (the steady state).
White noise, seeded, on both channels (``NOISE_F_N``, ``NOISE_Z_M``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FS_HZ = 200.0
LEVELS_N = (1.0, 2.5, 6.0)  # force amplitudes [N] (a multisine's: RMS x sqrt 2)
NOISE_F_N = 0.02
NOISE_Z_M = 2e-7
BAND_HZ = (8.0, 22.0)
SWEEP_S = 60.0
LEAD_S = 2.0
TAIL_DECAYS = 12.0
MS_PERIOD_S = 40.0  # 0.025 Hz lines: four in each close mode's half-power band (0.1 Hz)
MS_PERIODS = 5


@dataclass(frozen=True)
class Mode:
    natural_hz: float  # at the lowest level
    damping_ratio: float
    modal_mass_kg: float
    #: relative change of the natural frequency from the lowest level to the highest (linear
    #: in log force)
    change: float = 0.0

    def at(self, level_n: float) -> float:
        """The natural frequency [Hz] at ``level_n``."""
        s = math.log(level_n / LEVELS_N[0]) / math.log(LEVELS_N[-1] / LEVELS_N[0])
        return self.natural_hz * (1.0 + s * self.change)


#: two modes 0.2 Hz apart (half-power bands 0.096 and 0.122 Hz: they overlap in no point), and
#: one softening 17.0 -> 16.15 Hz over the levels
MODES = (Mode(12.0, 0.004, 20.0), Mode(12.2, 0.005, 30.0), Mode(17.0, 0.010, 40.0, -0.05))


def receptance(f_hz: np.ndarray, level_n: float) -> np.ndarray:
    w = 2 * math.pi * np.asarray(f_hz, dtype=float)
    h = np.zeros(w.shape, dtype=complex)
    for m in MODES:
        wr = 2 * math.pi * m.at(level_n)
        h += 1.0 / (m.modal_mass_kg * (wr**2 - w**2 + 2j * m.damping_ratio * wr * w))
    return h


def sweep(level_n: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Force [N] and response [m] of a linear up-sweep over ``BAND_HZ`` in ``SWEEP_S``, with
    ``LEAD_S`` of rest before and the modes' decay after."""
    slowest = max(1.0 / (m.damping_ratio * 2 * math.pi * m.at(level_n)) for m in MODES)
    n = int((LEAD_S + SWEEP_S + TAIL_DECAYS * slowest) * FS_HZ)
    t = np.arange(n) / FS_HZ - LEAD_S
    f0, f1 = BAND_HZ
    on = (t >= 0) & (t <= SWEEP_S)
    force = np.where(on, level_n * np.sin(2 * math.pi * (f0 * t + 0.5 * (f1 - f0) / SWEEP_S
                                                         * t**2)), 0.0)
    pad = 4 * n
    spec = np.fft.rfft(force, pad) * receptance(np.fft.rfftfreq(pad, 1.0 / FS_HZ), level_n)
    z = np.fft.irfft(spec, pad)[:n]
    return (force + NOISE_F_N * rng.standard_normal(n),
            z + NOISE_Z_M * rng.standard_normal(n))


def multisine(level_n: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``MS_PERIODS`` periods of a random-phase multisine on every line of ``BAND_HZ``, RMS x
    sqrt 2 = ``level_n``, and the structure's steady state."""
    n = int(MS_PERIOD_S * FS_HZ)
    lines = np.arange(int(BAND_HZ[0] * MS_PERIOD_S), int(BAND_HZ[1] * MS_PERIOD_S) + 1)
    spec = np.zeros(n // 2 + 1, dtype=complex)
    spec[lines] = np.exp(1j * rng.uniform(0, 2 * math.pi, lines.size))
    f1 = np.fft.irfft(spec, n)
    z1 = np.fft.irfft(spec * np.concatenate([[0.0], receptance(
        np.arange(1, n // 2 + 1) / MS_PERIOD_S, level_n)]), n)
    scale = level_n / (math.sqrt(2.0) * float(np.std(f1)))
    total = n * MS_PERIODS
    return (np.tile(f1 * scale, MS_PERIODS) + NOISE_F_N * rng.standard_normal(total),
            np.tile(z1 * scale, MS_PERIODS) + NOISE_Z_M * rng.standard_normal(total))


def write_csv(force: np.ndarray, z: np.ndarray, path: Path) -> Path:
    t = np.arange(force.size) / FS_HZ
    np.savetxt(path, np.column_stack([t, force, z]), delimiter=",", header="time_s,fx_N,x_m",
               comments="", fmt="%.10g")
    return path
