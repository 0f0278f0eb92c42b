"""Output-error fitting: parameters of the replayed model against measured responses.

The residual is measured minus simulated response on the training segments only, in units of the
RMS measured response (so tolerances mean the same for micrometres and volts), minimised with
a small Levenberg-Marquardt (finite-difference Jacobian, normal equations of size
k x k, bounds by projection) over parameters normalised by their typical scale: the residual
vectors are long (10^5 samples) and the parameters few, so the k x k normal equations keep the
linear algebra negligible next to the simulations. Several start points are tried where the error
surface has several minima (a mode's frequency); the best on training data wins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import ValidationError

from analysis.diagnose.data import DiagnoseError, RunRecord, Segment
from analysis.diagnose.model import Evaluator, Model, Param, residuals

#: what a fit on data can raise: a trial model the rig refuses (a parameter out of its range),
#: arithmetic out of range, a singular system (``fit_failure``)
_FIT_ERRORS = (ValidationError, ValueError, ArithmeticError, np.linalg.LinAlgError)


def fit_failure(err: BaseException) -> str | None:
    """Why a fit could not be made, for the report (None: ``err`` is no fit failure but a bad
    request, ``DiagnoseError``, or a bug, and must propagate). A candidate that cannot be
    fitted is reported as such, never a crash: the data are the user's, not ours to refuse."""
    if isinstance(err, DiagnoseError) or not isinstance(err, _FIT_ERRORS):
        return None
    first = str(err).strip().splitlines()
    return f"could not be fitted: {type(err).__name__}: {' '.join(first[:3])[:300]}"


@dataclass
class FitResult:
    model: Model
    train_sse: float  # [m^2]
    train_n: int
    nfev: int


def apply(model: Model, params: list[Param], values: np.ndarray) -> Model:
    """``model`` with each parameter set, held within its bounds: a fit at a bound comes back
    as x0 + ((lo - x0) / s) s, which rounding can put just outside (a joint stiffness of
    -2e-10 N/m that the rig's validation refuses)."""
    for p, v in zip(params, values, strict=True):
        model = p.set(model, min(max(float(v), p.lo), p.hi))
    return model


def _finite(r: np.ndarray) -> np.ndarray:
    # a diverging simulation (an unstable trial parameter) scores as a very bad fit; one pass
    # over the (10^5-sample) residual where it is all finite and in range, as it nearly always
    # is (NaN and inf fail the comparison)
    with np.errstate(invalid="ignore"):
        if r.size == 0 or float(np.max(np.abs(r))) <= 1e6:
            return r
    return np.nan_to_num(np.clip(r, -1e6, 1e6), nan=1e6)


def train_sse(ev: Evaluator, model: Model, train: list[Segment]) -> tuple[float, int]:
    r = residuals(ev, model, train).vector()
    with np.errstate(over="ignore", invalid="ignore"):
        sse = float(np.dot(r, r))
    return (sse if math.isfinite(sse) else math.inf), int(r.size)


@dataclass
class Following:
    """Parameters (a fitted baseline's) that follow a screened term to first order.

    Their Jacobian ``J`` (of the decimated, scaled training residual, per typical scale) is
    taken once at ``at``; a screened term is then fitted against the residual with ``J``'s
    column space projected out (what the followers cannot absorb), and the followers are moved
    by the Gauss-Newton step ``-J^+ r`` at its optimum. Without it a term that the linear
    baseline partly absorbed when it was fitted (a softening spring: a lower fitted stiffness)
    is judged against a baseline that already took its share of the data, and looks useless.
    """
    params: list[Param]
    q: np.ndarray  # orthonormal basis of J's columns (n x r)
    pinv: np.ndarray  # J^+ (k x n)

    def project(self, r: np.ndarray) -> np.ndarray:
        return r - self.q @ (self.q.T @ r)

    def follow(self, ev: Evaluator, model: Model, train: list[Segment], scale_m: float,
               step: int) -> Model:
        """``model`` with the followers moved by the Gauss-Newton step at ``model``."""
        r = _finite(residuals(ev, model, train).vector(step) / scale_m)
        du = -self.pinv @ r
        values = [p.get(model) + d * p.scale for p, d in zip(self.params, du, strict=True)]
        return apply(model, self.params, np.array(values))


