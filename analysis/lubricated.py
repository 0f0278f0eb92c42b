"""Lubricated system, unidirectional dwells: system damping and dynamic stiffness (eq. 14), total
and added mass by regression over frequency (Table 6, Appendix E), the seal's equivalent damping
(eq. 9) and the squeeze film's damping C = C_t - C_seal - C_rv (Figures 31-37, Appendix F).

Per dwell along axis z with F and Z the 1X complex amplitudes (eq. 12-13), z' = i w Z:
    C_t = Re(F / z'),   K - w^2 M_T = -w Im(F / z') = Re(F / Z)        (eq. 14)
    C_seal = 4 F_mu / (pi w |Z|)                                      (eq. 9)

Two ways of removing the seal are reported side by side:

- ``eq9`` (the report's): subtract C_seal of eq. 9 from C_t. Eq. 9 assumes the seal slips all
  the time on a sinusoidal velocity; it leaves the seal's in-phase force in K - w^2 M_T.
- ``stick_slip``: rebuild the seal force over one cycle from the measured motion (eq. 8 with
  sticking): F_mu sign(v) while the housing slides, and the force that holds it, F - K z, while it
  sticks (|v| below ``STICK_FRACTION`` of its peak and |F - K z| within F_mu, with a margin for
  the ripple of the rebuilt cycle; inertia and damping vanish there). Its 1X is
  subtracted from F before eq. 14, which then gives C_sfd + C_rv and K - w^2 M_T free of the seal.
  At low frequencies the housing sticks at each reversal (the inertia force w^2 M_T |Z| at the
  turning point is smaller than F_mu below about 30 Hz at 38 um), and eq. 9 then biases both the
  damping and the mass; the stick-slip estimate does not. K for the stick phases is the static
  stiffness (Table 2), as the report uses it for the mass fit.
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

N_QUAD = 2048  # points over one cycle for the seal force
SEAL_HARMONICS = 25  # harmonics of force and motion used to rebuild the cycle
STICK_FRACTION = 0.02  # |v| below this fraction of its peak counts as sticking...
HOLD_MARGIN = 1.15  # ...if the holding force is within F_mu (margin: the rebuilt cycle's ripple)
AMPLITUDE_GROUP_M = 0.5e-6  # dwells whose targets agree within this share an amplitude group
METHODS = ("eq9", "stick_slip")


def seal_force_1x(force_harmonics: np.ndarray, disp_harmonics: np.ndarray, freq_hz: float,
                  f_mu_n: float, k_n_per_m: float) -> tuple[complex, float]:
    """1X of the seal force rebuilt from the measured cycle (eq. 8 with sticking).

    Parameters
    ----------
    force_harmonics, disp_harmonics : complex ndarray
        1X..nX of the applied force [N] and the displacement [m] along the axis.
    freq_hz : float
        Excitation frequency [Hz].
    f_mu_n : float
        Seal friction force [N].
    k_n_per_m : float
        Structural stiffness [N/m] (holds the housing while it sticks).

    Returns
    -------
    (complex, float)
        The seal force's 1X complex amplitude [N] (force on the housing, opposing motion, as
        applied force must overcome it) and the fraction of the cycle spent sticking.
    """
    t = np.arange(N_QUAD) / (N_QUAD * freq_hz)
    f = synthesize(force_harmonics, freq_hz, t)
    z = synthesize(disp_harmonics, freq_hz, t)
    v = synthesize(disp_harmonics, freq_hz, t, derivative=1)
    hold = f - k_n_per_m * z  # what the seal must carry to keep the housing still
    # sticking: nearly at rest, and the seal can carry the holding force
    stick = (np.abs(v) < STICK_FRACTION * np.abs(v).max()) & (
        np.abs(hold) <= HOLD_MARGIN * f_mu_n)
    seal = np.where(stick, np.clip(hold, -f_mu_n, f_mu_n), f_mu_n * np.sign(v))
    w = 2 * np.pi * freq_hz
    return complex(2.0 / N_QUAD * np.sum(seal * np.exp(-1j * w * t))), float(stick.mean())


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
    c_seal_ss: float  # seal's equivalent damping from the stick-slip estimate [N.s/m]
    k_dyn_ss: float  # K - w^2 M_T with the stick-slip seal force removed [N/m]
    c_sfd_ss: float
    stick_fraction: float
    u_c_t: float
    u_k_dyn: float
    u_c_sfd: float
    u_c_sfd_ss: float
    t_oil_c: float | None = None

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
            "C_seal_stick_slip_Ns_per_m": self.c_seal_ss,
            "K_dyn_stick_slip_N_per_m": self.k_dyn_ss,
            "C_sfd_stick_slip_Ns_per_m": self.c_sfd_ss,
            "U_C_sfd_stick_slip_Ns_per_m": self.u_c_sfd_ss,
            "stick_fraction": self.stick_fraction, "t_oil_c": self.t_oil_c,
        }


def lub_point(dw: Dwell, axis: str, f_mu_n: float, u_f_mu_n: float, c_rv: float,
              u_c_rv: float, k_n_per_m: float) -> LubPoint:
    """Coefficients of one dwell along ``axis`` (eq. 9, eq. 14 and the stick-slip variant)."""
    f, z = dw.z1("f" + axis), dw.z1(axis)
    w = dw.omega
    zdot = 1j * w * z
    c_t = (f / zdot).real
    k_dyn = (f / z).real
    amp = abs(z)
    c_seal = 4 * f_mu_n / (np.pi * w * amp)
    seal1, stick = seal_force_1x(dw.harmonics["f" + axis], dw.harmonics[axis], dw.freq_hz,
                                 f_mu_n, k_n_per_m)
    c_seal_ss = (seal1 / zdot).real
    k_dyn_ss = ((f - seal1) / z).real
    c_sfd_ss = ((f - seal1) / zdot).real - c_rv
    # Appendix B style: |F/z'| (or |F/Z|) times the combined relative instrument uncertainty
    u_rel = np.hypot(U_FORCE_REL, U_DISPLACEMENT_REL)
    u_c_t = abs(f / zdot) * u_rel
    u_k = abs(f / z) * u_rel
    u_fmu_rel = u_f_mu_n / f_mu_n if f_mu_n else 0.0
    u_seal = c_seal * np.hypot(u_fmu_rel, U_DISPLACEMENT_REL)
    u_seal_ss = abs(c_seal_ss) * np.hypot(u_fmu_rel, U_DISPLACEMENT_REL)
    target = dw.target_value if dw.target_kind == "displacement" else amp
    return LubPoint(dw.run_id, dw.step, axis, dw.freq_hz, float(target), float(amp), f, z,
                    float(c_t), float(k_dyn), float(c_seal), float(c_t - c_seal - c_rv),
                    float(c_seal_ss), float(k_dyn_ss), float(c_sfd_ss), stick, float(u_c_t),
                    float(u_k), combine(u_c_t, u_seal, u_c_rv), combine(u_c_t, u_seal_ss, u_c_rv),
                    dw.means.get("t_oil"))


@dataclass
class MassFit:
    """Dynamic stiffness against w^2 for one axis, amplitude and method (Table 6, App. E)."""

    axis: str
    amplitude_m: float
    method: str  # "eq9" (report) or "stick_slip"
    n: int
    k_n_per_m: float  # free-intercept fit
    u_k_n_per_m: float
    m_t_kg: float
    u_m_t_kg: float
    r2: float
    added_mass_kg: float  # D = M_T - M - M_f
    u_added_mass_kg: float
    k_static_n_per_m: float
    m_t_fixed_k_kg: float  # K held at the static stiffness (the report's Table 6)
    r2_fixed_k: float
    added_mass_fixed_k_kg: float

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def fit_mass(pts: list[LubPoint], method: str, k_static: float, m_housing_kg: float,
             m_fluid_kg: float, u_m_housing_kg: float, u_m_fluid_kg: float) -> MassFit:
    """Regress K - w^2 M_T over frequency: free (K, M_T) and with K held at ``k_static``."""
    w2 = np.array([p.omega**2 for p in pts])
    kd = np.array([p.k_dyn if method == "eq9" else p.k_dyn_ss for p in pts])
    a = np.vstack([np.ones_like(w2), -w2]).T
    par, se, r2 = linear_lstsq(a, kd)
    tt = t95(len(pts) - 2)
    m_fixed = float(np.sum(w2 * (k_static - kd)) / np.sum(w2**2))
    res = kd - (k_static - w2 * m_fixed)
    ss_tot = float(((kd - kd.mean()) ** 2).sum())
    r2_fixed = 1.0 - float(res @ res) / ss_tot if ss_tot > 0 else 1.0
    u_rel = np.hypot(U_FORCE_REL, U_DISPLACEMENT_REL)
    u_mt = combine(tt * se[1], par[1] * u_rel)
    u_k = combine(tt * se[0], abs(par[0]) * u_rel)
    d = float(par[1]) - m_housing_kg - m_fluid_kg
    axis = pts[0].axis
    amp = float(np.mean([p.amplitude_m for p in pts]))
    return MassFit(axis, amp, method, len(pts), float(par[0]), u_k, float(par[1]), u_mt,
                   float(r2), d, combine(u_mt, u_m_housing_kg, u_m_fluid_kg), k_static, m_fixed,
                   r2_fixed, m_fixed - m_housing_kg - m_fluid_kg)


@dataclass
class LubResult:
    points: list[LubPoint]
    mass_fits: list[MassFit]
    f_mu_n: float
    c_rv_ns_per_m: float
    f_mu_source: str
    k_static: dict[str, float]
    sfd_by_amplitude: list[dict[str, Any]] = field(default_factory=list)


def identify_lubricated(dwells: list[Dwell], skipped: list[Skipped], *, f_mu_n: float,
                        u_f_mu_n: float, c_rv: float, u_c_rv: float, f_mu_source: str,
                        k_static: dict[str, float], m_housing_kg: float, m_fluid_kg: float,
                        u_m_housing_kg: float, u_m_fluid_kg: float) -> LubResult | None:
    """Identify every unidirectional dwell, then the mass fits and the SFD damping per amplitude.

    Parameters
    ----------
    dwells : list of Dwell
        Dwells of lubricated runs (harmonics up to `SEAL_HARMONICS` where available).
    f_mu_n, u_f_mu_n : float
        Seal friction force and its uncertainty [N] (from the dry tests, or the rig config).
    c_rv, u_c_rv : float
        Residual damping and its uncertainty [N.s/m].
    k_static : dict
        Static stiffness per axis {"x": K_sx, "y": K_sy} [N/m].
    m_housing_kg, m_fluid_kg, u_m_housing_kg, u_m_fluid_kg : float
        M and M_f and their uncertainties [kg] for D = M_T - M - M_f.
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
        points.append(lub_point(dw, axis, f_mu_n, u_f_mu_n, c_rv, u_c_rv, k_static[axis]))
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
        by_amp.append(sfd_summary(axis, pts))
        freqs = sorted({p.freq_hz for p in pts})
        if len(freqs) < 3:
            amp = float(np.mean([p.amplitude_m for p in pts]))
            skipped.append(Skipped(",".join(sorted({p.run for p in pts})), "lubricated",
                                   f"mass fit for {axis}, {amp * 1e6:.1f} um not made: "
                                   f"{len(freqs)} frequencies, 3 needed"))
            continue
        runs = sorted({p.run for p in pts})
        for method in METHODS:
            fit = fit_mass(pts, method, k_static[axis], m_housing_kg, m_fluid_kg,
                           u_m_housing_kg, u_m_fluid_kg)
            # repeated tests (several runs at this amplitude): their scatter adds to U_D
            per_run = []
            for r in runs:
                rp = [q for q in pts if q.run == r]
                if len({q.freq_hz for q in rp}) >= 3:
                    per_run.append(fit_mass(rp, method, k_static[axis], m_housing_kg,
                                            m_fluid_kg, u_m_housing_kg, u_m_fluid_kg
                                            ).added_mass_kg)
            if len(per_run) > 1:
                fit.u_added_mass_kg = combine(fit.u_added_mass_kg, scatter_u95(per_run))
                fit.u_m_t_kg = combine(fit.u_m_t_kg, scatter_u95(per_run))
            fits.append(fit)
    return LubResult(points, fits, f_mu_n, c_rv, f_mu_source, dict(k_static), by_amp)


