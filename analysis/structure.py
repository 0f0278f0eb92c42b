"""Structure and instrument tests: static load steps (Table 2, eq. B.1-B.8), impacts (Table 3,
eq. B.9-B.11), eddy-current probe calibration (Table A1, eq. B.1-B.5) and flow against pressure
(eq. 1 and eq. 5, Figures 20 and 25, eq. B.17-B.19).

Each takes an open run of the matching kind and returns plain data for the report's tables.
"""

from __future__ import annotations

import math
import re
from collections import defaultdict
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from analysis.dwells import read_signal, run_label
from analysis.errors import Skipped
from analysis.uncertainty import (
    U_DISPLACEMENT_REL,
    U_FLOWMETER_REL,
    U_FORCE_GAUGE_N,
    U_FORCE_REL,
    U_PRESSURE_PA,
    combine,
    line_fit,
    probe_gain_u,
    scatter_u95,
    static_stiffness_u,
    t95,
)
from rig_model.params import RigParams
from storage import RunData

MIL_M = 25.4e-6


def _span_mean(run: RunData, name: str, step: dict[str, Any], analysis: str,
               skipped: list[Skipped], channel: bool = False) -> float | None:
    first, last = int(step["first_sample"]), int(step["last_sample"])
    idx = int(step["index"])
    if last - first < 2:
        skipped.append(Skipped(run_label(run), analysis, f"empty span [{first}, {last})", idx))
        return None
    if channel:
        if name not in run.channel_names:
            present = ", ".join(run.channel_names)
            skipped.append(Skipped(run_label(run), analysis, f"channel {name!r} is not in the "
                                   f"run (channels {present})", idx, name,
                                   cause=f"channel not in the run (channels {present})"))
            return None
        data: np.ndarray | None = run.channel(name, first, last)
        assert data is not None
        if not np.all(np.isfinite(data)):
            skipped.append(Skipped(run_label(run), analysis,
                                   f"{int((~np.isfinite(data)).sum())} NaN sample(s)", idx, name))
            return None
    else:
        data = read_signal(run, name, first, last, analysis, idx, skipped)
        if data is None:
            return None
    return float(np.mean(data))