def following(ev: Evaluator, at: Model, params: list[Param], train: list[Segment],
              scale_m: float, step: int, h: float = 1e-3) -> Following | None:
    """The first-order dependence of the training residual on ``params`` at model ``at``."""
    if not params:
        return None
    r0 = _finite(residuals(ev, at, train).vector(step) / scale_m)
    cols = []
    for p in params:
        x = p.get(at)
        d = h if x + h * p.scale <= p.hi else -h
        m = apply(at, [p], np.array([x + d * p.scale]))
        cols.append((_finite(residuals(ev, m, train).vector(step) / scale_m) - r0) / d)
    jac = np.column_stack(cols)
    u, sv, _ = np.linalg.svd(jac, full_matrices=False)
    rank = int(np.sum(sv > 1e-9 * max(float(sv[0]), 1e-300)))
    return Following(list(params), u[:, :rank], np.linalg.pinv(jac, rcond=1e-9))


def fit(ev: Evaluator, starts: list[Model], params: list[Param], train: list[Segment],
        scale_m: float, max_nfev: int | None = None, screen: bool = True,
        step: int = 1, keep: int = 1, follow: Following | None = None) -> FitResult:
    """Fit ``params`` from each start model; return the best on training data.

    With ``screen`` and more than ``keep`` starts, the starts are first ranked by their training
    error and only the best ``keep`` are refined. ``step`` decimates the residual vector
    (samples) the least-squares problem sees; the reported training error uses every sample.
    With ``follow``, its parameters follow ``params`` to first order (`Following`).
    """
    if not params:
        sse, n = train_sse(ev, starts[0], train)
        return FitResult(starts[0], sse, n, 1)

    def vec(m: Model) -> np.ndarray:
        r = _finite(residuals(ev, m, train).vector(step) / scale_m)
        return follow.project(r) if follow is not None else r

    if screen and len(starts) > keep:
        if follow is None:
            ranked = sorted(starts, key=lambda m: train_sse(ev, m, train)[0])
        else:
            ranked = sorted(starts, key=lambda m: float(np.sum(vec(m) ** 2)))
        starts = ranked[:keep]
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
            return vec(apply(_start, params, _x0 + u * _s))

        x_opt, nfev = levenberg_marquardt(fun, u0, lo, hi,
                                          max_nfev or 12 * (len(params) + 1))
        nfev_total += nfev
        model = apply(start, params, x0 + x_opt * scales)
        sse, n = train_sse(ev, model, train)
        if follow is not None:
            moved = follow.follow(ev, model, train, scale_m, step)
            sse_moved, _ = train_sse(ev, moved, train)
            if sse_moved < sse:
                model, sse = moved, sse_moved
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


def levenberg_marquardt(fun, u0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_nfev: int,
                        h: float = 1e-3, max_step: float = 5.0) -> tuple[np.ndarray, int]:
    """Minimise ``|fun(u)|^2`` over the box ``lo <= u <= hi``; return (u, evaluations).

    Forward differences of step ``h`` (backward at an upper bound); damping ``lam`` on the
    diagonal of J'J, raised on a failed step and lowered on a successful one; no step moves a
    parameter by more than ``max_step`` (units of its scale).
    """
    u = np.clip(np.asarray(u0, dtype=float), lo, hi)
    r = fun(u)
    cost = float(np.dot(r, r))
    nfev = 1
    lam = 1e-3
    k = u.size
    while nfev + k + 1 <= max_nfev:
        # column by column: Fortran order writes each column in one run of memory, and J'J
        # and J'r read it so (a third of the C order's time on a 10^5-sample residual)
        jac = np.empty((r.size, k), order="F")
        for j in range(k):
            step = h if u[j] + h <= hi[j] else -h
            du = u.copy()
            du[j] += step
            jac[:, j] = (fun(du) - r) / step
            nfev += 1
        a = jac.T @ jac
        g = jac.T @ r
        diag = np.maximum(np.diag(a), 1e-12 * max(np.max(np.diag(a)), 1e-300))
        improved = False
        while nfev < max_nfev:
            try:
                delta = np.linalg.solve(a + lam * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            big = float(np.max(np.abs(delta)))
            if big > max_step:  # trust region: at most max_step typical scales per step
                delta *= max_step / big
            u_new = np.clip(u + delta, lo, hi)
            r_new = fun(u_new)
            nfev += 1
            cost_new = float(np.dot(r_new, r_new))
            if cost_new < cost:
                rel = (cost - cost_new) / max(cost, 1e-300)
                moved = float(np.max(np.abs(u_new - u)))
                u, r, cost = u_new, r_new, cost_new
                lam = max(lam / 5, 1e-9)
                improved = True
                if rel < 1e-7 or moved < 1e-7:
                    return u, nfev
                break
            lam *= 5
            if lam > 1e8:
                break
        if not improved:
            break
    return u, nfev