def sfd_summary(axis: str, pts: list[LubPoint]) -> dict[str, Any]:
    """SFD damping of one amplitude group: mean over frequencies with its uncertainty (propagated
    and scatter), and the frequency trends of C_t and C_sfd (least-squares slopes per Hz)."""
    amp = float(np.mean([p.amplitude_m for p in pts]))
    f = np.array([p.freq_hz for p in pts])
    out: dict[str, Any] = {"axis": axis, "amplitude_m": amp, "n_points": len(pts),
                           "freqs_hz": sorted({float(v) for v in f})}
    temps = [p.t_oil_c for p in pts if p.t_oil_c is not None]
    out["t_oil_c"] = float(np.mean(temps)) if temps else None
    ct = np.array([p.c_t for p in pts])
    out["C_t_mean_Ns_per_m"] = float(ct.mean())
    out["dC_t_df_Ns_per_m_per_Hz"] = float(np.polyfit(f, ct, 1)[0]) if np.ptp(f) > 0 else None
    for method, vals, us in (("eq9", [p.c_sfd for p in pts], [p.u_c_sfd for p in pts]),
                             ("stick_slip", [p.c_sfd_ss for p in pts],
                              [p.u_c_sfd_ss for p in pts])):
        c = np.array(vals)
        u_prop = float(np.sqrt(np.mean(np.square(us))) / np.sqrt(len(pts)))
        out[method] = {
            "C_sfd_mean_Ns_per_m": float(c.mean()),
            "U_C_sfd_Ns_per_m": combine(u_prop, scatter_u95(c.tolist())),
            "dC_sfd_df_Ns_per_m_per_Hz": float(np.polyfit(f, c, 1)[0]) if np.ptp(f) > 0
            else None,
            "C_sfd_rel_spread": float(np.ptp(c) / abs(c.mean())) if c.mean() else None,
        }
    return out
