"""Amplitude dependence: the linear model fitted per level, the classic first test for a
nonlinearity.

Levels are the runs (several runs: one level each, e.g. one force level per run of a ground
vibration test), or, within one run of dwells, groups of dwells of about the same response
amplitude (displacement-held dwells) or else the same force amplitude (force-held dwells):
sorted amplitudes split where one is more than 25 % above the previous, each group with dwells at
3 or more frequencies.

Per level and driven axis, the main mode (the largest peak of the receptance |Z/F|) is fitted as
one mode, ``F/Z = K - w^2 M + i w C``, by weighted least squares on the dynamic-stiffness points
near the peak (within a factor 1.25 in frequency, else 1.5; all points where fewer than 4 lie
there, so other modes bias it least), the
points of `start.dynamic_stiffness_points` (1X per dwell, or H1 where coherent). Natural
frequency and damping ratio carry a standard deviation from the fit's residual (first-order
propagation of the parameter covariance). These are the apparent (equivalent linear) properties
at that level: the film's mass and damping included.

The verdict regresses the natural frequency and the damping ratio on log(level) (weighted by
their variances) and calls a trend where the change over the levels is at least
``FREQ_CHANGE`` (1 %) of the natural frequency, or ``DAMP_CHANGE`` (10 %) of the damping ratio,
and at least ``T_MIN`` (3) standard errors. No trend is "level-independent" only where the
levels resolve the least change called one (``T_MIN`` sd of the change within it); otherwise it
is "not resolved", with the change and its sd. A level's natural frequency is shown as a figure
only where it lies among its points' frequencies (not extrapolated) and stands ``T_MIN`` sd from
zero, its damping ratio likewise (an overdamped film's one-mode fit over 20-60 Hz gave
16.8 +- 18 Hz). ``EFFECTS_BY_TREND`` ties each pattern to the
library's effects; a finding of diagnose that a significant trend beyond the baseline
contradicts (level-independent terms alone, or a cubic spring of the wrong sign) is named in
``contradicted``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from analysis.diagnose.data import RunRecord, Segment, driven_axes
from analysis.diagnose.model import Evaluator, Model, Residuals, residuals
from analysis.diagnose.residual_analysis import harmonics
from analysis.diagnose.start import dynamic_stiffness_points, fit_one_mode

FREQ_CHANGE = 0.01
DAMP_CHANGE = 0.10
T_MIN = 3.0
LEVEL_GAP = 1.25

#: (stiffness trend, damping trend) -> effects of the library that show that pattern
EFFECTS_BY_TREND: dict[tuple[str, str], list[str]] = {
    ("softening", "rising"): ["joint_microslip"],
    ("softening", "none"): ["cubic_stiffness", "quadratic_stiffness", "joint_microslip"],
    ("softening", "falling"): ["coulomb_friction", "joint_microslip"],
    ("hardening", "none"): ["cubic_stiffness"],
    ("hardening", "falling"): ["cubic_stiffness", "air_entrainment"],
    ("hardening", "rising"): ["cubic_stiffness", "amplitude_dependent_damping"],
    ("none", "rising"): ["amplitude_dependent_damping", "joint_microslip"],
    ("none", "falling"): ["coulomb_friction", "air_entrainment"],
    ("none", "none"): [],
}
#: effects whose size does not depend on the level: a significant trend is not theirs
#: (a viscosity drift is left out: it follows time, and levels recorded in time order
#: would show it as a trend)
LEVEL_INDEPENDENT = ("added_mass", "second_mode", "cross_coupling", "sensor_gain",
                     "channel_delay")


@dataclass
class LevelFit:
    """The main mode of one axis at one level."""

    label: str
    axis: str
    level_by: str  # "force" or "response"
    force_n: float  # median force amplitude of the level [N]
    response_m: float  # median response amplitude [m]
    segments: int
    points: int
    natural_hz: float
    natural_hz_sd: float
    damping_ratio: float
    damping_ratio_sd: float
    mass_kg: float
    damping_ns_per_m: float
    stiffness_n_per_m: float
    band_hz: tuple[float, float] = (0.0, math.inf)  # lowest and highest point [Hz]

    @property
    def level(self) -> float:
        return self.force_n if self.level_by == "force" else self.response_m

    @property
    def frequency_determined(self) -> bool:
        """The natural frequency lies among the points (not extrapolated) and stands
        ``T_MIN`` standard deviations from zero: a figure an engineer can read."""
        lo, hi = self.band_hz
        return lo <= self.natural_hz <= hi and T_MIN * self.natural_hz_sd <= self.natural_hz

    @property
    def damping_determined(self) -> bool:
        return T_MIN * self.damping_ratio_sd <= self.damping_ratio

    @property
    def text(self) -> str:
        """``natural frequency, damping ratio`` with their sd, or why they are not given."""
        f = f"{self.natural_hz:.4g} +/- {self.natural_hz_sd:.2g} Hz"
        if not self.frequency_determined:
            lo, hi = self.band_hz
            where = (f"outside the points' {lo:.4g}-{hi:.4g} Hz, " if not lo <= self.natural_hz
                     <= hi else "")
            f = f"natural frequency not determined ({where}{f})"
        z = f"damping ratio {self.damping_ratio:.3g} +/- {self.damping_ratio_sd:.2g}"
        if not self.damping_determined:
            z = f"damping ratio not determined ({z[14:]})"
        return f"{f}, {z}"

    def to_dict(self) -> dict[str, Any]:
        return {"level": self.label, "axis": self.axis, "level_by": self.level_by,
                "force_amplitude_N": self.force_n, "response_amplitude_m": self.response_m,
                "segments": self.segments, "points": self.points,
                "natural_frequency_hz": self.natural_hz, "natural_frequency_sd_hz":
                self.natural_hz_sd, "damping_ratio": self.damping_ratio,
                "damping_ratio_sd": self.damping_ratio_sd, "band_hz": list(self.band_hz),
                "natural_frequency_determined": self.frequency_determined,
                "damping_ratio_determined": self.damping_determined, "mass_kg": self.mass_kg,
                "damping_Ns_per_m": self.damping_ns_per_m,
                "stiffness_N_per_m": self.stiffness_n_per_m}


@dataclass
class Trend:
    """Relative change over the levels (lowest to highest) and its t-statistic."""

    change: float
    t: float
    verdict: str  # "softening"/"hardening"/"none" or "rising"/"falling"/"none"
    sd: float = 0.0  # of the change, from the levels' own uncertainties
    min_change: float = 0.0  # the least change called a trend

    @property
    def resolved(self) -> bool:
        """A trend was called, or the levels would have shown the least change called one
        (``T_MIN`` sd of the change within it): only then is "none" level-independence."""
        return self.verdict != "none" or T_MIN * self.sd <= self.min_change

    def words(self, noun: str, trend_fmt: str) -> str:
        if self.verdict != "none":
            return f"{self.verdict} ({self.change:{trend_fmt}})"
        if self.resolved:
            return f"{noun} level-independent"
        return (f"{noun} not resolved by the levels ({self.change:+.0%} +/- {self.sd:.0%} "
                "over them)")

    def to_dict(self) -> dict[str, Any]:
        return {"relative_change": self.change, "relative_change_sd": self.sd, "t": self.t,
                "verdict": self.verdict, "resolved": self.resolved}


@dataclass
class AmplitudeDependence:
    levels: list[LevelFit]
    frequency: dict[str, Trend] = field(default_factory=dict)  # per axis
    damping: dict[str, Trend] = field(default_factory=dict)
    effects: dict[str, list[str]] = field(default_factory=dict)  # per axis
    contradicted: dict[str, str] = field(default_factory=dict)  # finding -> why
    baseline_levels: list[LevelFit] = field(default_factory=list)  # the baseline's prediction
    excess_frequency: dict[str, Trend] = field(default_factory=dict)  # beyond the baseline
    excess_damping: dict[str, Trend] = field(default_factory=dict)
    reason: str = ""  # why there is no verdict (too few levels)

    @property
    def text(self) -> str:
        if self.reason:
            return self.reason
        parts = []
        for ax in self.frequency:
            f, d = self.frequency[ax], self.damping[ax]
            stiff = (f"{f.verdict} ({f.change:+.1%} in natural frequency)"
                     if f.verdict != "none" else f.words("natural frequency", "+.1%"))
            damp = (f"damping {d.verdict} with level ({d.change:+.0%})" if d.verdict != "none"
                    else d.words("damping", "+.0%"))
            more = ""
            if ax in self.excess_frequency:
                ef, ed = self.excess_frequency[ax], self.excess_damping[ax]
                more = (f" (beyond the baseline: stiffness {ef.words('', '+.1%').strip()}, "
                        f"damping {ed.words('', '+.0%').strip()})")
            parts.append(f"{ax}: {stiff}, {damp}{more}")
        return "; ".join(parts)

    def nonlinear(self) -> bool:
        return any(t.verdict != "none" for t in (*self.frequency.values(),
                                                  *self.damping.values()))

    def to_dict(self) -> dict[str, Any]:
        return {"levels": [lv.to_dict() for lv in self.levels],
                "natural_frequency_trend": {a: t.to_dict() for a, t in self.frequency.items()},
                "damping_trend": {a: t.to_dict() for a, t in self.damping.items()},
                "consistent_effects": self.effects, "contradicted_findings": self.contradicted,
                "baseline_levels": [lv.to_dict() for lv in self.baseline_levels],
                "natural_frequency_trend_beyond_baseline":
                    {a: t.to_dict() for a, t in self.excess_frequency.items()},
                "damping_trend_beyond_baseline":
                    {a: t.to_dict() for a, t in self.excess_damping.items()},
                "verdict": self.text, "nonlinear": self.nonlinear()}


# --- levels ------------------------------------------------------------------------------
def _amplitudes(rec: RunRecord, seg: Segment, axis: int) -> tuple[float, float]:
    """Force and response amplitude of ``seg`` on ``axis`` (1X for a dwell, else sqrt(2) RMS)."""
    f = rec.force_n[axis, seg.start:seg.stop]
    zs = [v[seg.start:seg.stop] for c, v in rec.responses.items() if rec.response_axis[c] == axis]
    z = np.mean(zs, axis=0) if zs else np.zeros_like(f)
    if seg.freq_hz:
        zf, _, _ = harmonics(f, seg.start, rec.sample_rate_hz, seg.freq_hz, 1)
        zz, _, _ = harmonics(z, seg.start, rec.sample_rate_hz, seg.freq_hz, 1)
        return float(abs(zf[0])), float(abs(zz[0]))
    return float(math.sqrt(2) * np.std(f)), float(math.sqrt(2) * np.std(z))


def _clusters(values: np.ndarray) -> list[np.ndarray]:
    """Indices grouped where sorted values jump by more than ``LEVEL_GAP``."""
    order = np.argsort(values)
    groups: list[list[int]] = [[int(order[0])]]
    for a, b in zip(order[:-1], order[1:], strict=True):
        if values[b] > LEVEL_GAP * max(values[a], 1e-300):
            groups.append([])
        groups[-1].append(int(b))
    return [np.array(g) for g in groups]


def levels(records: list[RunRecord], segs: list[Segment],
            axis: int) -> tuple[list[tuple[str, list[Segment]]], str]:
    """(label, segments) per level, and what the level is ("force" or "response")."""
    segs = [s for s in segs if axis in driven_axes(records[s.run], s.start, s.stop)]
    runs = sorted({s.run for s in segs})
    if len(runs) > 1:
        return [(records[r].name, [s for s in segs if s.run == r]) for r in runs], "force"
    dwells = [s for s in segs if s.freq_hz]
    if len(dwells) < 6:
        return [], "force"
    amps = np.array([_amplitudes(records[s.run], s, axis) for s in dwells])
    for by, col in (("response", 1), ("force", 0)):
        groups = _clusters(amps[:, col])
        good = [g for g in groups if len({dwells[i].freq_hz for i in g}) >= 3]
        if len(good) >= 2 and len(good) == len(groups):
            unit = "um" if by == "response" else "N"
            scale = 1e6 if by == "response" else 1.0
            out = []
            for g in good:
                med = float(np.median(amps[g, col])) * scale
                out.append((f"{med:.3g} {unit}", [dwells[i] for i in g]))
            return out, by
    return [], "force"


# --- the fit per level -------------------------------------------------------------------
def _main_mode(w: np.ndarray, d: np.ndarray, wt: np.ndarray) -> tuple[np.ndarray,
                                                                        np.ndarray] | None:
    """(K, M, C) of the main mode and their covariance, or None where the fit fails."""
    if w.size < 3:
        return None
    peak = w[np.argmax(np.abs(1.0 / d))]
    for span in (1.25, 1.5):  # the narrowest window around the peak with 4 points or more
        near = (w >= peak / span) & (w <= peak * span)
        if np.count_nonzero(near) >= 4:
            w, d, wt = w[near], d[near], wt[near]
            break
    sol, cov = fit_one_mode(w, d, wt)
    if cov is None or not (sol[0] > 0 and sol[1] > 0 and sol[2] > 0):
        return None  # not a mode (or a negative damping): no estimate at this level
    return sol, cov


def fit_level(records: list[RunRecord], segs: list[Segment], axis: int, label: str,
              level_by: str) -> LevelFit | None:
    w, d, wt = dynamic_stiffness_points(records, segs, axis)
    got = _main_mode(w, d, wt)
    if got is None:
        return None
    (k, m, c), cov = got
    fn = math.sqrt(k / m) / (2 * math.pi)
    zeta = c / (2 * math.sqrt(k * m))
    g_f = np.array([fn / (2 * k), -fn / (2 * m), 0.0])
    g_z = np.array([-zeta / (2 * k), -zeta / (2 * m), zeta / c if c else 0.0])
    amps = np.array([_amplitudes(records[s.run], s, axis) for s in segs])
    return LevelFit(label, "xy"[axis], level_by, float(np.median(amps[:, 0])),
                    float(np.median(amps[:, 1])), len(segs), int(w.size), fn,
                    float(math.sqrt(max(g_f @ cov @ g_f, 0.0))), zeta,
                    float(math.sqrt(max(g_z @ cov @ g_z, 0.0))), float(m), float(c), float(k),
                    (float(w.min()) / (2 * math.pi), float(w.max()) / (2 * math.pi)))


def trend(x: np.ndarray, y: np.ndarray, sd: np.ndarray, min_change: float,
           words: tuple[str, str], ref: float | None = None) -> Trend:
    """Weighted regression of y on x; change over the levels relative to ``ref`` (default:
    the mean of y)."""
    sd = np.maximum(sd, 1e-6 * np.maximum(np.abs(y), 1e-300))
    wts = 1.0 / sd**2
    xm = float(np.sum(wts * x) / np.sum(wts))
    sxx = float(np.sum(wts * (x - xm) ** 2))
    if sxx <= 0:
        return Trend(0.0, 0.0, "none", math.inf, min_change)
    slope = float(np.sum(wts * (x - xm) * y) / sxx)
    # the levels' own uncertainties (each from its fit's residual); no scatter-about-the-line
    # term: a trend that is monotonic but not linear in log(level) is still a trend
    se = 1.0 / math.sqrt(sxx)
    mean = float(np.mean(y)) if ref is None else ref
    change = slope * float(x.max() - x.min()) / mean if mean else 0.0
    t = abs(slope) / se
    verdict = "none"
    if abs(change) >= min_change and t >= T_MIN:
        verdict = words[0] if change > 0 else words[1]
    sd_change = se * float(x.max() - x.min()) / abs(mean) if mean else math.inf
    return Trend(change, t, verdict, sd_change, min_change)


def with_predictions(records: list[RunRecord], res: Residuals) -> list[RunRecord]:
    """Copies of ``records`` whose responses are a model's prediction (measured - residual)
    on the segments of ``res`` (elsewhere the measurement)."""
    out = []
    for ri, rec in enumerate(records):
        resp = {ch: v.copy() for ch, v in rec.responses.items()}
        for seg, chans in res.per_segment.items():
            if seg.run != ri:
                continue
            for ch, r in chans.items():
                if ch in resp:
                    resp[ch][seg.start:seg.stop] -= r
        out.append(replace(rec, responses=resp))
    return out


def amplitude_dependence(records: list[RunRecord], segs: list[Segment],
                         predicted: list[RunRecord] | None = None) -> AmplitudeDependence:
    """The main mode per level and axis, and the verdict on its trend (see module doc).

    With ``predicted`` (`with_predictions` of the baseline), the same levels are fitted on the
    baseline's prediction, and the trend beyond the baseline (measured minus predicted) is
    judged too: that is what a finding must explain."""
    fits: list[LevelFit] = []
    out = AmplitudeDependence(fits)
    for axis in (0, 1):
        lvls, by = levels(records, segs, axis)
        pairs = []
        for lab, ss in lvls:
            f = fit_level(records, ss, axis, lab, by)
            p = fit_level(predicted, ss, axis, lab, by) if predicted is not None else None
            if f is not None and (predicted is None or p is not None):
                pairs.append((f, p))
        fits.extend(f for f, _ in pairs)
        if predicted is not None:
            out.baseline_levels.extend(p for _, p in pairs if p is not None)
        if len(pairs) < 2:
            continue
        ax = "xy"[axis]
        got = [f for f, _ in pairs]
        x = np.log([f.level for f in got])
        fn = np.array([f.natural_hz for f in got])
        fsd = np.array([f.natural_hz_sd for f in got])
        zt = np.array([f.damping_ratio for f in got])
        zsd = np.array([f.damping_ratio_sd for f in got])
        out.frequency[ax] = trend(x, fn, fsd, FREQ_CHANGE, ("hardening", "softening"))
        out.damping[ax] = trend(x, zt, zsd, DAMP_CHANGE, ("rising", "falling"))
        out.effects[ax] = EFFECTS_BY_TREND[(out.frequency[ax].verdict,
                                            out.damping[ax].verdict)]
        if predicted is not None:
            pf = np.array([p.natural_hz for _, p in pairs if p is not None])
            pz = np.array([p.damping_ratio for _, p in pairs if p is not None])
            psd_f = np.array([p.natural_hz_sd for _, p in pairs if p is not None])
            psd_z = np.array([p.damping_ratio_sd for _, p in pairs if p is not None])
            out.excess_frequency[ax] = trend(x, fn - pf, np.hypot(fsd, psd_f), FREQ_CHANGE,
                                              ("hardening", "softening"), float(np.mean(fn)))
            out.excess_damping[ax] = trend(x, zt - pz, np.hypot(zsd, psd_z), DAMP_CHANGE,
                                            ("rising", "falling"), float(np.mean(zt)))
    if not out.frequency:
        out.reason = ("no amplitude dependence judged: it needs two or more levels (runs, or "
                      "groups of dwells at 3+ frequencies each at distinct amplitudes)")
    return out


def contradictions(dep: AmplitudeDependence,
                   findings: list[tuple[str, dict[str, Any]]]) -> dict[str, str]:
    """Findings (effect, parameters) that a significant trend over the levels (beyond the
    baseline) contradicts. Deliberately few: level-independent findings when nothing else was
    found to carry the trend, and a cubic spring of the wrong sign (the physics says the
    opposite). A term merely absent from the pattern's list is not contradicted: the per-level
    fits of one nonlinearity can bias the other property a little."""
    out: dict[str, str] = {}
    freq = dep.excess_frequency or dep.frequency
    damp = dep.excess_damping or dep.damping
    level_terms = [e for e, _ in findings if e not in LEVEL_INDEPENDENT]
    for ax, ft in freq.items():
        dt = damp[ax]
        if ft.verdict == "none" and dt.verdict == "none":
            continue
        for effect, params in findings:
            why = None
            if effect in LEVEL_INDEPENDENT and not level_terms:
                why = (f"{effect} does not depend on the level, but the {ax} axis's main mode "
                       f"does beyond the baseline ({ft.verdict} stiffness, damping "
                       f"{dt.verdict}) and no level-dependent term was found")
            elif effect == "cubic_stiffness" and ft.verdict != "none":
                k3 = float(params.get("k3_N_per_m3", 0.0))
                if (k3 > 0) != (ft.verdict == "hardening"):
                    why = (f"cubic_stiffness k3 = {k3:.3g} N/m^3 is "
                           f"{'hardening' if k3 > 0 else 'softening'}, the levels show "
                           f"{ft.verdict} on {ax}")
            if why:
                out.setdefault(effect, why)
    return out

def check_levels(ev: Evaluator, baseline: Model, fit_train: list[Segment], segs: list[Segment],
                 offsets: dict[tuple[int, str], float], findings: list[Any]) -> AmplitudeDependence:
    """The amplitude dependence of the data and of the baseline's prediction on ``segs``, and
    the findings it contradicts: each gets ``evidence["contradicted_by_levels"]`` and low
    confidence (a cause the levels argue against is not named with confidence)."""
    pred = with_predictions(ev.records, residuals(ev, baseline, fit_train, segs, offsets))
    try:
        dep = amplitude_dependence(ev.records, segs, pred)
    except (np.linalg.LinAlgError, ValueError) as err:  # e.g. a baseline that diverges
        return AmplitudeDependence([], reason=f"amplitude dependence not judged: {err}")
    dep.contradicted = contradictions(dep, [(f.effect, f.parameters) for f in findings])
    for f in findings:
        if f.effect in dep.contradicted:
            f.evidence["contradicted_by_levels"] = dep.contradicted[f.effect]
            f.evidence["confidence"] = "low"
    return dep
