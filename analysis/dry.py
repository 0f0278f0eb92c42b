"""Dry system (no oil), circular load orbits: the seal's friction force and the residual damping
from the energy balance (eq. 2-4), Im(F/X) and the equivalent damping (Figures 16-19, Table 4).

Per dwell, over one period T:
    Work  = pi (|F_x||X| sin phi_1 + |F_y||Y| sin phi_2) = pi Im(F_x X*) + pi Im(F_y Y*)   (eq. 2)
    E_dry = F_mu  integral |V| dt                                                          (eq. 3)
    E_rv  = C_rv  integral (V_x^2 + V_y^2) dt                                              (eq. 4)
with V rebuilt from the displacement's Fourier coefficients. Work = E_dry + E_rv is linear in
(F_mu, C_rv): a least-squares fit across frequencies gives both, with r^2.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

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

N_QUAD = 512  # quadrature points over one period


@dataclass
class DryPoint:
    """Energy terms of one dwell (per cycle) and the transfer functions of each axis."""

    run: str
    step: int
    freq_hz: float
    load_n: float
    work_j: float
    abs_v_integral_m: float  # integral |V| dt over one period [m]
    v2_integral_m2_per_s: float  # integral V.V dt over one period [m^2/s]
    fx: complex
    fy: complex
    x: complex
    y: complex

    def im_f_over_x(self) -> tuple[float, float]:
        """Im(F/X) per axis [N/m] (Figure 18)."""
        return (self.fx / self.x).imag, (self.fy / self.y).imag

    def equivalent_damping(self) -> tuple[float, float]:
        """Im(F/X)/w per axis [N.s/m] (Figure 19)."""
        w = 2 * np.pi * self.freq_hz
        ix, iy = self.im_f_over_x()
        return ix / w, iy / w

    def dissipated_j(self, f_mu_n: float, c_rv_ns_per_m: float) -> float:
        return f_mu_n * self.abs_v_integral_m + c_rv_ns_per_m * self.v2_integral_m2_per_s


def dry_point(dw: Dwell, velocity_harmonics: int = 1) -> DryPoint:
    """Energy terms of one circular-orbit dwell (needs fx, fy, x, y)."""
    fx, fy, x, y = dw.z1("fx"), dw.z1("fy"), dw.z1("x"), dw.z1("y")
    work = np.pi * ((fx * np.conj(x)).imag + (fy * np.conj(y)).imag)
    period = 1.0 / dw.freq_hz
    t = np.arange(N_QUAD) * period / N_QUAD
    k = velocity_harmonics
    vx = synthesize(dw.harmonics["x"][:k], dw.freq_hz, t, derivative=1)
    vy = synthesize(dw.harmonics["y"][:k], dw.freq_hz, t, derivative=1)
    speed = np.hypot(vx, vy)
    dt = period / N_QUAD
    load = dw.target_value if dw.target_kind == "load" else float(np.hypot(abs(fx), abs(fy))
                                                                  / np.sqrt(2))
    return DryPoint(dw.run_id, dw.step, dw.freq_hz, float(load), float(work),
                    float(speed.sum() * dt), float((speed**2).sum() * dt), fx, fy, x, y)


@dataclass
class EnergyFit:
    """F_mu and C_rv fitted to the work of a set of dwells (one row of Table 4, or all)."""

    label: str
    f_mu_n: float
    c_rv_ns_per_m: float
    r2: float
    n: int
    u_f_mu_n: float  # 95 %, regression and instruments
    u_c_rv_ns_per_m: float

    def to_dict(self) -> dict[str, float | int | str]:
        return {"label": self.label, "F_mu_N": self.f_mu_n, "C_rv_Ns_per_m": self.c_rv_ns_per_m,
                "r2": self.r2, "n_points": self.n, "U_F_mu_N": self.u_f_mu_n,
                "U_C_rv_Ns_per_m": self.u_c_rv_ns_per_m}


def fit_energy(points: list[DryPoint], label: str) -> EnergyFit:
    """Least squares of Work = F_mu integral|V| + C_rv integral V^2 over ``points`` (eq. 2-4)."""
    if len(points) < 3:
        raise ValueError(f"{label}: the energy balance needs at least 3 dwells, got {len(points)}")
    a = np.array([[p.abs_v_integral_m, p.v2_integral_m2_per_s] for p in points])
    w = np.array([p.work_j for p in points])
    p, se, r2 = linear_lstsq(a, w)
    tt = t95(len(points) - 2)
    # instruments (B.3): Work ~ F X so F_mu ~ F; C_rv ~ F / X
    u_fmu = combine(tt * se[0], p[0] * U_FORCE_REL)
    u_crv = combine(tt * se[1], p[1] * np.hypot(U_FORCE_REL, U_DISPLACEMENT_REL))
    return EnergyFit(label, float(p[0]), float(p[1]), float(r2), len(points), u_fmu, u_crv)


@dataclass
class DryResult:
    points: list[DryPoint]
    overall: EnergyFit | None
    by_test: list[EnergyFit]
    f_mu_n: float
    c_rv_ns_per_m: float
    u_f_mu_n: float
    u_c_rv_ns_per_m: float

    def table4(self) -> dict[str, object]:
        """Table 4: per test and load the fit, plus the identified (overall) values."""
        return {
            "rows": [f.to_dict() for f in self.by_test],
            "identified": {"F_mu_N": self.f_mu_n, "U_F_mu_N": self.u_f_mu_n,
                           "C_rv_Ns_per_m": self.c_rv_ns_per_m,
                           "U_C_rv_Ns_per_m": self.u_c_rv_ns_per_m,
                           "r2": self.overall.r2 if self.overall else float("nan")},
        }


def identify_dry(dwells: list[Dwell], skipped: list[Skipped],
                 velocity_harmonics: int = 1) -> DryResult | None:
    """Energy-balance identification over every usable circular-orbit dwell.

    Returns None (with a `Skipped` entry) when fewer than 3 usable dwells remain.
    """
    points: list[DryPoint] = []
    for dw in dwells:
        need = [s for s in ("fx", "fy", "x", "y") if s not in dw.harmonics]
        if need:
            skipped.append(Skipped(dw.run_id, "dry", f"dwell left out of the energy balance: "
                                   f"no usable {need}", dw.step, ",".join(need)))
            continue
        if not dw.motion.startswith("circular"):
            skipped.append(Skipped(dw.run_id, "dry", f"motion {dw.motion!r} is not a circular "
                                   "orbit; the energy balance uses circular orbits", dw.step))
            continue
        points.append(dry_point(dw, velocity_harmonics))
    if len(points) < 3:
        skipped.append(Skipped(",".join(sorted({d.run_id for d in dwells})) or "-", "dry",
                               f"energy balance not fitted: {len(points)} usable dwell(s), "
                               "3 needed"))
        return None
    groups: dict[tuple[str, float], list[DryPoint]] = defaultdict(list)
    for p in points:
        groups[(p.run, round(p.load_n, 0))].append(p)
    by_test = []
    for (run, load), pts in sorted(groups.items()):
        if len(pts) >= 3:
            by_test.append(fit_energy(pts, f"{run}, {load:g} N"))
    overall = fit_energy(points, "all dry dwells")
    # the scatter of repeated tests adds to the overall fit's uncertainty
    u_fmu = combine(overall.u_f_mu_n, scatter_u95([f.f_mu_n for f in by_test]))
    u_crv = combine(overall.u_c_rv_ns_per_m, scatter_u95([f.c_rv_ns_per_m for f in by_test]))
    return DryResult(points, overall, by_test, overall.f_mu_n, overall.c_rv_ns_per_m, u_fmu, u_crv)
