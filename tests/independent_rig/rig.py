"""The rig's physics, written a second time for tests (shares no code with ``simulated_hw``).

Per axis z in {x, y}, z the housing's displacement relative to the journal, h = z + f its absolute
displacement and f the frame's (0 unless a frame mode is given)::

    (M + M_f) h'' + D z'' + (C_rv + C_film) z' + K_z z + F_seal - sum(F_extra) = F_z  (housing)
    m_fr f'' + c_fr f' + k_fr f = (C_rv + C_film) z' + K_z z + D z'' + F_seal - sum(F_extra)

M_f and D only when lubricated (D: eq. 15, C_film: eq. 16 at the centre or a given constant).
The seal's dry friction ``F_seal = F_mu v / sqrt(|v|^2 + v_eps^2)`` acts against the 2-D relative
velocity vector, regularised (smooth) so that an ODE solver can integrate it: an approximation of
true sticking, good while the peak velocity is far above ``v_eps`` (default 0.1 mm/s, against
1.6 mm/s at 20 Hz and 13 um).

Any scalar parameter may be a number or a function of time ``t -> value`` (time-varying; those
force the ODE path). ``extra_forces`` are callables ``f(t, z, v) -> (Fx, Fy)``: the force they add
*on the housing* [N] given the relative displacement and velocity 2-vectors (so a restoring
cubic spring is ``lambda t, z, v: -k3 * z**3``); their reaction goes to the frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

Param = float | Callable[[float], float]
ExtraForce = Callable[[float, np.ndarray, np.ndarray], np.ndarray | Sequence[float]]


def value_at(p: Param, t: float) -> float:
    """A parameter's value at time ``t`` [s]."""
    return float(p(t)) if callable(p) else float(p)


def eq1_viscosity_pa_s(temperature_c: float) -> float:
    """Eq. 1: mu = 2.8 cP exp(-0.01665 (T - 23.6)) [Pa.s]."""
    return 2.8e-3 * math.exp(-0.01665 * (temperature_c - 23.6))


@dataclass(frozen=True)
class FilmGeometry:
    """The damper (section III): 127 mm x 25.4 mm, 127 um clearance; ISO VG 2 oil."""

    diameter_m: float = 0.127
    length_m: float = 0.0254
    clearance_m: float = 127e-6
    density_kg_per_m3: float = 736.0

    def eq15_added_mass_kg(self) -> float:
        """D = 1/2 rho pi R (2L)^3 / (10 c)  [kg] (7.58 kg for the report's damper)."""
        r = self.diameter_m / 2
        return 0.5 * self.density_kg_per_m3 * math.pi * r * (2 * self.length_m) ** 3 / (
            10 * self.clearance_m)

    def eq16_damping_centred(self, viscosity_pa_s: float) -> float:
        """C = pi mu R (L/c)^3 at eps = 0 [N.s/m] (5,060 N.s/m at 3.17 cP)."""
        r = self.diameter_m / 2
        return math.pi * viscosity_pa_s * r * (self.length_m / self.clearance_m) ** 3


@dataclass(frozen=True)
class FrameMode:
    """The frame under the rods as a second mass (report section IV.3: about 39 Hz)."""

    frequency_hz: float = 39.0
    modal_mass_kg: float = 40.0
    damping_ratio: float = 0.03

    @property
    def stiffness_n_per_m(self) -> float:
        return self.modal_mass_kg * (2 * math.pi * self.frequency_hz) ** 2

    @property
    def damping_ns_per_m(self) -> float:
        return 2 * self.damping_ratio * math.sqrt(self.stiffness_n_per_m * self.modal_mass_kg)


_FILM = FilmGeometry()


