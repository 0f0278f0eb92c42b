"""The describing function of the library's hysteretic joint: what it adds per amplitude.

The joint (``joint_microslip``) is a Bouc-Wen element of exponent 1 with beta + gamma = 1:
``F = F_s w``, ``dw/dz = (k_j / F_s) (1 - (beta sgn(w z') + gamma) |w|)``, its ``shape``
``beta - gamma`` in [0, 1] (1: Dahl's law ``dF/dz = k_j (1 - sgn(z') F / F_s)``; 0: elastic
unloading at ``k_j``, the smooth seal that pre-slides and saturates). Stuck it adds its
stiffness ``k_j``, slipping its force saturates at ``F_s``. Driven by ``z = A sin(theta)`` its
steady force's fundamental, ``F1 = (K_eq + i K_loss) A``, is what an experimentalist reads off a
stepped sine at that amplitude: the equivalent stiffness ``K_eq`` (``k_j`` at small amplitude,
falling as the joint slips) and the loss stiffness ``K_loss`` (``4 F_s / (pi A)`` at full slip;
equivalent viscous damping ``K_loss / omega`` at frequency omega; energy dissipated per cycle
``pi K_loss A^2``). The steady cycle has a closed form per branch (the law is linear in ``w``
on each side of ``w = 0``), sampled and projected on the fundamental.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: points per half cycle (closed form per point: no integration error, only quadrature)
_POINTS = 2000
#: shapes below this are the elastic-unloading limit (avoids 0 / 0 in the closed form)
_ELASTIC_SHAPE = 1e-12


def _along_motion(u0: float, s: np.ndarray, shape: float) -> np.ndarray:
    """``u = sgn(z') F / F_s`` after moving ``s`` pre-sliding distances (``k_j |dz| / F_s``)
    from ``u0``: ``du/ds = 1 - shape u`` while unloading (``u < 0``), ``1 - u`` loading."""
    if u0 >= 0.0:
        return 1.0 - (1.0 - u0) * np.exp(-s)
    if shape > _ELASTIC_SHAPE:
        s0 = math.log1p(-shape * u0) / shape
        unload = u0 * np.exp(-shape * s) - np.expm1(-shape * s) / shape
    else:
        s0 = -u0
        unload = u0 + s
    return np.where(s <= s0, unload, 1.0 - np.exp(-np.maximum(s - s0, 0.0)))


def _steady_top(kappa_amp: float, shape: float) -> float:
    """``F_top / F_s`` of the steady cycle of amplitude A (``kappa_amp = k_j A / F_s``): the
    rising branch from ``-F_top`` at ``-A`` reaches ``+F_top`` at ``+A`` (bisection: the end
    falls as the start falls, the law being monotone in ``u``)."""
    lo, hi = 0.0, 1.0
    span = np.array([2.0 * kappa_amp])
    for _ in range(60):
        t = 0.5 * (lo + hi)
        if float(_along_motion(-t, span, shape)[0]) > t:
            lo = t
        else:
            hi = t
    return 0.5 * (lo + hi)


def joint_describing_function(k_j: float, f_s: float, amplitude_m: float,
                              shape: float = 1.0) -> tuple[float, float]:
    """Equivalent stiffness and loss stiffness [N/m] of the joint at ``amplitude_m``."""
    if amplitude_m <= 0 or k_j <= 0 or f_s <= 0:
        return 0.0, 0.0
    theta = np.linspace(-math.pi / 2, 3 * math.pi / 2, 2 * _POINTS + 1)
    z = amplitude_m * np.sin(theta)
    kappa = k_j / f_s
    t = _steady_top(kappa * amplitude_m, shape)
    # rising branch from -A; the falling branch is its mirror, F(z) = -F_rising(-z)
    rising = theta <= math.pi / 2
    force = np.empty_like(z)
    force[rising] = f_s * _along_motion(-t, kappa * (z[rising] + amplitude_m), shape)
    force[~rising] = -f_s * _along_motion(-t, kappa * (amplitude_m - z[~rising]), shape)
    # the fundamental over the whole cycle (theta spans 2 pi, end point dropped)
    th, ff = theta[:-1], force[:-1]
    k_eq = float(2.0 * np.mean(ff * np.sin(th)) / amplitude_m)
    k_loss = float(2.0 * np.mean(ff * np.cos(th)) / amplitude_m)
    return k_eq, k_loss


def joint_table(k_j: float, f_s: float, amplitudes_m: list[float],
                freq_hz: float | None = None, shape: float = 1.0) -> list[dict[str, Any]]:
    """One row per amplitude: the joint's equivalent stiffness and loss stiffness (and, at
    ``freq_hz``, its equivalent viscous damping)."""
    rows = []
    for a in sorted(amplitudes_m):
        k_eq, k_loss = joint_describing_function(k_j, f_s, a, shape)
        row: dict[str, Any] = {"amplitude_m": a, "stiffness_N_per_m": k_eq,
                               "loss_stiffness_N_per_m": k_loss,
                               "energy_per_cycle_J": math.pi * k_loss * a * a}
        if freq_hz:
            row["damping_Ns_per_m_at_hz"] = {"freq_hz": freq_hz,
                                             "damping_Ns_per_m": k_loss / (2 * math.pi * freq_hz)}
        rows.append(row)
    return rows


def describing_function_text(row: dict[str, Any]) -> str:
    """One `joint_table` row in words, for the CLI and the report."""
    text = (f"at {row['amplitude_m'] * 1e6:.3g} um: stiffness "
            f"{row['stiffness_N_per_m'] / 1e3:.4g} kN/m, loss stiffness "
            f"{row['loss_stiffness_N_per_m'] / 1e3:.4g} kN/m, "
            f"{row['energy_per_cycle_J'] * 1e3:.3g} mJ per cycle")
    damping = row.get("damping_Ns_per_m_at_hz")
    if damping:
        text += (f", equivalent damping {damping['damping_Ns_per_m']:.4g} N.s/m at "
                 f"{damping['freq_hz']:.3g} Hz")
    return text


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
