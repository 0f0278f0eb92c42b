"""Several modes from the data: a modal fit of the receptance per level and axis, its order
chosen by the residual against the points' own noise.

Per level (``amplitude.levels``: runs, or groups of dwells of one amplitude) and driven axis,
the points are the dwells' 1X receptances ``H = Z / F`` (``residual_analysis.harmonics``), each
with the standard deviation its own noise gives it: the RMS the harmonic fit leaves of force
and response, over the dwell's N samples, is an amplitude error of ``sd * sqrt(2 / N)`` per
real component. The model is modal superposition,

    H(w) = sum_r A_r / (w_r^2 - w^2 + 2 i zeta_r w_r w),

with complex residues A_r (linear, solved for each set of poles: variable projection) and the
poles (w_r, zeta_r) by nonlinear least squares, weighted by the points' standard deviations.
Orders 1, 2, ... are fitted, each from the previous order's poles and a new pole where the
weighted residual is largest; the order kept is the one of least BIC
(``chi2 + n_params * ln(n_equations)``): a mode is added only while the residual it removes
stands above the points' noise (the search stops two orders past the least). Each mode has 4
real parameters; n modes need 4n + 1 dwell frequencies or more (twice as many equations as
parameters, and two to spare), so a level of five dwell frequencies fits one mode whatever its
residual.

Modes are followed over the levels by frequency (nearest within ``MATCH_RATIO``), from the
level with the most modes; the natural frequency and damping ratio of each against the level
are judged with `amplitude`'s trend rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from analysis.diagnose.amplitude import (
    DAMP_CHANGE,
    FREQ_CHANGE,
    Trend,
    levels,
    trend,
)
from analysis.diagnose.data import RunRecord, Segment, driven_axes
from analysis.diagnose.residual_analysis import harmonics
from analysis.diagnose.start import stands_above_noise

#: the most modes fitted per level and axis (a bound on the work, not on the data)
MAX_MODES = 8
#: a mode of one level is the same as one of the reference level within this frequency ratio
MATCH_RATIO = 1.15
#: damping ratios fitted between these (a pole outside is no mode of a structure)
ZETA_BOUNDS = (1e-4, 0.7)


@dataclass
class Mode:
    natural_hz: float
    natural_hz_sd: float
    damping_ratio: float
    damping_ratio_sd: float
    residue: complex  # A_r [m/N.s^-2]: w_r^2 A_r is the mode's static compliance share

    def to_dict(self) -> dict[str, Any]:
        return {"natural_frequency_hz": self.natural_hz,
                "natural_frequency_sd_hz": self.natural_hz_sd,
                "damping_ratio": self.damping_ratio, "damping_ratio_sd": self.damping_ratio_sd,
                "static_compliance_m_per_N": abs(self.residue) / (2 * math.pi
                                                                  * self.natural_hz) ** 2}


@dataclass
class LevelModes:
    """The modes of one axis at one level, and the order search that chose them."""

    label: str
    axis: str
    force_n: float  # median 1X force amplitude of the level's dwells [N]
    points: int
    modes: list[Mode]
    #: per order tried: modes, chi2 (weighted by the points' noise), BIC
    orders: list[dict[str, float]] = field(default_factory=list)

    @property
    def chi2_per_dof(self) -> float:
        row = next(r for r in self.orders if r["modes"] == len(self.modes))
        return row["chi2"] / max(1.0, 2 * self.points - 4 * len(self.modes))

    def to_dict(self) -> dict[str, Any]:
        return {"level": self.label, "axis": self.axis, "force_amplitude_N": self.force_n,
                "points": self.points,
                "modes": [m.to_dict() for m in self.modes],
                "chi2_per_dof": self.chi2_per_dof, "orders": self.orders}


@dataclass
class ModeTrack:
    """One mode followed over the levels of one axis."""

    axis: str
    index: int  # 1 = lowest frequency at the reference level
    levels: list[str]
    natural_hz: list[float]
    damping_ratio: list[float]
    frequency: Trend | None = None
    damping: Trend | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"axis": self.axis, "mode": self.index, "levels": self.levels,
                "natural_frequency_hz": self.natural_hz, "damping_ratio": self.damping_ratio,
                "natural_frequency_trend": self.frequency.to_dict() if self.frequency else None,
                "damping_trend": self.damping.to_dict() if self.damping else None}


@dataclass
class Modes:
    """Modes per level and axis, followed over the levels."""

    levels: list[LevelModes]
    tracks: list[ModeTrack]
    reason: str = ""
    skipped: list[str] = field(default_factory=list)  # levels whose fit failed, and why

    def per_axis(self) -> dict[str, int]:
        """The most modes found at any level, per axis."""
        out: dict[str, int] = {}
        for lv in self.levels:
            out[lv.axis] = max(out.get(lv.axis, 0), len(lv.modes))
        return out

    @property
    def text(self) -> str:
        if self.reason:
            return self.reason
        parts = []
        for ax, n in self.per_axis().items():
            rows = []
            for tr in (t for t in self.tracks if t.axis == ax):
                f = " -> ".join(f"{v:.4g}" for v in tr.natural_hz)
                z = " -> ".join(f"{100 * v:.2g}" for v in tr.damping_ratio)
                rows.append(f"{f} Hz (damping {z} %)")
            parts.append(f"{ax}: {n} mode{'s' if n > 1 else ''} ({'; '.join(rows)})")
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        return {"modes_per_axis": self.per_axis(), "levels": [lv.to_dict() for lv in self.levels],
                "tracks": [t.to_dict() for t in self.tracks], "not_fitted": self.skipped,
                "verdict": self.text}


# --- points ------------------------------------------------------------------------------
def receptance_points(records: list[RunRecord], segs: list[Segment],
                      axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angular frequencies [rad/s], 1X receptances Z/F [m/N] and their standard deviations
    per real component [m/N] from each dwell's own noise."""
    w, h, sd = [], [], []
    for seg in segs:
        rec = records[seg.run]
        chans = [v for c, v in rec.responses.items() if rec.response_axis[c] == axis]
        if not seg.freq_hz or not chans:
            continue
        fs, n = rec.sample_rate_hz, seg.n
        z = np.mean(chans, axis=0)[seg.start:seg.stop]
        zf, _, nf = harmonics(rec.force_n[axis, seg.start:seg.stop], seg.start, fs,
                              seg.freq_hz, 1)
        zz, _, nz = harmonics(z, seg.start, fs, seg.freq_hz, 1)
        if abs(zz[0]) == 0.0 or not stands_above_noise(abs(zf[0]), nf, n):
            continue  # the axis is not driven in this dwell
        hh = zz[0] / zf[0]
        scale = math.sqrt(2.0 / n) / abs(zf[0])
        w.append(2 * math.pi * seg.freq_hz)
        h.append(hh)
        sd.append(scale * math.hypot(nz, abs(hh) * nf))
    sd_arr = np.array(sd)
    # a noiseless channel (synthetic data) would weigh a point without bound
    floor = 1e-9 * float(np.max(np.abs(h))) if h else 0.0
    return np.array(w), np.array(h), np.maximum(sd_arr, floor)


