"""Modes beyond the rig kernel's: linear modal superposition at the output.

The kernel (``rig_model.physics``) holds the housing's mode and, at most, the frame's. Where the
band holds more (a ground-vibration-test-like structure: several modes per axis), the fitted
baseline adds them here: the response of an axis is the kernel's plus, for each extra mode r on
that axis, the linear mode

    q_r'' + 2 zeta_r w_r q_r' + w_r^2 q_r = F_axis / m_r

driven by the force the kernel is driven by (measured force, offset included). Its displacement,
velocity and acceleration are added to the axis' rows. For a linear structure this is exact
(receptances add); where a nonlinear force acts (friction, the film, a joint) it is an
approximation: the extra modes do not see that force, and the kernel's mode does not see the
extra modes' motion.

Each mode is integrated exactly per sample: the second-order section discretised with a
first-order hold (the force linear between samples, as the kernel takes it), run by
``scipy.signal.lfilter``. A dwell replayed in steady state starts from the mode's exact periodic
steady state of the dwell's whole periods (a lightly damped mode would not forget its start
within the kernel's warm-up); any other window starts from rest, as the kernel does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.signal import cont2discrete, lfilter, ss2tf


@dataclass(frozen=True)
class ExtraMode:
    """One linear mode added at an axis' output: receptance 1 / (m (w_n^2 - w^2 + 2i zeta w_n
    w))."""

    axis: int  # 0 = x, 1 = y
    natural_hz: float
    damping_ratio: float
    modal_mass_kg: float

    def to_dict(self) -> dict[str, Any]:
        return {"axis": "xy"[self.axis], "natural_frequency_hz": self.natural_hz,
                "damping_ratio": self.damping_ratio, "modal_mass_kg": self.modal_mass_kg}


@lru_cache(maxsize=4096)
def _section(natural_hz: float, damping_ratio: float, modal_mass_kg: float,
             fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Numerators (3, 3: displacement, velocity, acceleration) and denominator of the mode's
    first-order-hold discretisation at ``fs``."""
    w = 2 * math.pi * natural_hz
    a = np.array([[0.0, 1.0], [-(w**2), -2 * damping_ratio * w]])
    b = np.array([[0.0], [1.0 / modal_mass_kg]])
    c = np.array([[1.0, 0.0], [0.0, 1.0], [-(w**2), -2 * damping_ratio * w]])
    d = np.array([[0.0], [0.0], [1.0 / modal_mass_kg]])
    ad, bd, cd, dd, _ = cont2discrete((a, b, c, d), 1.0 / fs, method="foh")
    num, den = ss2tf(ad, bd, cd, dd)
    return np.asarray(num, dtype=float), np.asarray(den, dtype=float)


def _periodic_state(b: np.ndarray, a: np.ndarray, chunk: np.ndarray) -> np.ndarray:
    """lfilter's state (direct form II transposed) that the filter returns to after ``chunk``:
    the steady state of ``chunk`` repeated for ever."""
    _, zf0 = lfilter(b, a, chunk, zi=np.zeros(2))
    # with no input the state moves by the companion matrix each sample
    comp = np.array([[-a[1] / a[0], 1.0], [-a[2] / a[0], 0.0]])
    m = np.linalg.matrix_power(comp, chunk.size)
    return np.linalg.solve(np.eye(2) - m, zf0)


def modal_response(force: np.ndarray, fs: float, modes: Sequence[ExtraMode],
                   periodic: int = 0) -> np.ndarray:
    """Displacement [m], velocity [m/s] and acceleration [m/s^2] (3, n) of the sum of ``modes``
    driven by ``force`` [N] sampled at ``fs`` [Hz]; from rest, or (``periodic`` > 0) from the
    steady state of the first ``periodic`` samples repeated (whole periods of a dwell)."""
    out = np.zeros((3, force.size))
    for md in modes:
        num, den = _section(md.natural_hz, md.damping_ratio, md.modal_mass_kg, fs)
        for row in range(3):
            zi = (_periodic_state(num[row], den, force[:periodic]) if periodic
                  else np.zeros(2))
            out[row] += lfilter(num[row], den, force, zi=zi)[0]
    return out

