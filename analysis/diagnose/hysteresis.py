"""The describing function of the library's hysteretic joint: what it adds per amplitude.

The joint (``joint_microslip``) is a Dahl element, ``dF/dz = k_j (1 - sgn(z') F / F_s)``: stuck it
adds its stiffness ``k_j``, slipping its force saturates at ``F_s``. Driven by ``z = A sin(theta)``
its steady force's fundamental, ``F1 = (K_eq + i K_loss) A``, is what an experimentalist reads
off a stepped sine at that amplitude: the equivalent stiffness ``K_eq`` (``k_j`` at small
amplitude, falling as the joint slips) and the loss stiffness ``K_loss`` (``4 F_s / (pi A)`` at
full slip; equivalent viscous damping ``K_loss / omega`` at frequency omega; energy dissipated
per cycle ``pi K_loss A^2``). The steady cycle has a closed form per branch (rising from
``-A``: ``F = F_s - (F_s + F_top) exp(-k_j (z + A) / F_s)``), sampled and projected on the
fundamental.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: points per half cycle (closed form per point: no integration error, only quadrature)
_POINTS = 2000


def dahl_describing_function(k_j: float, f_s: float, amplitude_m: float) -> tuple[float, float]:
    """Equivalent stiffness and loss stiffness [N/m] of a Dahl element at ``amplitude_m``."""
    if amplitude_m <= 0 or k_j <= 0 or f_s <= 0:
        return 0.0, 0.0
    theta = np.linspace(-math.pi / 2, 3 * math.pi / 2, 2 * _POINTS + 1)
    z = amplitude_m * np.sin(theta)
    # steady state: on the rising branch from -A, F starts at -F_top and rises towards F_s;
    # on the falling branch it mirrors. F_top solves F_top = F_s - (F_s + F_top) e^{-2 k A/F_s}
    g = math.exp(-2.0 * k_j * amplitude_m / f_s)
    f_top = f_s * (1 - g) / (1 + g)
    force = np.empty_like(z)
    rising = theta <= math.pi / 2
    force[rising] = f_s - (f_s + f_top) * np.exp(-k_j * (z[rising] + amplitude_m) / f_s)
    force[~rising] = -f_s + (f_s + f_top) * np.exp(-k_j * (amplitude_m - z[~rising]) / f_s)
    # the fundamental over the whole cycle (theta spans 2 pi, end point dropped)
    th, ff = theta[:-1], force[:-1]
    k_eq = float(2.0 * np.mean(ff * np.sin(th)) / amplitude_m)
    k_loss = float(2.0 * np.mean(ff * np.cos(th)) / amplitude_m)
    return k_eq, k_loss


def joint_table(k_j: float, f_s: float, amplitudes_m: list[float],
                freq_hz: float | None = None) -> list[dict[str, Any]]:
    """One row per amplitude: the joint's equivalent stiffness and loss stiffness (and, at
    ``freq_hz``, its equivalent viscous damping)."""
    rows = []
    for a in sorted(amplitudes_m):
        k_eq, k_loss = dahl_describing_function(k_j, f_s, a)
        row: dict[str, Any] = {"amplitude_m": a, "stiffness_N_per_m": k_eq,
                               "loss_stiffness_N_per_m": k_loss,
                               "energy_per_cycle_J": math.pi * k_loss * a * a}
        if freq_hz:
            row["damping_Ns_per_m_at_hz"] = {"freq_hz": freq_hz,
                                             "damping_Ns_per_m": k_loss / (2 * math.pi * freq_hz)}
        rows.append(row)
    return rows


#: sorted amplitudes split into levels where one exceeds the previous by this factor
LEVEL_GAP = 1.25


def amplitude_levels(amplitudes_m: list[float]) -> list[float]:
    """The levels of a set of dwell amplitudes [m]: sorted, split where one exceeds the previous
    by ``LEVEL_GAP``, the median of each group."""
    amps = sorted(a for a in amplitudes_m if a > 0)
    groups: list[list[float]] = []
    for a in amps:
        if groups and a <= LEVEL_GAP * groups[-1][-1]:
            groups[-1].append(a)
        else:
            groups.append([a])
    return [float(np.median(g)) for g in groups]