# --- the fit -----------------------------------------------------------------------------
def _basis(w: np.ndarray, wr: np.ndarray, zr: np.ndarray) -> np.ndarray:
    return 1.0 / (wr[None, :] ** 2 - w[:, None] ** 2 + 2j * (zr * wr)[None, :] * w[:, None])


def _residues(w: np.ndarray, h: np.ndarray, sd: np.ndarray, wr: np.ndarray,
              zr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The complex residues for the poles (weighted least squares) and the weighted residual
    (real and imaginary parts stacked)."""
    b = _basis(w, wr, zr) / sd[:, None]
    a, *_ = np.linalg.lstsq(b, h / sd, rcond=None)
    r = b @ a - h / sd
    return a, np.concatenate([r.real, r.imag])


def _fit_poles(w: np.ndarray, h: np.ndarray, sd: np.ndarray, wr0: np.ndarray,
               zr0: np.ndarray, w_lim: tuple[float, float]) -> tuple[np.ndarray, float,
                                                                     np.ndarray | None]:
    """Poles (log w_r, log zeta_r) refined from the start, chi2, and their covariance."""
    lo = np.concatenate([np.full(wr0.size, math.log(w_lim[0])),
                         np.full(zr0.size, math.log(ZETA_BOUNDS[0]))])
    hi = np.concatenate([np.full(wr0.size, math.log(w_lim[1])),
                         np.full(zr0.size, math.log(ZETA_BOUNDS[1]))])
    x0 = np.clip(np.concatenate([np.log(wr0), np.log(zr0)]), lo + 1e-9, hi - 1e-9)
    m = wr0.size

    def fun(x: np.ndarray) -> np.ndarray:
        return _residues(w, h, sd, np.exp(x[:m]), np.exp(x[m:]))[1]

    res = least_squares(fun, x0, bounds=(lo, hi), x_scale="jac", ftol=1e-6, xtol=1e-6,
                        max_nfev=200 * (2 * m + 1))
    chi2 = float(np.sum(res.fun**2))
    dof = max(1, res.fun.size - 4 * m)
    try:
        cov = np.linalg.inv(res.jac.T @ res.jac) * max(1.0, chi2 / dof)
    except np.linalg.LinAlgError:
        cov = None
    return res.x, chi2, cov


def _new_pole(w: np.ndarray, h: np.ndarray, sd: np.ndarray, wr: np.ndarray,
              zr: np.ndarray) -> float:
    """Where the next pole starts: the frequency of the largest weighted residual."""
    if wr.size == 0:
        return float(w[np.argmax(np.abs(h))])
    _, r = _residues(w, h, sd, wr, zr)
    k = w.size
    return float(w[np.argmax(np.hypot(r[:k], r[k:]))])


def fit_modes(w: np.ndarray, h: np.ndarray, sd: np.ndarray,
              max_modes: int = MAX_MODES) -> tuple[list[Mode], list[dict[str, float]]]:
    """The modes of one set of receptance points, their order by BIC, and the order table."""
    order = np.argsort(w)
    w, h, sd = w[order], h[order], sd[order]
    n_eq = 2 * w.size
    w_lim = (float(w.min()) / 2, float(w.max()) * 2)
    # distinct frequencies: a repeated dwell adds no information on the number of poles
    top = min(max_modes, (np.unique(w).size - 1) // 4)
    rows: list[dict[str, float]] = []
    best: tuple[float, list[Mode]] | None = None
    best_n = 0
    wr, zr = np.zeros(0), np.zeros(0)
    for n in range(1, top + 1):
        w_new = _new_pole(w, h, sd, wr, zr)
        x, chi2, cov = _fit_poles(w, h, sd, np.append(wr, w_new), np.append(zr, 0.02), w_lim)
        wr, zr = np.exp(x[:n]), np.exp(x[n:])
        bic = chi2 + 4 * n * math.log(n_eq)
        rows.append({"modes": n, "chi2": chi2, "bic": bic})
        if best is None or bic < best[0]:
            best_n = n
            a, _ = _residues(w, h, sd, wr, zr)
            var = np.diag(cov) if cov is not None else np.full(2 * n, np.nan)
            modes = [Mode(float(wr[i] / (2 * math.pi)),
                          float(wr[i] / (2 * math.pi) * math.sqrt(max(var[i], 0.0))),
                          float(zr[i]), float(zr[i] * math.sqrt(max(var[n + i], 0.0))),
                          complex(a[i])) for i in range(n)]
            best = (bic, sorted(modes, key=lambda md: md.natural_hz))
        elif n >= best_n + 2:
            break  # two orders past the least BIC: more poles fit only the noise
    return (best[1] if best else []), rows


# --- over the levels ---------------------------------------------------------------------
def _track(axis: str, fits: list[LevelModes]) -> list[ModeTrack]:
    """Each mode of the reference level (most modes; the lowest level among equals) followed
    over the levels: the nearest mode within ``MATCH_RATIO`` in frequency, each used once."""
    ref = max(fits, key=lambda lv: len(lv.modes))
    tracks = []
    for i, m in enumerate(ref.modes):
        labs, fn, zt, fsd, zsd, lvl = [], [], [], [], [], []
        for lv in fits:
            near = [md for md in lv.modes
                    if max(md.natural_hz, m.natural_hz) / min(md.natural_hz, m.natural_hz)
                    <= MATCH_RATIO]
            if not near:
                continue
            md = min(near, key=lambda q: abs(math.log(q.natural_hz / m.natural_hz)))
            labs.append(lv.label)
            fn.append(md.natural_hz)
            zt.append(md.damping_ratio)
            fsd.append(md.natural_hz_sd)
            zsd.append(md.damping_ratio_sd)
            lvl.append(lv.force_n)
        tr = ModeTrack(axis, i + 1, labs, fn, zt)
        if len(labs) >= 2 and all(np.isfinite(fsd)) and all(np.isfinite(zsd)):
            x = np.log(lvl)
            tr.frequency = trend(x, np.array(fn), np.array(fsd), FREQ_CHANGE,
                                 ("hardening", "softening"))
            tr.damping = trend(x, np.array(zt), np.array(zsd), DAMP_CHANGE,
                               ("rising", "falling"))
        tracks.append(tr)
    return tracks


# small matrices: one BLAS thread (OpenBLAS's spinning threads cost 30x on a loaded machine)
@threadpool_limits.wrap(limits=1, user_api="blas")
def modal_dependence(records: list[RunRecord], segs: list[Segment]) -> Modes:
    """The modes of every driven axis at every level (or of all dwells as one level where
    there are no distinct levels), and each mode's natural frequency and damping against the
    level."""
    out = Modes([], [])
    for axis in (0, 1):
        lvls, _ = levels(records, segs, axis)
        if not lvls:
            lvls = [("all dwells", [s for s in segs if s.freq_hz and axis in driven_axes(
                records[s.run], s.start, s.stop)])]
        fits = []
        for lab, ss in lvls:
            w, h, sd = receptance_points(records, ss, axis)
            if w.size < 5:
                continue
            try:
                modes, rows = fit_modes(w, h, sd)
            except (np.linalg.LinAlgError, ValueError) as err:  # e.g. points not finite
                out.skipped.append(f"{'xy'[axis]} {lab}: modal fit failed: {err}")
                continue
            if not modes:
                continue
            f_amp = [abs(harmonics(records[s.run].force_n[axis, s.start:s.stop], s.start,
                                   records[s.run].sample_rate_hz, s.freq_hz, 1)[0][0])
                     for s in ss if s.freq_hz]
            fits.append(LevelModes(lab, "xy"[axis], float(np.median(f_amp)), int(w.size),
                                   modes, rows))
        out.levels.extend(fits)
        if fits:
            out.tracks.extend(_track("xy"[axis], fits))
    if not out.levels:
        out.reason = ("no modal fit: it needs 5 or more dwell frequencies on a driven axis"
                      + "".join(f"; {why}" for why in out.skipped))
    return out
