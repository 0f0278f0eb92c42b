"""Uncertainty of identified coefficients: the report's Appendix B (eq. B.1-B.8, B.11, B.17-B.19)
plus the scatter across repeated tests.

Conventions: U_x is a 95 % interval half-width in the units of x; relative values are named u_x.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

# Instrument uncertainties of Appendix B (relative, 95 %), used when a run does not say otherwise.
U_FORCE_REL = 0.01  # load cell linearity, 1 % (B.2.2)
U_DISPLACEMENT_REL = math.sqrt(7.84e-4)  # probe, 0.0008/0.03019 = 2.65 % (B.2.2)
U_FORCE_GAUGE_N = 0.5 * 4.4482216  # static tests: force gauge +/- 0.5 lb (section IV.1)
U_VOLTMETER_V = 0.001  # calibration voltmeter (B.1)
U_DIAL_GAUGE_M = 0.0001 * 0.0254  # dial gauge +/- 0.0001 in (B.1)
U_FLOWMETER_REL = 0.015  # flow meter bias, 1.5 % of reading (B.3)
U_PRESSURE_PA = 0.18 * 6894.757  # pressure reading, about 0.18 psig (B.3)


def t95(dof: int) -> float:
    """Student t for a two-sided 95 % interval with ``dof`` degrees of freedom (4.303 for 2)."""
    return float(stats.t.ppf(0.975, max(int(dof), 1)))


@dataclass(frozen=True)
class LineFit:
    """Least-squares line ``y = slope x + intercept`` with its goodness and errors."""

    slope: float
    intercept: float
    r2: float
    see: float  # standard error of estimate, eq. B.1 [y units]
    slope_se: float  # standard error of the slope
    intercept_se: float
    n: int
    x_range: float
    y_range: float


def line_fit(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray) -> LineFit:
    """Fit ``y = a x + b`` by least squares (needs 3 points or more for the SEE of eq. B.1)."""
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    n = xa.size
    if n < 3:
        raise ValueError(f"a line fit needs at least 3 points, got {n}")
    if np.ptp(xa) == 0:
        raise ValueError("a line fit needs at least two distinct x values")
    a, b = np.polyfit(xa, ya, 1)
    res = ya - (a * xa + b)
    ss_res = float(res @ res)
    ss_tot = float(((ya - ya.mean()) ** 2).sum())
    see = math.sqrt(ss_res / (n - 2))
    sxx = float(((xa - xa.mean()) ** 2).sum())
    slope_se = see / math.sqrt(sxx)
    intercept_se = see * math.sqrt(1.0 / n + xa.mean() ** 2 / sxx)
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    return LineFit(float(a), float(b), r2, see, slope_se, intercept_se, n,
                   float(np.ptp(xa)), float(np.ptp(ya)))


def linear_lstsq(a: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares ``y = a @ p``; returns (p, standard errors of p, r^2 about the mean of y).

    r^2 is the correlation of the fit (1 - SS_res / SS_tot), as the report's Table 4 and 6 quote.
    """
    a = np.asarray(a, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n, k = a.shape
    p, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ p
    ss_res = float(res @ res)
    ss_tot = float(((y - y.mean()) ** 2).sum())
    dof = max(n - k, 1)
    s2 = ss_res / dof
    try:
        cov = s2 * np.linalg.inv(a.T @ a)
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(k, np.nan)
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    return p, se, r2


def scatter_u95(values: Sequence[float]) -> float:
    """Precision error of the mean of repeated tests, ``t S_x / sqrt(N)`` (eq. B.6, B.17-B.19).

    0 for a single value (no repetition, no scatter information).
    """
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=np.float64)
    if v.size < 2:
        return 0.0
    return t95(v.size - 1) * float(v.std(ddof=1)) / math.sqrt(v.size)


def combine(*parts: float) -> float:
    """Root-sum-square of independent uncertainty parts (eq. B.3)."""
    return math.sqrt(sum(float(p) ** 2 for p in parts if np.isfinite(p)))


def probe_gain_u(fit: LineFit, u_voltmeter_v: float = U_VOLTMETER_V,
                 u_gauge_m: float = U_DIAL_GAUGE_M) -> float:
    """Relative uncertainty of a probe gain from its calibration line (eq. B.4-B.5).

    ``fit`` is volts against displacement (slope = gain [V/m]).
    """
    u_vfit = math.sqrt(fit.see**2 + u_voltmeter_v**2)  # eq. B.5
    return math.sqrt((u_gauge_m / fit.x_range) ** 2 + (u_vfit / fit.y_range) ** 2)  # eq. B.4


def static_stiffness_u(fit: LineFit, u_force_n: float, u_gain_rel: float,
                       u_avg_m: float = 0.0) -> float:
    """Relative uncertainty of a static stiffness (eq. B.7).

    ``fit`` is displacement [m] against force [N] (slope = 1/K). ``u_avg_m`` is the precision
    error of the averaged points (eq. B.6) combined into the displacement fit uncertainty.
    """
    u_dfit = math.sqrt(fit.see**2 + u_avg_m**2)
    return math.sqrt((u_force_n / fit.x_range) ** 2 + (u_dfit / fit.y_range) ** 2
                     + u_gain_rel**2)