# --- static load tests ---------------------------------------------------------------------------
@dataclass
class StaticFit:
    """Stiffness of one axis from static load steps (Table 2)."""

    axis: str
    k_n_per_m: float
    u_k_n_per_m: float
    r2: float
    see_m: float  # eq. B.1 on displacement against force
    n_levels: int
    n_steps: int
    force_range_n: tuple[float, float]
    natural_freq_hz: float  # sqrt(K/M)/2 pi with the housing mass
    u_natural_freq_hz: float
    points: list[dict[str, float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def identify_static(run: RunData, skipped: list[Skipped], mass_kg: float, u_mass_rel: float,
                    u_gain_rel: float = U_DISPLACEMENT_REL,
                    u_force_n: float = U_FORCE_GAUGE_N) -> list[StaticFit]:
    """Static stiffness per axis: displacement against force, averaged over repeats (eq. B.6).

    Each step holds a force (``target_value`` [N]) along ``motion`` ("x" or "y"); the mean of the
    measured force and displacement over the step's span is one data point; a step loaded by
    hand (``gauge_force_n``, the force gauge's reading typed) pairs that with the displacement.
    """
    label = run_label(run)
    levels: dict[tuple[str, float], list[tuple[float, float]]] = defaultdict(list)
    for st in run.steps:
        axis = str(st.get("motion", ""))
        if axis not in ("x", "y"):
            skipped.append(Skipped(label, "static", f"motion {axis!r} is not x or y",
                                   int(st["index"])))
            continue
        if "gauge_force_n" in st:  # loaded by hand: the force gauge's reading as typed
            f: float | None = float(st["gauge_force_n"])
        else:
            f = _span_mean(run, "f" + axis, st, "static", skipped)
        d = _span_mean(run, axis, st, "static", skipped)
        if f is None or d is None:
            continue
        levels[(axis, round(float(st["target_value"]), 3))].append((f, d))
    fits = []
    for axis in ("x", "y"):
        pts = sorted((k[1], v) for k, v in levels.items() if k[0] == axis)
        if not pts:
            continue
        force = np.array([np.mean([p[0] for p in v]) for _, v in pts])
        disp = np.array([np.mean([p[1] for p in v]) for _, v in pts])
        u_avg = max(scatter_u95([p[1] for p in v]) for _, v in pts)  # eq. B.6
        if len(pts) < 3:
            skipped.append(Skipped(label, "static", f"{axis}: {len(pts)} force level(s), 3 "
                                   "needed for a stiffness fit", channel="f" + axis))
            continue
        fit = line_fit(force, disp)  # displacement [m] vs force [N]: slope = 1/K
        k = 1.0 / fit.slope
        u_k = abs(k) * static_stiffness_u(fit, u_force_n, u_gain_rel, u_avg)  # eq. B.7
        fn = math.sqrt(abs(k) / mass_kg) / (2 * math.pi)
        u_fn = fn * 0.5 * math.hypot(u_k / abs(k), u_mass_rel)
        fits.append(StaticFit(
            axis, float(k), float(u_k), fit.r2, fit.see, len(pts),
            sum(len(v) for _, v in pts), (float(force.min()), float(force.max())), fn, u_fn,
            [{"force_n": float(a), "displacement_m": float(b)} for a, b in zip(force, disp,
                                                                                 strict=True)]))
    if not fits:
        skipped.append(Skipped(label, "static", "no axis had enough usable load steps"))
    return fits


# --- impact tests --------------------------------------------------------------------------------
@dataclass
class ImpactFit:
    """K, M, C of one axis fitted to the impact FRF (Table 3)."""

    axis: str
    k_n_per_m: float
    m_kg: float
    c_ns_per_m: float
    damping_ratio: float
    natural_freq_hz: float
    r2: float
    u_k_n_per_m: float
    u_m_kg: float
    u_natural_freq_hz: float
    n_impacts: int
    band_hz: tuple[float, float]
    freq_hz: list[float] = field(default_factory=list)
    frf_m_per_n: list[list[float]] = field(default_factory=list)  # [re, im]
    coherence: list[float] = field(default_factory=list)  # of H1 over the accepted strikes

    def model(self, f_hz: np.ndarray) -> np.ndarray:
        w = 2 * np.pi * np.asarray(f_hz)
        return 1.0 / (self.k_n_per_m - self.m_kg * w**2 + 1j * self.c_ns_per_m * w)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def identify_impact(run: RunData, skipped: list[Skipped],
                    band_hz: tuple[float, float] = (5.0, 150.0),
                    hammer: str = "hammer") -> list[ImpactFit]:
    """FRF X/F averaged over strikes (H1), and a fit of 1/(K - M w^2 + i C w) (eq. B.9-B.11).

    Each step is one strike: ``motion`` names the axis struck, the span covers the pulse and the
    free decay. The hammer channel gives the force, the probes the displacement.
    """
    label = run_label(run)
    fs = run.sample_rate_hz
    by_axis: dict[str, list[tuple[np.ndarray, np.ndarray]]] = defaultdict(list)
    for st in run.steps:
        idx = int(st["index"])
        axis = str(st.get("motion", ""))
        if not st.get("accepted", True):  # a hit rejected at the rig (kept in the run)
            continue
        if axis not in ("x", "y"):
            skipped.append(Skipped(label, "impact", f"motion {axis!r} is not x or y", idx))
            continue
        first, last = int(st["first_sample"]), int(st["last_sample"])
        force = read_signal(run, hammer, first, last, "impact", idx, skipped) \
            if hammer in run.channel_names else None
        if force is None:
            if hammer not in run.channel_names:
                skipped.append(Skipped(label, "impact", f"no hammer channel {hammer!r}", idx,
                                       hammer))
            continue
        disp = read_signal(run, axis, first, last, "impact", idx, skipped)
        if disp is None:
            continue
        if force.max() <= 0:
            skipped.append(Skipped(label, "impact", "no strike in the span", idx, hammer))
            continue
        by_axis[axis].append((force, disp))
    fits = []
    for axis, strikes in sorted(by_axis.items()):
        n = min(len(f) for f, _ in strikes)
        sxf: np.ndarray = np.zeros(n // 2 + 1, complex)
        sff: np.ndarray = np.zeros(n // 2 + 1)
        sxx: np.ndarray = np.zeros(n // 2 + 1)
        for f, d in strikes:
            f0 = f[:n] - np.median(f[:n])
            d0 = d[:n] - np.mean(d[: max(n // 50, 2)])  # pre-strike level
            ff = np.fft.rfft(f0)
            dd = np.fft.rfft(d0)
            sxf = sxf + dd * np.conj(ff)
            sff = sff + np.abs(ff) ** 2
            sxx = sxx + np.abs(dd) ** 2
        freq = np.fft.rfftfreq(n, 1.0 / fs)
        h = sxf / sff
        coherence = np.abs(sxf) ** 2 / (sff * sxx)  # 1 for a single strike: says nothing
        band = (freq >= band_hz[0]) & (freq <= band_hz[1])
        if band.sum() < 5:
            skipped.append(Skipped(label, "impact", f"{axis}: window too short for the band "
                                   f"{band_hz} Hz", channel=axis))
            continue
        fb, hb = freq[band], h[band]
        w = 2 * np.pi * fb
        # H (K - M w^2 + i C w) = 1, linear in K, M, C (Levy's weighting by |H|)
        rows = np.stack([hb, -hb * w**2, 1j * hb * w], axis=1)
        a = np.vstack([rows.real, rows.imag])
        y = np.concatenate([np.ones(fb.size), np.zeros(fb.size)])
        (k, m, c), *_ = np.linalg.lstsq(a, y, rcond=None)
        fit_h = 1.0 / (k - m * w**2 + 1j * c * w)
        mag, mag_fit = np.abs(hb), np.abs(fit_h)
        r2 = 1.0 - float(((mag - mag_fit) ** 2).sum()) / float(((mag - mag.mean()) ** 2).sum())
        wn = math.sqrt(k / m) if k > 0 and m > 0 else float("nan")
        zeta = c / (2 * math.sqrt(k * m)) if k > 0 and m > 0 else float("nan")
        low = fb < 0.5 * wn / (2 * np.pi)  # the flexibility plateau used for H(0)
        mis = float(np.sqrt(np.mean((1 - mag[low] / mag_fit[low]) ** 2))) if low.any() else 0.0
        u_k_rel = math.sqrt(U_FORCE_REL**2 + U_DISPLACEMENT_REL**2 + mis**2)  # B.11
        d_f = fs / n  # frequency resolution
        u_wn_rel = (d_f * 2 * np.pi) / wn
        u_m_rel = math.sqrt(u_k_rel**2 + (2 * u_wn_rel) ** 2)
        fits.append(ImpactFit(axis, float(k), float(m), float(c), float(zeta),
                              float(wn / (2 * np.pi)), float(r2), abs(k) * u_k_rel,
                              abs(m) * u_m_rel, d_f, len(strikes), band_hz,
                              [float(v) for v in fb],
                              [[float(v.real), float(v.imag)] for v in hb],
                              [float(v) for v in coherence[band]]))
    if not fits:
        skipped.append(Skipped(label, "impact", "no usable strike"))
    return fits


# --- probe calibration ---------------------------------------------------------------------------
@dataclass
class ProbeCal:
    """Gain of one eddy-current probe from static steps against a reference gauge (Table A1)."""

    channel: str
    gain_v_per_m: float
    gain_mv_per_mil: float
    r2: float
    see_v: float
    u_gain_rel: float
    n_points: int
    gain_in_use_v_per_m: float
    points: list[dict[str, float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def identify_probe_calibration(run: RunData, skipped: list[Skipped],
                               skip_steps: Collection[int] = ()) -> list[ProbeCal]:
    """Probe output volts against the reference displacement, per probe (eq. B.1-B.5).

    Each step holds a displacement along ``motion``; its reference reading [m] is the step's
    ``reference_m`` (or ``target_value``). Volts are rebuilt from the recorded engineering units
    with the gain and offset in use: ``V = gain * value + offset``. Steps whose index is in
    ``skip_steps`` are left out (entries questioned: `analysis.channel_calibration`).
    """
    label = run_label(run)
    pts: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for st in run.steps:
        axis = str(st.get("motion", ""))
        idx = int(st["index"])
        if idx in skip_steps:
            continue
        if axis not in ("x", "y"):
            skipped.append(Skipped(label, "probe_calibration", f"motion {axis!r} is not x or y",
                                   idx))
            continue
        ref = float(st.get("reference_m", st.get("target_value", float("nan"))))
        if not math.isfinite(ref):
            skipped.append(Skipped(label, "probe_calibration", "no reference reading", idx))
            continue
        probes = [c for c in run.channel_names if re.fullmatch(rf"{axis}\d+", c)]
        if not probes:
            skipped.append(Skipped(label, "probe_calibration", f"no {axis} probe channels", idx,
                                   axis))
        for ch in probes:
            val = _span_mean(run, ch, st, "probe_calibration", skipped, channel=True)
            if val is None:
                continue
            a = run.channel_attrs(ch)
            gain, off = float(a.get("gain_v_per_unit", float("nan"))), float(a.get("offset_v", 0))
            if not math.isfinite(gain):
                skipped.append(Skipped(label, "probe_calibration", "no gain_v_per_unit "
                                       "attribute: volts cannot be rebuilt", idx, ch))
                continue
            pts[ch].append((ref, gain * val + off))
    out = []
    for ch, p in sorted(pts.items()):
        if len(p) < 3:
            skipped.append(Skipped(label, "probe_calibration", f"{len(p)} point(s), 3 needed",
                                   channel=ch))
            continue
        x = np.array([a for a, _ in p])
        v = np.array([b for _, b in p])
        fit = line_fit(x, v)
        gain_in_use = float(run.channel_attrs(ch).get("gain_v_per_unit", float("nan")))
        out.append(ProbeCal(ch, fit.slope, fit.slope * MIL_M * 1e3, fit.r2, fit.see,
                            probe_gain_u(fit), len(p), gain_in_use,
                            [{"reference_m": float(a), "volts": float(b)} for a, b in p]))
    return out


# --- flow ----------------------------------------------------------------------------------------
def eq1_viscosity_pa_s(temperature_c: float) -> float:
    """Eq. 1: mu = 2.8 cP exp(-0.01665 (T - 23.6)) [Pa.s]."""
    return 2.8e-3 * math.exp(-0.01665 * (temperature_c - 23.6))


@dataclass
class FlowResult:
    points: list[dict[str, float]]
    slope_m3_per_s_per_pa: float
    r2: float
    viscosity_fit_pa_s: float  # the viscosity eq. 5 needs to match the slope
    viscosity_eq1_pa_s: float  # eq. 1 at the mean oil temperature
    viscosity_config_pa_s: float  # the rig configuration's law at that temperature
    mean_temperature_c: float
    mean_flow_ratio_eq1: float
    mean_flow_ratio_config: float

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def identify_flow(run: RunData, skipped: list[Skipped], params: RigParams) -> FlowResult | None:
    """Flow through the film against the pressure difference, beside eq. 5 with eq. 1's viscosity.

    Each step is one supply pressure held steady; means of p_in, p_rec, q_in, t_oil over its span
    make one point; repeated pressures give the precision error (eq. B.17-B.19).
    """
    label = run_label(run)
    film = params.film
    raw: dict[float, list[tuple[float, float, float, float]]] = defaultdict(list)
    for st in run.steps:
        vals = [_span_mean(run, c, st, "flow", skipped, channel=True)
                for c in ("p_in", "p_rec", "q_in", "t_oil")]
        if any(v is None for v in vals):
            continue
        p_in, p_rec, q, t = (float(v) for v in vals)  # type: ignore[arg-type]
        key = round(float(st.get("supply_pressure_pa", st.get("target_value", p_in))), 0)
        raw[key].append((p_in, p_rec, q / 60_000.0, t))
    pts = []
    for key, rows in sorted(raw.items()):
        arr = np.array(rows)
        dp = float(arr[:, 0].mean() - arr[:, 1].mean())
        q = float(arr[:, 2].mean())
        t = float(arr[:, 3].mean())
        mu1 = eq1_viscosity_pa_s(t)
        muc = film.viscosity_pa_s(t)
        q5_1 = film.eq5_flow_m3_per_s(dp, mu1) if dp > 0 else float("nan")
        q5_c = film.eq5_flow_m3_per_s(dp, muc) if dp > 0 else float("nan")
        u_q = combine(q * U_FLOWMETER_REL, scatter_u95(arr[:, 2].tolist()))
        pts.append({"supply_pressure_pa": key, "p_in_pa": float(arr[:, 0].mean()),
                    "p_rec_pa": float(arr[:, 1].mean()), "dp_pa": dp, "U_dp_pa":
                    math.sqrt(2) * U_PRESSURE_PA, "q_m3_per_s": q, "q_l_per_min": q * 60_000,
                    "U_q_m3_per_s": u_q, "t_oil_c": t, "mu_eq1_pa_s": mu1,
                    "q_eq5_eq1_m3_per_s": q5_1, "q_eq5_config_m3_per_s": q5_c,
                    "flow_ratio_eq1": q / q5_1 if q5_1 else float("nan"),
                    "flow_ratio_config": q / q5_c if q5_c else float("nan"),
                    "dp_ratio": dp / float(arr[:, 0].mean()) if arr[:, 0].mean() else float("nan"),
                    "n_repeats": len(rows)})
    good = [p for p in pts if p["dp_pa"] > 0]
    if len(good) < 3:
        skipped.append(Skipped(label, "flow", f"{len(good)} pressure level(s) with flow, 3 "
                               "needed"))
        return None
    fit = line_fit([p["dp_pa"] for p in good], [p["q_m3_per_s"] for p in good])
    mu_fit = math.pi * film.diameter_m * film.clearance_m**3 / (12 * film.length_m * fit.slope)
    t_mean = float(np.mean([p["t_oil_c"] for p in good]))
    return FlowResult(pts, fit.slope, fit.r2, mu_fit, eq1_viscosity_pa_s(t_mean),
                      film.viscosity_pa_s(t_mean), t_mean,
                      float(np.mean([p["flow_ratio_eq1"] for p in good])),
                      float(np.mean([p["flow_ratio_config"] for p in good])))


__all__ = ["identify_flow", "identify_impact", "identify_probe_calibration", "identify_static",
           "t95"]