@dataclass
class RigSpec:
    """Everything that decides the housing's motion. Defaults: the report's rig, lubricated,
    no end seal (``seal_friction_n=26.0`` puts the report's seal back).

    Attributes
    ----------
    housing_mass_kg, stiffness_x_n_per_m, stiffness_y_n_per_m, residual_damping_ns_per_m
        M = 9.7 kg, K_sx = 788 kN/m, K_sy = 823 kN/m, C_rv = 370 N.s/m (Tables 1-3).
    lubricated
        Film present (M_f, D and C_film act) or dry.
    fluid_mass_kg, added_mass_kg, film_damping_ns_per_m
        M_f = 0.62 kg; D (default eq. 15, 7.58 kg); C_film (default eq. 16 at 3.17 cP, 5,060).
    seal_friction_n, seal_v_eps_m_per_s
        F_mu (0: no seal) and the regularisation velocity of the friction law.
    frame
        Optional second (frame) mode.
    extra_forces
        Callables ``f(t, z, v) -> (Fx, Fy)`` on the housing [N] (hidden effects).
    """

    housing_mass_kg: Param = 9.7
    stiffness_x_n_per_m: Param = 788e3
    stiffness_y_n_per_m: Param = 823e3
    residual_damping_ns_per_m: Param = 370.0
    lubricated: bool = True
    fluid_mass_kg: Param = 0.62
    added_mass_kg: Param = field(default_factory=_FILM.eq15_added_mass_kg)
    film_damping_ns_per_m: Param = field(
        default_factory=lambda: _FILM.eq16_damping_centred(3.17e-3))
    seal_friction_n: Param = 0.0
    seal_v_eps_m_per_s: float = 1e-4
    frame: FrameMode | None = None
    extra_forces: list[ExtraForce] = field(default_factory=list)

    # --- the terms at time t ------------------------------------------------------------------
    def masses(self, t: float) -> tuple[float, float]:
        """(M + M_f, D) [kg] acting on absolute and relative acceleration."""
        m = value_at(self.housing_mass_kg, t)
        if not self.lubricated:
            return m, 0.0
        return m + value_at(self.fluid_mass_kg, t), value_at(self.added_mass_kg, t)

    def damping(self, t: float) -> float:
        c = value_at(self.residual_damping_ns_per_m, t)
        return c + (value_at(self.film_damping_ns_per_m, t) if self.lubricated else 0.0)

    def stiffness(self, t: float) -> np.ndarray:
        return np.array([value_at(self.stiffness_x_n_per_m, t),
                         value_at(self.stiffness_y_n_per_m, t)])

    def nonlinear_force(self, t: float, z: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Seal friction plus extra forces, as forces ON the housing [N] (x, y)."""
        out = np.zeros(2)
        f_mu = value_at(self.seal_friction_n, t)
        if f_mu:
            out -= f_mu * v / math.sqrt(float(v @ v) + self.seal_v_eps_m_per_s**2)
        for extra in self.extra_forces:
            out += np.asarray(extra(t, z, v), dtype=np.float64)
        return out

    @property
    def is_linear_time_invariant(self) -> bool:
        params = (self.housing_mass_kg, self.stiffness_x_n_per_m, self.stiffness_y_n_per_m,
                  self.residual_damping_ns_per_m, self.fluid_mass_kg, self.added_mass_kg,
                  self.film_damping_ns_per_m, self.seal_friction_n)
        return (not any(callable(p) for p in params) and not self.extra_forces
                and float(self.seal_friction_n) == 0.0)  # type: ignore[arg-type]

    # --- closed form (linear part) ------------------------------------------------------------
    def receptance(self, omega: float, t: float = 0.0,
                   extra_damping_ns_per_m: float = 0.0) -> np.ndarray:
        """Complex relative displacement per unit force, per axis, shape (2,) [m/N].

        ``z = H F`` for ``F e^{i w t}``; with a frame the frame's flexibility is folded in.
        ``extra_damping_ns_per_m`` adds an equivalent viscous term (e.g. eq. 9 for the seal).
        """
        m_abs, d = self.masses(t)
        k = self.stiffness(t)
        c = self.damping(t) + extra_damping_ns_per_m
        iw = 1j * omega
        # internal force (housing -> frame): R = (k + iw c - w^2 d) z; housing: -w^2 m h + R = F
        r = k + iw * c - omega**2 * d
        if self.frame is None:
            return 1.0 / (r - omega**2 * m_abs)
        fr = self.frame
        frame_dyn = fr.stiffness_n_per_m + iw * fr.damping_ns_per_m - omega**2 * fr.modal_mass_kg
        # frame: frame_dyn f = R; housing: -w^2 m (z + f) + R = F
        f_per_r = 1.0 / frame_dyn
        return 1.0 / (r - omega**2 * m_abs * (1.0 + r * f_per_r))

    def frame_per_relative(self, omega: float, t: float = 0.0) -> np.ndarray:
        """Frame displacement per unit relative displacement, per axis (0 without a frame)."""
        if self.frame is None:
            return np.zeros(2, dtype=complex)
        m_abs, d = self.masses(t)
        r = self.stiffness(t) + 1j * omega * self.damping(t) - omega**2 * d
        fr = self.frame
        frame_dyn = fr.stiffness_n_per_m + 1j * omega * fr.damping_ns_per_m \
            - omega**2 * fr.modal_mass_kg
        return np.asarray(r / frame_dyn, dtype=complex)

    # --- ODE ----------------------------------------------------------------------------------
    def terms(self, t: float) -> tuple[float, float, float, float, float, float]:
        """(M + M_f, D, C_rv + C_film, K_x, K_y, F_mu) at time ``t`` (cached when constant)."""
        cached = self.__dict__.get("_const_terms")
        if cached is not None:
            return cached  # type: ignore[no-any-return]
        m_abs, d = self.masses(t)
        kx, ky = self.stiffness(t)
        out = (m_abs, d, self.damping(t), float(kx), float(ky),
               value_at(self.seal_friction_n, t))
        params = (self.housing_mass_kg, self.stiffness_x_n_per_m, self.stiffness_y_n_per_m,
                  self.residual_damping_ns_per_m, self.fluid_mass_kg, self.added_mass_kg,
                  self.film_damping_ns_per_m, self.seal_friction_n)
        if not any(callable(p) for p in params):
            self.__dict__["_const_terms"] = out
        return out

    def derivative(self, t: float, state: np.ndarray, force: np.ndarray) -> np.ndarray:
        """d/dt of ``[z(2), v(2), f(2), vf(2)]`` under shaker force ``force`` (2,) [N]."""
        zx, zy, vx, vy, fx, fy, vfx, vfy = (float(s) for s in state)
        m_abs, d, c, kx, ky, f_mu = self.terms(t)
        # internal force: what the housing transmits to the rods, film and seal (and the frame)
        ix, iy = c * vx + kx * zx, c * vy + ky * zy
        if f_mu:
            scale = f_mu / math.sqrt(vx * vx + vy * vy + self.seal_v_eps_m_per_s**2)
            ix, iy = ix + scale * vx, iy + scale * vy
        if self.extra_forces:
            z, v = np.array([zx, zy]), np.array([vx, vy])
            for extra in self.extra_forces:
                ex, ey = (float(e) for e in extra(t, z, v))
                ix, iy = ix - ex, iy - ey
        f_x, f_y = float(force[0]), float(force[1])
        if self.frame is None:
            return np.array([vx, vy, (f_x - ix) / (m_abs + d), (f_y - iy) / (m_abs + d),
                             0.0, 0.0, 0.0, 0.0])
        fr = self.frame
        # unknowns a = z'', af = f''; housing: m (a + af) + d a = F - internal;
        # frame: m_fr af = internal + d a - k_fr f - c_fr vf. Per axis a 2x2 solve, by hand.
        k_fr, c_fr, m2 = fr.stiffness_n_per_m, fr.damping_ns_per_m, fr.modal_mass_kg
        rx, ry = -k_fr * fx - c_fr * vfx, -k_fr * fy - c_fr * vfy
        den = m_abs + d + m_abs * d / m2
        ax = (f_x - ix - m_abs * (ix + rx) / m2) / den
        ay = (f_y - iy - m_abs * (iy + ry) / m2) / den
        return np.array([vx, vy, ax, ay, vfx, vfy, (ix + d * ax + rx) / m2,
                         (iy + d * ay + ry) / m2])
