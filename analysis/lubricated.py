"""Lubricated system, unidirectional dwells: system damping and dynamic stiffness (eq. 14), total
and added mass by regression over frequency (Table 6, Appendix E), the seal's equivalent damping
(eq. 9) and the squeeze film's damping C = C_t - C_seal - C_rv (Figures 31-37, Appendix F).

Per dwell along axis z with F and Z the 1X complex amplitudes (eq. 12-13), z' = i w Z:
    C_t = Re(F / z'),   K - w^2 M_T = -w Im(F / z') = Re(F / Z)        (eq. 14)
    C_seal = 4 F_mu / (pi w |Z|)                                      (eq. 9)

Besides eq. 9 (which assumes a sinusoidal velocity), the seal force is also evaluated on the
measured motion: the 1X of F_mu sign(v(t)), with v(t) rebuilt from the displacement's 1X..5X.
That variant ("waveform") removes the seal's in-phase (stiffness-like) part too, which eq. 9
cannot; both are reported side by side.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from analysis.dwells import Dwell
from analysis.errors import Skipped
from analysis.sync import synthesize
from analysis.uncertainty import (
    U_DISPLACEMENT_REL,
    U_FORCE_REL,
    combine,
    linear_lstsq,
    scatter_u95,
    t95,
)

N_QUAD = 1024
AMPLITUDE_GROUP_M = 0.5e-6  # dwells whose targets agree within this share an amplitude group


@dataclass
class LubPoint:
    """Identified coefficients of one unidirectional dwell."""

    run: str
    step: int
    axis: str
    freq_hz: float
    target_m: float
    amplitude_m: float
    force: complex
    disp: complex
    c_t: float  # system damping, eq. 14 [N.s/m]
    k_dyn: float  # K - w^2 M_T [N/m]
    c_seal: float  # eq. 9 [N.s/m]
    c_sfd: float  # C_t - C_seal - C_rv [N.s/m]
    c_t_wave: float  # system damping less the seal force evaluated on the measured motion
    k_dyn_wave: float
    c_sfd_wave: float
    u_c_t: float
    u_k_dyn: float
    u_c_sfd: float

    @property
    def omega(self) -> float:
        return 2 * np.pi * self.freq_hz

    def to_dict(self) -> dict[str, Any]:
        return {
            "run": self.run, "step": self.step, "axis": self.axis, "freq_hz": self.freq_hz,
            "target_m": self.target_m, "amplitude_m": self.amplitude_m,
            "force_n": [self.force.real, self.force.imag],
            "disp_m": [self.disp.real, self.disp.imag],
            "C_t_Ns_per_m": self.c_t, "U_C_t_Ns_per_m": self.u_c_t,
            "K_dyn_N_per_m": self.k_dyn, "U_K_dyn_N_per_m": self.u_k_dyn,
            "C_seal_Ns_per_m": self.c_seal, "C_sfd_Ns_per_m": self.c_sfd,
            "U_C_sfd_Ns_per_m": self.u_c_sfd,
            "C_t_waveform_Ns_per_m": self.c_t_wave, "K_dyn_waveform_N_per_m": self.k_dyn_wave,
            "C_sfd_waveform_Ns_per_m": self.c_sfd_wave,
        }


def seal_force_1x(disp_harmonics: np.ndarray, freq_hz: float, f_mu_n: float) -> complex:
    """1X complex amplitude of ``F_mu sign(v(t))`` for the periodic motion of these harmonics."""
    t = np.arange(N_QUAD) / (N_QUAD * freq_hz)
    v = synthesize(disp_harmonics, freq_hz, t, derivative=1)
    vmax = np.abs(v).max()
    sgn = np.where(np.abs(v) > 1e-6 * vmax, np.sign(v), 0.0)
    w = 2 * np.pi * freq_hz
    return complex(f_mu_n * 2.0 / N_QUAD * np.sum(sgn * np.exp(-1j * w * t)))


def lub_point(dw: Dwell, axis: str, f_mu_n: float, u_f_mu_n: float, c_rv: float,
              u_c_rv: float) -> LubPoint:
    f, z = dw.z1("f" + axis), dw.z1(axis)
    w = dw.omega
    zdot = 1j * w * z
    c_t = (f / zdot).real
    k_dyn = (f / z).real
    amp = abs(z)
    c_seal = 4 * f_mu_n / (np.pi * w * amp)
    c_sfd = c_t - c_seal - c_rv
    fs1 = seal_force_1x(dw.harmonics[axis], dw.freq_hz, f_mu_n)
    c_t_wave = ((f - fs1) / zdot).real
    k_dyn_wave = ((f - fs1) / z).real
    # Appendix B style: the magnitude of F/z' (or F/Z) times the combined relative uncertainty
    u_rel = np.hypot(U_FORCE_REL, U_DISPLACEMENT_REL)
    u_c_t = abs(f / zdot) * u_rel
    u_k = abs(f / z) * u_rel
    u_seal = c_seal * np.hypot(u_f_mu_n / f_mu_n if f_mu_n else 0.0, U_DISPLACEMENT_REL)
    target = dw.target_value if dw.target_kind == "displacement" else amp
    return LubPoint(dw.run_id, dw.step, axis, dw.freq_hz, float(target), float(amp), f, z,
                    float(c_t), float(k_dyn), float(c_seal), float(c_sfd), float(c_t_wave),
                    float(k_dyn_wave), float(c_t_wave - c_rv), float(u_c_t), float(u_k),
                    combine(u_c_t, u_seal, u_c_rv))


@dataclass
class MassFit:
    """Dynamic stiffness against w^2 for one axis and amplitude (Table 6, Appendix E)."""

    axis: str
    amplitude_m: float
    n: int
    k_n_per_m: float  # free-intercept fit
    m_t_kg: float
    r2: float
    u_k_n_per_m: float
    u_m_t_kg: float
    m_t_fixed_k_kg: float  # with K held at the static stiffness (the report's way)
    r2_fixed_k: float
    k_static_n_per_m: float
    added_mass_kg: float  # D = M_T - M - M_f (free fit)
    u_added_mass_kg: float
    added_mass_fixed_k_kg: float
    m_t_wave_kg: float  # same fit on the seal-compensated dynamic stiffness
    k_wave_n_per_m: float
    added_mass_wave_kg: float

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items()}


def _fit_mass(pts: list[LubPoint], k_static: float, m_housing: float, m_fluid: float,
              u_m_housing: float, u_m_fluid: float, attr: str = "k_dyn"
              ) -> tuple[float, float, float, float, float, float, float]:
    w2 = np.array([p.omega**2 for p in pts])
    kd = np.array([getattr(p, attr) for p in pts])
    a = np.vstack([np.ones_like(w2), -w2]).T
    par, se, r2 = linear_lstsq(a, kd)
    tt = t95(len(pts) - 2)
    # K held: M_T by least squares through the fixed intercept
    m_fixed = float(np.sum(w2 * (k_static - kd)) / np.sum(w2**2))
    res = kd - (k_static - w2 * m_fixed)
    ss_tot = float(((kd - kd.mean()) ** 2).sum())
    r2_fixed = 1.0 - float(res @ res) / ss_tot if ss_tot > 0 else 1.0
    u_mt = combine(tt * se[1], par[1] * U_FORCE_REL, par[1] * U_DISPLACEMENT_REL)
    u_k = combine(tt * se[0], abs(par[0]) * np.hypot(U_FORCE_REL, U_DISPLACEMENT_REL))
    del u_m_housing, u_m_fluid
    return float(par[0]), float(par[1]), float(r2), u_k, u_mt, m_fixed, r2_fixed


@dataclass
class LubResult:
    points: list[LubPoint]
    mass_fits: list[MassFit]
    f_mu_n: float
    c_rv_ns_per_m: float
    f_mu_source: str
    sfd_by_amplitude: list[dict[str, Any]] = field(default_factory=list)


def identify_lubricated(dwells: list[Dwell], skipped: list[Skipped], *, f_mu_n: float,
                        u_f_mu_n: float, c_rv: float, u_c_rv: float, f_mu_source: str,
                        k_static: dict[str, float], m_housing_kg: float, m_fluid_kg: float,
                        u_m_housing_kg: float, u_m_fluid_kg: float) -> LubResult | None:
    """Identify every unidirectional dwell, then the mass fits and the SFD damping per amplitude.

    Parameters
    ----------
    dwells : list of Dwell
        Dwells of lubricated runs.
    f_mu_n, u_f_mu_n : float
        Seal friction force and its uncertainty [N] (from the dry tests, or the rig config).
    c_rv, u_c_rv : float
        Residual damping and its uncertainty [N.s/m].
    k_static : dict
        Static stiffness per axis {"x": K_sx, "y": K_sy} [N/m] for the report's fixed-K mass fit.
    m_housing_kg, m_fluid_kg : float
        M and M_f [kg] for D = M_T - M - M_f.
    """
    points: list[LubPoint] = []
    for dw in dwells:
        if dw.motion not in ("x", "y"):
            skipped.append(Skipped(dw.run_id, "lubricated", f"motion {dw.motion!r} is not "
                                   "unidirectional (x or y); eq. 14 is applied to x/y dwells",
                                   dw.step))
            continue
        axis = dw.motion
        need = [s for s in ("f" + axis, axis) if s not in dw.harmonics]
        if need:
            skipped.append(Skipped(dw.run_id, "lubricated", f"dwell left out: no usable {need}",
                                   dw.step, ",".join(need)))
            continue
        if abs(dw.z1(axis)) == 0:
            skipped.append(Skipped(dw.run_id, "lubricated", "zero displacement", dw.step, axis))
            continue
        points.append(lub_point(dw, axis, f_mu_n, u_f_mu_n, c_rv, u_c_rv))
    if not points:
        skipped.append(Skipped(",".join(sorted({d.run_id for d in dwells})) or "-", "lubricated",
                               "no usable unidirectional dwell"))
        return None
    groups: dict[tuple[str, float], list[LubPoint]] = defaultdict(list)
    for p in points:
        key = round(p.target_m / AMPLITUDE_GROUP_M) * AMPLITUDE_GROUP_M
        groups[(p.axis, key)].append(p)
    fits: list[MassFit] = []
    by_amp: list[dict[str, Any]] = []
    for (axis, _), pts in sorted(groups.items()):
        amp = float(np.mean([p.amplitude_m for p in pts]))
        freqs = sorted({p.freq_hz for p in pts})
        by_amp.append(_sfd_summary(axis, amp, pts))
        if len(freqs) < 3:
            skipped.append(Skipped(",".join(sorted({p.run for p in pts})), "lubricated",
                                   f"mass fit for {axis}, {amp * 1e6:.1f} um not made: "
                                   f"{len(freqs)} frequencies, 3 needed"))
            continue
        ks = k_static.get(axis, float("nan"))
        k, mt, r2, u_k, u_mt, m_fixed, r2_fixed = _fit_mass(
            pts, ks, m_housing_kg, m_fluid_kg, u_m_housing_kg, u_m_fluid_kg)
        kw, mtw, *_ = _fit_mass(pts, ks, m_housing_kg, m_fluid_kg, u_m_housing_kg,
                                u_m_fluid_kg, attr="k_dyn_wave")
        d = mt - m_housing_kg - m_fluid_kg
        u_d = combine(u_mt, u_m_housing_kg, u_m_fluid_kg)
        fits.append(MassFit(axis, amp, len(pts), k, mt, r2, u_k, u_mt, m_fixed, r2_fixed, ks, d,
                            u_d, m_fixed - m_housing_kg - m_fluid_kg, mtw, kw,
                            mtw - m_housing_kg - m_fluid_kg))
    return LubResult(points, fits, f_mu_n, c_rv, f_mu_source, by_amp)


def _sfd_summary(axis: str, amp: float, pts: list[LubPoint]) -> dict[str, Any]:
    """SFD damping of one amplitude group: mean over frequencies, with propagated and scatter
    uncertainty, and the frequency trend of C_t and C_sfd (slopes per Hz)."""
    c = np.array([p.c_sfd for p in pts])
    cw = np.array([p.c_sfd_wave for p in pts])
    ct = np.array([p.c_t for p in pts])
    f = np.array([p.freq_hz for p in pts])
    u_prop = float(np.sqrt(np.mean([p.u_c_sfd**2 for p in pts])) / np.sqrt(len(pts)))
    slope_ct = float(np.polyfit(f, ct, 1)[0]) if np.ptp(f) > 0 else float("nan")
    slope_c = float(np.polyfit(f, c, 1)[0]) if np.ptp(f) > 0 else float("nan")
    return {
        "axis": axis, "amplitude_m": amp, "n_points": len(pts),
        "C_sfd_mean_Ns_per_m": float(c.mean()),
        "U_C_sfd_Ns_per_m": combine(u_prop, scatter_u95(c)),
        "C_sfd_waveform_mean_Ns_per_m": float(cw.mean()),
        "C_t_mean_Ns_per_m": float(ct.mean()),
        "dC_t_df_Ns_per_m_per_Hz": slope_ct, "dC_sfd_df_Ns_per_m_per_Hz": slope_c,
        "C_sfd_rel_spread": float(np.ptp(c) / abs(c.mean())) if c.mean() else float("nan"),
    }
