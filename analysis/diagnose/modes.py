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

Data that are not dwells (multisine, random; a run without dwells is cut into blocks) give
points from each run's contiguous stretches. Where the force repeats (a periodic multisine, four
periods or more): each line's mean over the whole periods, unwindowed (no leakage), with its
standard deviation from the periods' scatter (`_periodic_h`); Welch's Hann windows leak
between a multisine's lines and biased its H1 by up to 38 %. Otherwise the H1 estimate
``S_fz / S_ff`` by Welch (Hann, half overlapping) over 1/``BROADBAND_AVERAGES`` of the stretch,
a line's standard deviation per real component ``|H| sqrt(1 - g2) / (|g| sqrt(2 n_d))``
(Bendat & Piersol's random error; ``g2`` the coherence, ``n_d`` the independent averages), a
line a point only where its coherence stands above what uncorrelated noise reaches with
``n_d`` averages at ``Z_STRUCTURE`` standard deviations' probability (``1 - p^(1/(n_d - 1))``).
A swept sine is not stationary (each window sees its own band), so Welch's coherence says
nothing of its noise: a sweep that starts and ends at rest (the response decayed before the
record ends) is taken whole instead (`_swept_h`): the record's own transform, ``H = Z / F`` on
every line of the swept band, exact for a linear structure (the response of a force that is
zero outside the record is the record's circular convolution), each line's standard deviation
from the channels' noise in the record's quiet tail (white: a noise of sd s puts N s^2 on each
line of N samples). A sweep cut off while it plays (or before its response decays) is left out
with the reason. The level of broadband data is its force's RMS
times sqrt(2) (the amplitude of a sine of the same power); of a sweep, its amplitude while it
plays (the median of the force's envelope where it is half its largest or more).

A pole the fit finds is said to be a mode (``LevelModes.shown``) only where the points show it:
its damping ratio below 1 (from 1 on its poles are real: the response is overdamped, no
vibration, and is said as that; between 1/sqrt 2 and 1 the receptance has no peak, but the
pole pair still oscillates: a mode), its natural frequency among the
points' frequencies (a pole beyond them is an extrapolation: an overdamped film over 20-60 Hz
put one at 115 +- 49 Hz), a point within ``EVIDENCE_WIDTHS`` half-power half-widths of it (a
mode in a gap of the plan is the fit's guess of what lies between the points: the dry circular
programme's 20 Hz and 70-200 Hz put two at 22 and 41 Hz), and its frequency and damping
determined by the points (sd of its frequency under its half-power half-width, of its damping
under a third of it: ``T_MIN``). Every other pole is reported as no mode, with its frequency,
damping, their sd and the reason.

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
from scipy.signal import csd, hilbert, welch
from scipy.special import erfc
from threadpoolctl import threadpool_limits

from analysis.diagnose.amplitude import (
    DAMP_CHANGE,
    FREQ_CHANGE,
    T_MIN,
    Trend,
    levels,
    trend,
)
from analysis.diagnose.data import RunRecord, Segment, driven_axes
from analysis.diagnose.residual_analysis import harmonics
from analysis.diagnose.residual_structure import Z_STRUCTURE
from analysis.diagnose.start import stands_above_noise

#: the most modes fitted per level and axis (a bound on the work, not on the data)
MAX_MODES = 8
#: a mode of one level is the same as one of the reference level within this frequency ratio
MATCH_RATIO = 1.15
#: disjoint windows of a broadband H1 estimate: each is this fraction of the record (the
#: resolution against the random error, which falls as 1 / sqrt(n_d)). A mode whose half-power
#: band spans only a few lines is biased by the window (not modelled): with 16 on 640 s of a
#: 0.5 %-damped 7.3 Hz mode the bias stood above the noise and the fit added 2-3 modes for it;
#: with 4 the coherence is too uncertain to weigh the lines by
BROADBAND_AVERAGES = 8
#: a mode whose half-power band is narrower than this many Welch lines (the Hann window's
#: main lobe) has its damping biased by the window: said with the modes
WINDOW_LINES = 4
#: starts tried for each new pole (the largest peaks of the residual)
NEW_POLE_TRIES = 3
#: damping ratios fitted between these. The upper bound is above what this rig shows: lubricated,
#: it is overdamped (the report's VI.3: "highly over damped"; C_t / (2 sqrt(K M_t)) with the
#: film's eq. 16 5.1 kN.s/m, C_rv 370 N.s/m, the seal's 4 F_mu / (pi w |z|) and M_t = M + M_f + D
#: = 17.9 kg is 1.0 at 38 um and 60 Hz, 3.4 at 13 um and 20 Hz). A bound at 0.7 pinned such a
#: pole on it and called it a mode ("56.37 Hz (damping >= 70 %)"); fitted up to 10, the pole
#: says what the response is: no resonance
ZETA_BOUNDS = (1e-4, 10.0)
#: the damping ratios the order search starts and fits poles within: a pole it puts on this
#: bound is then refitted within ``ZETA_BOUNDS`` (a search over the wider range left a
#: five-mode random record's greedy path in a local minimum, with three spurious poles)
SEARCH_ZETA = 0.7
#: from this damping ratio on, a pole pair is two real poles: no vibration, an overdamped
#: response, no mode (below it, down to 1/sqrt 2, the receptance has no peak but the free
#: response still oscillates: the independent rig's linear film, 72 %, is a mode at 33.4 Hz)
OVERDAMPED_ZETA = 1.0
#: a mode is shown by the points only where one lies within this many half-power half-widths
#: (zeta f_n) of its natural frequency: there the mode's resonant part is at least 1/sqrt 5 of
#: its peak (a mode further from every point is the fit's guess of a gap)
EVIDENCE_WIDTHS = 2.0


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
    #: the lowest and highest frequency of the points [Hz]: a mode outside is extrapolated
    band_hz: tuple[float, float] = (0.0, math.inf)
    #: the points' frequencies [Hz] (the evidence a mode needs near it)
    freqs_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def in_band(self, mode: Mode) -> bool:
        """The mode's natural frequency lies among the points' frequencies."""
        return self.band_hz[0] <= mode.natural_hz <= self.band_hz[1]

    def why_not(self, mode: Mode) -> list[str]:
        """Why the points do not show ``mode`` as a mode (empty: they do); see the module
        doc."""
        f, z = mode.natural_hz, mode.damping_ratio
        lo, hi = self.band_hz
        if z >= OVERDAMPED_ZETA:
            return ["overdamped: no resonance"]
        why = []
        if not self.in_band(mode):
            why.append(f"extrapolated {'above' if f > hi else 'below'} the points' "
                       f"{lo:.4g}-{hi:.4g} Hz")
        elif self.freqs_hz.size and not np.any(
                np.abs(self.freqs_hz - f) <= EVIDENCE_WIDTHS * z * f):
            below = self.freqs_hz[self.freqs_hz < f]
            above = self.freqs_hz[self.freqs_hz > f]
            why.append(f"between the points at {below.max():.4g} and {above.min():.4g} Hz, "
                       f"none within its half-power band")
        if _on_bound(z):
            why.append("its damping on the fit's bound")
        if not (mode.natural_hz_sd < z * f and mode.damping_ratio_sd < z / T_MIN):
            why.append("not determined by the points")
        return why

    def shown(self, mode: Mode) -> bool:
        """The points show ``mode``: resonant, among them, near one and determined."""
        return not self.why_not(mode)

    @property
    def dof(self) -> float:
        return max(1.0, 2 * self.points - 4 * len(self.modes))

    @property
    def chi2_per_dof(self) -> float:
        row = next(r for r in self.orders if r["modes"] == len(self.modes))
        return row["chi2"] / self.dof

    @property
    def linear(self) -> bool:
        """The fit leaves the points at their noise: its chi2 per degree of freedom within
        ``Z_STRUCTURE`` of its sd (sqrt(2 / dof)) of 1. Where it does not (a nonlinear force:
        the dry seal's friction left 2e6 x the noise over 20-200 Hz), no order of modes
        describes the points, and their poles' sd say so."""
        return self.chi2_per_dof <= 1.0 + Z_STRUCTURE * math.sqrt(2.0 / self.dof)

    def to_dict(self) -> dict[str, Any]:
        return {"level": self.label, "axis": self.axis, "force_amplitude_N": self.force_n,
                "points": self.points, "band_hz": list(self.band_hz),
                "modes": [{**m.to_dict(), "in_band": self.in_band(m), "shown": self.shown(m),
                           "why_not": self.why_not(m)} for m in self.modes],
                "chi2_per_dof": self.chi2_per_dof, "orders": self.orders}


def _on_bound(zeta: float) -> bool:
    return not ZETA_BOUNDS[0] * (1 + 1e-6) < zeta < ZETA_BOUNDS[1] * (1 - 1e-6)


def _pole_text(m: Mode, why: list[str]) -> str:
    return (f"{m.natural_hz:.4g} +- {m.natural_hz_sd:.2g} Hz, damping ratio "
            f"{m.damping_ratio:.2g} +- {m.damping_ratio_sd:.2g} ({', '.join(why)})")


@dataclass
class ModeTrack:
    """One pole of the reference level followed over the levels of one axis."""

    axis: str
    index: int  # 1 = lowest frequency at the reference level
    levels: list[str]
    natural_hz: list[float]
    damping_ratio: list[float]
    frequency: Trend | None = None
    damping: Trend | None = None
    #: the reference level's band [Hz]
    band_hz: tuple[float, float] = (0.0, math.inf)
    #: why the reference level's points do not show the pole as a mode (empty: a mode)
    why_not: list[str] = field(default_factory=list)
    reference: Mode | None = None  # the pole at the reference level

    @property
    def shown(self) -> bool:
        return not self.why_not

    @property
    def in_band(self) -> bool:
        return self.band_hz[0] <= self.natural_hz[0] <= self.band_hz[1] if self.natural_hz \
            else False

    @property
    def extrapolation_text(self) -> str:
        """A pole that is no mode, with its uncertainty and why it is none."""
        m = self.reference or Mode(self.natural_hz[0], math.nan, self.damping_ratio[0],
                                   math.nan, 0j)
        return _pole_text(m, self.why_not)

    def to_dict(self) -> dict[str, Any]:
        return {"axis": self.axis, "mode": self.index, "levels": self.levels,
                "shown": self.shown, "why_not": self.why_not, "band_hz": list(self.band_hz),
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
    cautions: list[str] = field(default_factory=list)  # modes the estimate may bias, and why

    def per_axis(self) -> dict[str, int]:
        """The most modes the points show (``LevelModes.shown``) at any level, per axis."""
        out: dict[str, int] = {}
        for lv in self.levels:
            out[lv.axis] = max(out.get(lv.axis, 0), sum(map(lv.shown, lv.modes)))
        return out

    def damped(self, axis: str) -> list[tuple[LevelModes, Mode]]:
        """The levels of ``axis`` whose fit holds a pole with no resonance (damping ratio
        1 or more: overdamped), with that pole."""
        return [(lv, m) for lv in self.levels if lv.axis == axis for m in lv.modes
                if m.damping_ratio >= OVERDAMPED_ZETA]

    @property
    def text(self) -> str:
        if self.reason:
            return self.reason
        parts = []
        for ax, n in self.per_axis().items():
            rows = []
            for tr in (t for t in self.tracks if t.axis == ax and t.shown):
                f = " -> ".join(f"{v:.4g}" for v in tr.natural_hz)
                z = " -> ".join(f"{100 * v:.2g}" for v in tr.damping_ratio)
                rows.append(f"{f} Hz (damping {z} %)")
            text = (f"{ax}: {n or 'no'} mode{'' if n <= 1 else 's'}"
                    + (f" ({'; '.join(rows)})" if rows else ""))
            damped = self.damped(ax)
            if damped:
                n_lv = len({id(lv) for lv in self.levels if lv.axis == ax})
                zs = ", ".join(f"{m.damping_ratio:.2g} +- {m.damping_ratio_sd:.2g}"
                               + (f" ({lv.label})" if n_lv > 1 else "") for lv, m in damped)
                text += ("; overdamped, no resonance in "
                         f"the band at {len({id(lv) for lv, _ in damped})} of {n_lv} "
                         f"level{'' if n_lv == 1 else 's'} (a pole's damping ratio {zs})")
            text += "".join(f"; no mode: a pole at {t.extrapolation_text}"
                            for t in self.tracks if t.axis == ax and not t.shown
                            and t.reference is not None
                            and t.reference.damping_ratio < OVERDAMPED_ZETA)
            worst = max((lv for lv in self.levels if lv.axis == ax),
                        key=lambda lv: lv.chi2_per_dof)
            if not worst.linear:
                text += (f"; the fit leaves {worst.chi2_per_dof:.2g} x the points' noise "
                         f"(chi2 per degree of freedom, {worst.label}): the receptance is not "
                         "a linear structure's")
            parts.append(text)
        return "; ".join(parts + [f"not fitted: {why}" for why in self.skipped]
                         + [f"caution: {why}" for why in self.cautions])

    def to_dict(self) -> dict[str, Any]:
        return {"modes_per_axis": self.per_axis(), "levels": [lv.to_dict() for lv in self.levels],
                "tracks": [t.to_dict() for t in self.tracks], "not_fitted": self.skipped,
                "cautions": self.cautions, "verdict": self.text}


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


def _stretches(segs: list[Segment]) -> list[tuple[int, int, int]]:
    """The segments that are not dwells, merged where contiguous: (run, start, stop)."""
    out: list[tuple[int, int, int]] = []
    for seg in sorted((s for s in segs if not s.freq_hz), key=lambda s: (s.run, s.start)):
        if out and out[-1][0] == seg.run and out[-1][2] == seg.start:
            out[-1] = (seg.run, out[-1][1], seg.stop)
        else:
            out.append((seg.run, seg.start, seg.stop))
    return out


def _period(f: np.ndarray) -> int:
    """The force's period in samples where it repeats (a periodic multisine, repeated sweeps),
    else 0: the first lag whose autocorrelation exceeds 1/2 (the repeating part carries more
    power than the rest), at a local maximum, and still does at the largest multiple of it
    within half the record (narrowband noise decorrelates over lags; a periodic signal does
    not)."""
    n = f.size
    spec = np.fft.rfft(f, 2 * n)
    acf = np.fft.irfft(np.abs(spec) ** 2)[: n // 2 + 1]
    if acf[0] <= 0:
        return 0
    lags = np.arange(acf.size)
    r = acf / (n - lags) / (acf[0] / n)
    for lag in range(64, n // 2):
        if r[lag] > 0.5 and r[lag] >= r[lag - 1] and r[lag] >= r[lag + 1]:
            m = (n // 2) // lag
            return lag if r[m * lag] > 0.5 else 0
    return 0


def _swept(f: np.ndarray, fs: float, nper: int) -> bool:
    """Whether the force's spectrum moves over the record (a swept sine): the centroid of its
    power in the record's first quarter and in its last differ by more than a quarter of the
    band that holds 90 % of the record's power (a stationary signal's centroid moves by its
    estimate's scatter only, a sweep's by most of its band)."""
    q = f.size // 4
    if q < nper:
        return False
    fa, p_all = welch(f, fs, nperseg=nper)
    cum = np.cumsum(p_all) / max(float(np.sum(p_all)), 1e-300)
    band = float(fa[np.searchsorted(cum, 0.95)] - fa[np.searchsorted(cum, 0.05)])
    centroids = []
    for part in (f[:q], f[-q:]):
        _, pp = welch(part, fs, nperseg=nper)
        centroids.append(float(np.sum(fa * pp) / max(float(np.sum(pp)), 1e-300)))
    return abs(centroids[1] - centroids[0]) > 0.25 * band


#: lines over which a periodic record's noise variances are pooled (noise spectra are smooth;
#: one line's variance from a few periods is itself too uncertain to weigh it by)
POOL_LINES = 11


def _significant(p_sd: float = Z_STRUCTURE) -> float:
    """The one-sided probability of a normal deviate beyond ``p_sd`` standard deviations."""
    return 0.5 * float(erfc(p_sd / math.sqrt(2.0)))


def _periodic_h(f: np.ndarray, z: np.ndarray, fs: float,
                period: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H over the whole periods: each line's mean force and response over the periods, their
    ratio, and its standard deviation per real component from the periods' scatter
    (linearised: var H = (var Z + |H|^2 var F - 2 Re(conj(H) cov(Z, F))) / |F|^2 of the means,
    the variances pooled over ``POOL_LINES``). A line is a point where its mean force stands
    ``Z_STRUCTURE`` standard deviations above that scatter: the lines the multisine excites."""
    k = f.size // period
    ff = np.fft.rfft(f[: k * period].reshape(k, period), axis=1)
    zz = np.fft.rfft(z[: k * period].reshape(k, period), axis=1)
    fm, zm = ff.mean(axis=0), zz.mean(axis=0)
    df, dz = ff - fm, zz - zm
    pool = np.ones(POOL_LINES) / POOL_LINES

    def pooled(x: np.ndarray) -> np.ndarray:  # the variance of a line's mean over the periods
        return np.convolve(x, pool, mode="same") / (k * (k - 1))

    var_f = pooled(np.sum(np.abs(df) ** 2, axis=0))
    var_z = pooled(np.sum(np.abs(dz) ** 2, axis=0))
    cov_zf = (np.convolve(np.sum(dz * np.conj(df), axis=0).real, pool, mode="same")
              / (k * (k - 1)))
    lines = np.arange(fm.size)
    good = (lines > 0) & (np.abs(fm) > Z_STRUCTURE * np.sqrt(var_f / 2.0))
    h = zm[good] / fm[good]
    var_h = (var_z[good] + np.abs(h) ** 2 * var_f[good]
             - 2.0 * (np.conj(h) * cov_zf[good]).real) / np.abs(fm[good]) ** 2
    return 2 * math.pi * lines[good] * fs / period, h, np.sqrt(np.maximum(var_h, 0.0) / 2.0)


def _welch_h(f: np.ndarray, z: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray,
                                                              np.ndarray]:
    """H1 by Welch (Hann, half overlapping, ``BROADBAND_AVERAGES`` independent averages), its
    random error from the coherence, on the lines whose coherence stands above what
    uncorrelated signals reach with ``Z_STRUCTURE`` standard deviations' probability."""
    nper = f.size // BROADBAND_AVERAGES
    fa, s_ff = welch(f, fs, nperseg=nper)
    _, s_zz = welch(z, fs, nperseg=nper)
    _, s_fz = csd(f, z, fs, nperseg=nper)
    # half-overlapping Hann windows: 2 n - 1 of them, worth n_windows / (1 + 2 c^2) independent
    # ones (c = 0.167, the correlation of neighbouring Hann windows' estimates: Welch 1967)
    n_d = (2 * BROADBAND_AVERAGES - 1) / (1.0 + 2 * 0.167**2)
    g2 = np.abs(s_fz) ** 2 / np.maximum(s_ff * s_zz, 1e-300)
    good = (fa > 0) & (g2 > 1.0 - _significant() ** (1.0 / (n_d - 1))) & (g2 < 1.0)
    h = s_fz[good] / s_ff[good]
    err = np.sqrt(1.0 - g2[good]) / (np.sqrt(g2[good]) * math.sqrt(2.0 * n_d))
    return 2 * math.pi * fa[good], h, np.abs(h) * err


#: the share of a sweep's force power outside which its band lies (each side)
SWEEP_TAIL = 0.005
#: a sweep is taken whole only where it starts at rest and its response has decayed by the
#: record's end (what is left there wraps into the transform): the response's RMS over the first
#: ``SWEEP_QUIET`` of the stretch, and the force's and the response's over the last
#: ``NOISE_TAIL``, within ``QUIET_RATIO`` times their noise beyond the sweep's band. That tail,
#: where nothing plays, gives the channels' noise (the spectrum beyond the band holds the
#: sweep's own side lobes: it put a 6 N sweep's force noise 13 % high, its chi2 at 0.5 per
#: degree of freedom)
SWEEP_QUIET = 0.005
NOISE_TAIL = 0.05
QUIET_RATIO = 3.0


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def _swept_h(f: np.ndarray, z: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray,
                                                              np.ndarray, float] | None:
    """H of a sweep taken whole: the record's transforms' ratio on the lines of the band that
    holds all but ``SWEEP_TAIL`` of the force's power at each side, where the force stands
    ``Z_STRUCTURE`` sd above its noise; each line's sd per real component from the force's
    and the response's noise in the record's quiet tail (white: a noise of sd s puts n s^2 on
    each line of n samples); and the sweep's amplitude. None where the sweep or its response
    does not start and end at the noise (not a whole sweep)."""
    n = f.size
    ff, zz = np.fft.rfft(f), np.fft.rfft(z)
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    pf = np.abs(ff) ** 2
    cum = np.cumsum(pf) / max(float(np.sum(pf)), 1e-300)
    lo = float(freqs[int(np.searchsorted(cum, SWEEP_TAIL))])
    hi = float(freqs[min(int(np.searchsorted(cum, 1.0 - SWEEP_TAIL)), freqs.size - 1)])
    # the noise's white level beyond the band (a margin of a quarter of the band: the median
    # of an exponential variable is ln 2 of its mean; rare harmonics pass under the median)
    out = freqs > hi + 0.25 * (hi - lo)
    tail = max(16, int(NOISE_TAIL * n))
    if np.count_nonzero(out) < 32 or tail > n // 4:
        return None
    sd_f = math.sqrt(float(np.median(pf[out])) / math.log(2.0) / n)
    sd_z = math.sqrt(float(np.median(np.abs(zz[out]) ** 2)) / math.log(2.0) / n)
    head = max(16, int(SWEEP_QUIET * n))
    if not (_rms(z[:head]) <= QUIET_RATIO * sd_z and _rms(z[-tail:]) <= QUIET_RATIO * sd_z
            and _rms(f[-tail:]) <= QUIET_RATIO * sd_f):
        return None
    var_f = n * float(np.var(f[-tail:]))  # per line, both components
    var_z = n * float(np.var(z[-tail:]))
    good = (freqs >= lo) & (freqs <= hi) & (np.abs(ff) > Z_STRUCTURE * math.sqrt(var_f / 2.0))
    h = zz[good] / ff[good]
    sd = np.sqrt((var_z + np.abs(h) ** 2 * var_f) / 2.0) / np.abs(ff[good])
    env = np.abs(hilbert(f))
    amp = float(np.median(env[env >= 0.5 * env.max()]))
    return 2 * math.pi * freqs[good], h, sd, amp


@dataclass
class BroadbandPoints:
    """Receptance points of broadband data."""

    w: np.ndarray  # angular frequencies [rad/s]
    h: np.ndarray  # receptances [m/N]
    sd: np.ndarray  # standard deviations per real component [m/N]
    force_n: float  # the force's RMS x sqrt 2 [N]
    window_hz: float  # the Welch lines' spacing (0: whole periods only, no window)


def broadband_points(records: list[RunRecord], segs: list[Segment], axis: int,
                     why_not: list[str] | None = None) -> BroadbandPoints:
    """The receptance of the segments that are not dwells (see the module doc). A swept run
    that does not start and end at rest is left out (with a reason in ``why_not``)."""
    w_all: list[np.ndarray] = []
    h_all: list[np.ndarray] = []
    sd_all: list[np.ndarray] = []
    power, count, window_hz = 0.0, 0, 0.0
    for run, a, b in _stretches(segs):
        rec = records[run]
        chans = [v for c, v in rec.responses.items() if rec.response_axis[c] == axis]
        if not chans or (b - a) // BROADBAND_AVERAGES < 64:
            continue
        fs = rec.sample_rate_hz
        f = rec.force_n[axis, a:b] - np.mean(rec.force_n[axis, a:b])
        if not np.any(f):
            continue
        z = np.mean(chans, axis=0)[a:b]
        z = z - np.mean(z)
        period = _period(f)
        if period and f.size // period >= 4:  # whole periods: no leakage, the periods average
            w, h, sd = _periodic_h(f, z, fs, period)
        elif _swept(f, fs, f.size // BROADBAND_AVERAGES):
            # diagnose does not score an imported run's first samples (the replay's start is
            # unknown there): the sweep's transform wants them, its rest before the sweep.
            # From the last dwell's end before it (or the run's start) where it is not whole
            a0 = max((s.stop for s in segs if s.run == run and s.freq_hz and s.stop <= a),
                     default=0)
            whole = None
            for start in dict.fromkeys((a, a0)):
                f0 = rec.force_n[axis, start:b] - np.mean(rec.force_n[axis, start:b])
                z0 = np.mean(chans, axis=0)[start:b]
                whole = _swept_h(f0, z0 - np.mean(z0), fs)
                if whole is not None:
                    break
            if whole is None:
                if why_not is not None:
                    why_not.append(f"{rec.name} [{a}:{b}]: a swept sine (its spectrum moves) "
                                   "that does not start and end at rest (force and response at "
                                   "their noise): its transform is not the structure's, and "
                                   "its coherence says nothing of its noise: not in the modal "
                                   "fit")
                continue
            w, h, sd, amp = whole
            w_all.append(w)
            h_all.append(h)
            sd_all.append(sd)
            # its level: the amplitude while it plays, as the power of a sine of it
            power += 0.5 * amp**2 * f0.size
            count += f0.size
            continue
        else:
            w, h, sd = _welch_h(f, z, fs)
            window_hz = max(window_hz, fs / (f.size // BROADBAND_AVERAGES))
        w_all.append(w)
        h_all.append(h)
        sd_all.append(sd)
        power += float(np.sum(f**2))
        count += f.size
    if not w_all:
        return BroadbandPoints(np.zeros(0), np.zeros(0, dtype=complex), np.zeros(0), 0.0, 0.0)
    return BroadbandPoints(np.concatenate(w_all), np.concatenate(h_all), np.concatenate(sd_all),
                           math.sqrt(2.0 * power / count), window_hz)


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
               zr0: np.ndarray, w_lim: tuple[float, float],
               zeta_hi: float = SEARCH_ZETA) -> tuple[np.ndarray, float, np.ndarray | None]:
    """Poles (log w_r, log zeta_r) refined from the start, chi2, and their covariance."""
    lo = np.concatenate([np.full(wr0.size, math.log(w_lim[0])),
                         np.full(zr0.size, math.log(ZETA_BOUNDS[0]))])
    hi = np.concatenate([np.full(wr0.size, math.log(w_lim[1])),
                         np.full(zr0.size, math.log(zeta_hi))])
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


def _new_poles(w: np.ndarray, h: np.ndarray, sd: np.ndarray, wr: np.ndarray,
               zr: np.ndarray, tries: int = NEW_POLE_TRIES) -> list[float]:
    """Where the next pole may start: the frequencies of the largest local maxima of the
    weighted residual (of |H| for the first pole), largest first."""
    if wr.size == 0:
        mag = np.abs(h)
    else:
        _, r = _residues(w, h, sd, wr, zr)
        mag = np.hypot(r[: w.size], r[w.size:])
    inner = (mag[1:-1] >= mag[:-2]) & (mag[1:-1] >= mag[2:])
    peaks = np.concatenate([[0] if mag[0] >= mag[min(1, mag.size - 1)] else [],
                            np.flatnonzero(inner) + 1,
                            [mag.size - 1] if mag[-1] > mag[max(mag.size - 2, 0)] else []])
    peaks = peaks.astype(int)
    best = peaks[np.argsort(mag[peaks])[::-1]][:tries]
    return [float(w[i]) for i in best] or [float(w[np.argmax(mag)])]


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
        # the new pole from a few starts (a greedy start alone fell into a local minimum on a
        # five-mode multisine: order 5 at chi2 3e7 where the five true modes give 500)
        fits = [_fit_poles(w, h, sd, np.append(wr, w_new), np.append(zr, 0.02), w_lim)
                for w_new in _new_poles(w, h, sd, wr, zr)]
        x, chi2, cov = min(fits, key=lambda fit: fit[1])
        if np.any(np.exp(x[n:]) >= SEARCH_ZETA * (1 - 1e-6)):
            # a pole on the search's bound: free to say it is overdamped
            wide = _fit_poles(w, h, sd, np.exp(x[:n]), np.exp(x[n:]), w_lim, ZETA_BOUNDS[1])
            if wide[1] <= chi2:
                x, chi2, cov = wide
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
    """Each pole of the reference level (most modes shown, then most poles; the lowest level
    among equals) followed over the levels: the nearest pole within ``MATCH_RATIO`` in
    frequency."""
    ref = max(fits, key=lambda lv: (sum(map(lv.shown, lv.modes)), len(lv.modes)))
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
        tr = ModeTrack(axis, i + 1, labs, fn, zt, band_hz=ref.band_hz,
                       why_not=ref.why_not(m), reference=m)
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
    """The modes of every driven axis at every level (or of all the data as one level where
    there are no distinct levels), and each mode's natural frequency and damping against the
    level."""
    out = Modes([], [])
    for axis in (0, 1):
        lvls, _ = levels(records, segs, axis)
        if not lvls:
            lvls = [("all data", [s for s in segs if axis in driven_axes(
                records[s.run], s.start, s.stop)])]
        fits = []
        for lab, ss in lvls:
            w, h, sd = receptance_points(records, ss, axis)
            bb = broadband_points(records, ss, axis, out.skipped)
            if bb.w.size:
                w, h, sd = np.append(w, bb.w), np.append(h, bb.h), np.append(sd, bb.sd)
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
                     for s in ss if s.freq_hz] or [bb.force_n]
            band = (float(w.min()) / (2 * math.pi), float(w.max()) / (2 * math.pi))
            fits.append(LevelModes(lab, "xy"[axis], float(np.median(f_amp)), int(w.size),
                                   modes, rows, band, np.unique(w) / (2 * math.pi)))
            narrow = [md.natural_hz for md in modes
                      if 2 * md.damping_ratio * md.natural_hz < WINDOW_LINES * bb.window_hz]
            if narrow:
                out.cautions.append(
                    f"{'xy'[axis]} {lab}: the half-power band of the mode(s) at "
                    f"{', '.join(f'{f:.4g}' for f in narrow)} Hz is within the Welch window's "
                    f"main lobe ({WINDOW_LINES} lines of {bb.window_hz:.3g} Hz): their damping, "
                    "and any mode beside them, may be the window's bias (a longer record, or a "
                    "periodic excitation, resolves them)")
        out.levels.extend(fits)
        if fits:
            out.tracks.extend(_track("xy"[axis], fits))
    if not out.levels:
        out.reason = ("no modal fit: it needs 5 or more dwell frequencies or coherent broadband "
                      "lines on a driven axis"
                      + "".join(f"; {why}" for why in out.skipped))
    return out
