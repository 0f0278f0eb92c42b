"""Output-error fitting: parameters of the replayed model against measured responses.

The residual is measured minus simulated response on the training segments only, in units of the
RMS measured response (so tolerances mean the same for micrometres and volts), minimised with
`scipy.optimize.least_squares` (trust-region reflective, finite-difference Jacobian) over
parameters normalised by their typical scale. Several start points are tried where the error
surface has several minima (a mode's frequency); the best on training data wins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.model import Evaluator, Model, Param, residuals


@dataclass
class FitResult:
    model: Model
    train_sse: float  # [m^2]
    train_n: int
    nfev: int


def apply(model: Model, params: list[Param], values: np.ndarray) -> Model:
    for p, v in zip(params, values, strict=True):
        model = p.set(model, float(v))
    return model


def train_sse(ev: Evaluator, model: Model, train: list[Segment]) -> tuple[float, int]:
    r = residuals(ev, model, train).vector()
    return float(np.dot(r, r)), int(r.size)


def fit(ev: Evaluator, starts: list[Model], params: list[Param], train: list[Segment],
        scale_m: float, max_nfev: int | None = None, screen: bool = True) -> FitResult:
    """Fit ``params`` from each start model; return the best on training data.

    With ``screen`` and several starts, the starts are first ranked by their training error and
    only the best two are refined.
    """
    if not params:
        sse, n = train_sse(ev, starts[0], train)
        return FitResult(starts[0], sse, n, 1)
    if screen and len(starts) > 2:
        ranked = sorted(starts, key=lambda m: train_sse(ev, m, train)[0])
        starts = ranked[:2]
    best: FitResult | None = None
    nfev_total = 0
    for start in starts:
        x0 = np.array([p.get(start) for p in params], dtype=float)
        scales = np.array([p.scale for p in params], dtype=float)
        lo = np.array([(p.lo - x) / s if math.isfinite(p.lo) else -np.inf
                       for p, x, s in zip(params, x0, scales, strict=True)])
        hi = np.array([(p.hi - x) / s if math.isfinite(p.hi) else np.inf
                       for p, x, s in zip(params, x0, scales, strict=True)])
        # a start on a bound (e.g. friction 0) is nudged inside
        u0 = np.clip(np.zeros(len(params)), lo + 1e-6, hi - 1e-6)

        def fun(u: np.ndarray, _x0: np.ndarray = x0, _s: np.ndarray = scales,
                _start: Model = start) -> np.ndarray:
            m = apply(_start, params, _x0 + u * _s)
            return residuals(ev, m, train).vector() / scale_m

        res = least_squares(fun, u0, bounds=(lo, hi), method="trf", diff_step=1e-3,
                            x_scale=1.0, max_nfev=max_nfev or 12 * (len(params) + 1),
                            xtol=1e-6, ftol=1e-8, gtol=1e-10)
        nfev_total += int(res.nfev)
        model = apply(start, params, x0 + res.x * scales)
        sse, n = train_sse(ev, model, train)
        if best is None or sse < best.train_sse:
            best = FitResult(model, sse, n, 0)
    assert best is not None
    best.nfev = nfev_total
    return best


def arx_linear_guess(rec: RunRecord, segs: list[Segment]) -> tuple[float, float, float, float]:
    """Mass, damping, stiffness and force offset of a 1-DOF x axis from an equation-error fit.

    A second-order ARX model x[n] = a1 x[n-1] + a2 x[n-2] + b0 f[n] + b1 f[n-1] + b2 f[n-2] + c
    fitted by least squares; its poles give the natural frequency and damping, its static gain
    the stiffness. Biased by noise, so only a start for the output-error fit.

    Returns
    -------
    (mass_kg, damping_ns_per_m, stiffness_n_per_m, force_offset_n), in the run's units.
    """
    ch = next(c for c, a in rec.response_axis.items() if a == 0)
    rows, rhs = [], []
    for s in segs:
        x = rec.responses[ch][s.start:s.stop]
        f = rec.force_n[0, s.start:s.stop]
        if x.size < 8:
            continue
        rows.append(np.column_stack([x[1:-1], x[:-2], f[2:], f[1:-1], f[:-2],
                                     np.ones(x.size - 2)]))
        rhs.append(x[2:])
    if not rows:
        raise ValueError(f"{rec.name}: no training samples for the linear start estimate")
    a1, a2, b0, b1, b2, c = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    fs = rec.sample_rate_hz
    z = np.roots([1.0, -a1, -a2]).astype(complex)
    s = np.log(z) * fs
    wn2 = float(np.real(s[0] * s[1]))
    two_zeta_wn = float(-np.real(s[0] + s[1]))
    bsum = b0 + b1 + b2
    k = (1.0 - a1 - a2) / bsum
    if not (wn2 > 0 and k > 0 and two_zeta_wn > 0):
        raise ValueError(f"{rec.name}: the data do not look like a damped second-order system "
                         f"(ARX poles {z}); cannot start the fitted baseline")
    m = k / wn2
    return float(m), float(two_zeta_wn * m), float(k), float(c / bsum)
