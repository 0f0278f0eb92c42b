"""The rig's physics, written a second time for tests (shares no code with ``simulated_hw``).

Per axis z in {x, y}, z the housing's displacement relative to the journal, h = z + f its absolute
displacement and f the frame's (0 unless a frame mode is given)::

    (M + M_f) h'' + D z'' + (C_rv + C_film) z' + K_z z + F_seal - sum(F_extra) = F_z  (housing)
    m_fr f'' + c_fr f' + k_fr f = (C_rv + C_film) z' + K_z z + D z'' + F_seal - sum(F_extra)

M_f and D only when lubricated (D: eq. 15, C_film: eq. 16 at the centre or a given constant).
K_z z is the rods' force, with their cross stiffness k_xy where they are turned from x and y
(``stiffness_xy_n_per_m``: K_sx z_x + k_xy z_y on x, k_xy z_x + K_sy z_y on y).
The seal's dry friction ``F_seal = F_mu v / sqrt(|v|^2 + v_eps^2)`` acts against the 2-D relative
velocity vector, regularised (smooth) so that an ODE solver can integrate it: an approximation of
true sticking, good while the peak velocity is far above ``v_eps`` (default 0.1 mm/s, against
1.6 mm/s at 20 Hz and 13 um).

Three film and structure terms of their own (each written from the physics, see its class):
the film's cross-coupled damping and added mass (``film_cross_damping_ns_per_m``,
``film_cross_mass_kg``; linear, so the closed form holds them as 2x2 matrices), air entrained
into the film at speed (``air``, an :class:`AirEntrainment`) and a joint micro-slipping beside
the rods' spring (``joint``, a :class:`DahlJoint`). The last two carry state: the ODE state is
``[z(2), v(2), f(2), vf(2), air fraction, joint force(2)]`` (``N_STATE``).

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
N_STATE = 11  # z(2), v(2), frame f(2), frame vf(2), air fraction, joint force (2)
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


@dataclass(frozen=True)
class AirEntrainment:
    """Air drawn into the film at speed: an open or poorly sealed damper ingests air as the whirl
    speed rises (report, introduction and ref. [14]). Following San Andres and De Santiago the
    air is taken as a loss of wetted length, L_eff = L (1 - a) with ``a`` the air fraction of the
    land; the film's damping and added mass, both ~ L^3 for the short damper (eqs. 15-16), and
    its cross-coupled terms scale by (1 - a)^3.

    The air fraction follows the squeeze speed |v| (2-D, relative) with a first-order lag,
    ``tau a' = k |v| - a``, capped at ``max_fraction`` where it acts; in a steady dwell its mean
    is k mean|v| ((2/pi) k w A for a straight line of amplitude A).

    Approximations: the lag and the linear law are a phenomenological fit, not a two-phase film
    model; the enclosed fluid mass M_f is kept (the air it displaces, <= 0.1 kg, is neglected).
    """

    coefficient_s_per_m: float  # k: air fraction per m/s of squeeze speed
    time_constant_s: float = 0.05
    max_fraction: float = 0.9

    def film_scale(self, fraction: float) -> float:
        """(L_eff / L)^3 at air fraction ``fraction`` (the lag state)."""
        a = min(max(fraction, 0.0), self.max_fraction)
        return (1.0 - a) ** 3

    def rate(self, fraction: float, speed_m_per_s: float) -> float:
        return (self.coefficient_s_per_m * speed_m_per_s - fraction) / self.time_constant_s

    def steady_fraction(self, mean_speed_m_per_s: float) -> float:
        """The lag's mean in a periodic steady state of mean squeeze speed ``mean_speed``."""
        return self.coefficient_s_per_m * mean_speed_m_per_s


@dataclass(frozen=True)
class DahlJoint:
    """A joint with friction at its interface (a clamped or bolted seat of the rods), beside
    the rods' spring on each axis: Dahl's law dF/dz = k_j (1 - sgn(z') F / F_s), here written
    in time, ``F' = k_j (z' - |z'| F / F_s)``, which is continuous in z' (no regularisation).

    Stuck (motion well below F_s / k_j) the joint is a spring k_j; as the amplitude grows it
    slips, its force saturating at F_s: the mode softens and its damping rises with the level.
    Its steady loop between -Z and Z is closed-form (``loop_force``): the rising branch
    ``F = F_s - (F_s + F_top) exp(-k_j (z + Z) / F_s)`` with ``F_top = F_s tanh(k_j Z / F_s)``,
    dissipating ``4 F_s (Z - F_s / k_j tanh(k_j Z / F_s))`` per cycle.

    Approximation: Dahl's single exponential branch stands for the distribution of micro-slip
    zones of a real interface (an Iwan element's many sliders, ``structure.IwanJoint``).
    """

    stiffness_n_per_m: float  # k_j: the joint stuck
    slip_force_n: float  # F_s: the force of full slip

    def rate(self, force_n: float, velocity_m_per_s: float) -> float:
        return self.stiffness_n_per_m * (
            velocity_m_per_s - abs(velocity_m_per_s) * force_n / self.slip_force_n)

    def loop_force(self, z: np.ndarray, v: np.ndarray,
                   amplitude_m: float | np.ndarray) -> np.ndarray:
        """The steady loop's force at ``z`` moving with velocity ``v`` between +-amplitude."""
        k, fs = self.stiffness_n_per_m, self.slip_force_n
        z, v = np.asarray(z, dtype=float), np.asarray(v, dtype=float)
        a = np.asarray(amplitude_m, dtype=float)
        top = fs * np.tanh(k * a / fs)
        rising = fs - (fs + top) * np.exp(-k * (z + a) / fs)
        falling = -(fs - (fs + top) * np.exp(-k * (a - z) / fs))
        return np.where(v >= 0, rising, falling)

    def loop_energy(self, amplitude_m: float) -> float:
        """Energy dissipated per cycle of the steady loop between +-amplitude [J]."""
        k, fs = self.stiffness_n_per_m, self.slip_force_n
        return 4 * fs * (amplitude_m - fs / k * math.tanh(k * amplitude_m / fs))


_FILM = FilmGeometry()


@dataclass
class RigSpec:
    """Everything that decides the housing's motion. Defaults: the report's rig, lubricated,
    no end seal (``seal_friction_n=26.0`` puts the report's seal back).

    Attributes
    ----------
    housing_mass_kg, stiffness_x_n_per_m, stiffness_y_n_per_m, residual_damping_ns_per_m
        M = 9.7 kg, K_sx = 788 kN/m, K_sy = 823 kN/m, C_rv = 370 N.s/m (Tables 1-3).
    stiffness_xy_n_per_m
        The rods' cross stiffness k_xy (0: their principal axes are x and y): the rods' force on
        x is ``-(K_sx z_x + k_xy z_y)``, on y ``-(k_xy z_x + K_sy z_y)``, a symmetric matrix
        (a spring stores energy; turned by theta from principal stiffnesses K_1, K_2,
        k_xy = (K_1 - K_2) sin(theta) cos(theta)).
    lubricated
        Film present (M_f, D, C_film and the film's cross terms act) or dry.
    fluid_mass_kg, added_mass_kg, film_damping_ns_per_m
        M_f = 0.62 kg; D (default eq. 15, 7.58 kg); C_film (default eq. 16 at 3.17 cP, 5,060).
    film_cross_damping_ns_per_m, film_cross_mass_kg
        The film's cross-coupled damping (C_xy, C_yx) and added mass (D_xy, D_yx): the film
        force on x is ``-(C z' + C_xy y' + D z'' + D_xy y'')``, on y ``-(... + C_yx x' +
        D_yx x'')`` (rotordynamic convention; a centred, sealed film has none: report IV).
    seal_friction_n, seal_v_eps_m_per_s
        F_mu (0: no seal) and the regularisation velocity of the friction law.
    frame
        Optional second (frame) mode.
    air
        Optional :class:`AirEntrainment` of the film.
    joint
        Optional :class:`DahlJoint` beside the rods' spring (per axis, force on z like K).
    extra_forces
        Callables ``f(t, z, v) -> (Fx, Fy)`` on the housing [N] (hidden effects).
    """

    housing_mass_kg: Param = 9.7
    stiffness_x_n_per_m: Param = 788e3
    stiffness_y_n_per_m: Param = 823e3
    residual_damping_ns_per_m: Param = 370.0
    stiffness_xy_n_per_m: float = 0.0
    lubricated: bool = True
    fluid_mass_kg: Param = 0.62
    added_mass_kg: Param = field(default_factory=_FILM.eq15_added_mass_kg)
    film_damping_ns_per_m: Param = field(
        default_factory=lambda: _FILM.eq16_damping_centred(3.17e-3))
    film_cross_damping_ns_per_m: tuple[float, float] = (0.0, 0.0)
    film_cross_mass_kg: tuple[float, float] = (0.0, 0.0)
    seal_friction_n: Param = 0.0
    seal_v_eps_m_per_s: float = 1e-4
    frame: FrameMode | None = None
    air: AirEntrainment | None = None
    joint: DahlJoint | None = None
    extra_forces: list[ExtraForce] = field(default_factory=list)

    # --- the terms at time t ------------------------------------------------------------------
    def masses(self, t: float, film_scale: float = 1.0) -> tuple[float, float]:
        """(M + M_f, D) [kg] acting on absolute and relative acceleration."""
        m = value_at(self.housing_mass_kg, t)
        if not self.lubricated:
            return m, 0.0
        return m + value_at(self.fluid_mass_kg, t), value_at(self.added_mass_kg, t) * film_scale

    def damping(self, t: float, film_scale: float = 1.0) -> float:
        c = value_at(self.residual_damping_ns_per_m, t)
        return c + (value_at(self.film_damping_ns_per_m, t) * film_scale
                    if self.lubricated else 0.0)

    def stiffness(self, t: float) -> np.ndarray:
        """The rods' stiffness matrix [[K_sx, k_xy], [k_xy, K_sy]] [N/m]."""
        k_xy = float(self.stiffness_xy_n_per_m)
        return np.array([[value_at(self.stiffness_x_n_per_m, t), k_xy],
                         [k_xy, value_at(self.stiffness_y_n_per_m, t)]])

    def cross_terms(self, film_scale: float = 1.0) -> tuple[float, float, float, float]:
        """(C_xy, C_yx, D_xy, D_yx) of the film (0 when dry)."""
        if not self.lubricated:
            return 0.0, 0.0, 0.0, 0.0
        (cxy, cyx), (dxy, dyx) = self.film_cross_damping_ns_per_m, self.film_cross_mass_kg
        return cxy * film_scale, cyx * film_scale, dxy * film_scale, dyx * film_scale

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
                and self.air is None and self.joint is None
                and float(self.seal_friction_n) == 0.0)  # type: ignore[arg-type]

    # --- closed form (linear part) ------------------------------------------------------------
    def _film_matrix(self, omega: float, t: float, extra_damping: np.ndarray,
                     air_fraction: float) -> tuple[np.ndarray, float]:
        """R = K + iw C - w^2 D (2x2: what the housing transmits per unit relative motion)
        and M + M_f."""
        scale = self.air.film_scale(air_fraction) if self.air is not None else 1.0
        m_abs, d = self.masses(t, scale)
        cxy, cyx, dxy, dyx = self.cross_terms(scale)
        c = self.damping(t, scale) + np.asarray(extra_damping, dtype=float)
        iw, w2 = 1j * omega, omega**2
        r = self.stiffness(t) + np.diag(iw * c - w2 * d)
        r[0, 1] += iw * cxy - w2 * dxy
        r[1, 0] += iw * cyx - w2 * dyx
        return r, m_abs

    def receptance_matrix(self, omega: float, t: float = 0.0,
                          extra_damping_ns_per_m: float | np.ndarray = 0.0,
                          air_fraction: float = 0.0) -> np.ndarray:
        """H (2x2 complex, [m/N]): relative displacement ``z = H F`` for force ``F e^{i w t}``.

        ``extra_damping_ns_per_m`` adds an equivalent viscous term per axis (e.g. eq. 9 for
        the seal), ``air_fraction`` the film's air (see :class:`AirEntrainment`). With a frame
        its flexibility is folded in: frame ``P f = R z`` (P its diagonal dynamic stiffness),
        housing ``-w^2 M (z + f) + R z = F``.
        """
        r, m_abs = self._film_matrix(omega, t, np.broadcast_to(extra_damping_ns_per_m, (2,)),
                                     air_fraction)
        dyn = r - omega**2 * m_abs * (np.eye(2) + self.frame_per_relative(omega, t, air_fraction,
                                                                          r))
        return np.linalg.inv(dyn)

    def receptance(self, omega: float, t: float = 0.0,
                   extra_damping_ns_per_m: float = 0.0, air_fraction: float = 0.0) -> np.ndarray:
        """Per axis, relative displacement per unit force on that axis alone (the other axis
        unforced), shape (2,) [m/N]: the diagonal of :meth:`receptance_matrix`."""
        return np.asarray(np.diag(self.receptance_matrix(omega, t, extra_damping_ns_per_m,
                                                         air_fraction)))

    def frame_per_relative(self, omega: float, t: float = 0.0, air_fraction: float = 0.0,
                           film: np.ndarray | None = None) -> np.ndarray:
        """Frame displacement per unit relative displacement, 2x2 (0 without a frame)."""
        if self.frame is None:
            return np.zeros((2, 2), dtype=complex)
        if film is None:
            film, _ = self._film_matrix(omega, t, np.zeros(2), air_fraction)
        fr = self.frame
        frame_dyn = fr.stiffness_n_per_m + 1j * omega * fr.damping_ns_per_m \
            - omega**2 * fr.modal_mass_kg
        return np.asarray(film / frame_dyn, dtype=complex)

    def force_for(self, target: np.ndarray, omega: float, t: float = 0.0,
                  air_fraction: float = 0.0) -> np.ndarray:
        """The force amplitudes that hold ``target`` (complex (2,)) on the axes where it is not
        zero, the other axis unforced (a unidirectional load moves both axes if coupled)."""
        h = self.receptance_matrix(omega, t, air_fraction=air_fraction)
        held = np.flatnonzero(np.abs(target) > 0)
        force = np.zeros(2, dtype=complex)
        if held.size:
            force[held] = np.linalg.solve(h[np.ix_(held, held)], target[held])
        return force

    def mean_speed(self, amplitude: np.ndarray, omega: float) -> float:
        """Mean |v| over a cycle of the harmonic motion ``Re(amplitude e^{i w t})``."""
        phases = np.exp(1j * np.linspace(0.0, 2 * math.pi, 512, endpoint=False))
        v = np.real(np.outer(1j * omega * np.asarray(amplitude), phases))
        return float(np.mean(np.hypot(v[0], v[1])))

    def steady_air_fraction(self, amplitude: np.ndarray, omega: float) -> float:
        """The air fraction's mean in the harmonic motion ``amplitude`` (0 without air)."""
        if self.air is None:
            return 0.0
        return self.air.steady_fraction(self.mean_speed(amplitude, omega))

    # --- ODE ----------------------------------------------------------------------------------
    def terms(self, t: float) -> tuple[float, float, float, float, float, float, float]:
        """(M + M_f, D, C_rv, C_film, K_x, K_y, F_mu) at time ``t`` (cached when constant)."""
        cached = self.__dict__.get("_const_terms")
        if cached is not None:
            return cached  # type: ignore[no-any-return]
        m_abs, d = self.masses(t)
        kx, ky = np.diag(self.stiffness(t))
        c_rv = value_at(self.residual_damping_ns_per_m, t)
        out = (m_abs, d, c_rv, self.damping(t) - c_rv, float(kx), float(ky),
               value_at(self.seal_friction_n, t))
        params = (self.housing_mass_kg, self.stiffness_x_n_per_m, self.stiffness_y_n_per_m,
                  self.residual_damping_ns_per_m, self.fluid_mass_kg, self.added_mass_kg,
                  self.film_damping_ns_per_m, self.seal_friction_n)
        if not any(callable(p) for p in params):
            self.__dict__["_const_terms"] = out
        return out

    def initial_state(self, z: np.ndarray, v: np.ndarray, omega: float,
                      amplitude: np.ndarray) -> np.ndarray:
        """A state on the harmonic motion ``amplitude`` at relative ``z``, ``v`` (frame at
        rest is set by the caller): air fraction at its steady mean, joint on its steady loop."""
        y0 = np.zeros(N_STATE)
        y0[0:2], y0[2:4] = z, v
        y0[8] = self.steady_air_fraction(amplitude, omega)
        if self.joint is not None:
            for k in range(2):
                y0[9 + k] = float(self.joint.loop_force(z[k], v[k], abs(amplitude[k])))
        return y0

    def derivative(self, t: float, state: np.ndarray, force: np.ndarray) -> np.ndarray:
        """d/dt of the state (see ``N_STATE``) under shaker force ``force`` (2,) [N]."""
        zx, zy, vx, vy, fx, fy, vfx, vfy, air, jx, jy = state.tolist()
        m_abs, d, c_rv, c_film, kx, ky, f_mu = self.terms(t)
        out = np.zeros(N_STATE)
        scale = 1.0
        if self.air is not None:
            scale = self.air.film_scale(air)
            out[8] = self.air.rate(air, math.sqrt(vx * vx + vy * vy))
        c = c_rv + c_film * scale
        d *= scale
        cxy, cyx, dxy, dyx = self.cross_terms(scale)
        # internal force: what the housing transmits to the rods, film and seal (and the frame)
        k_xy = self.stiffness_xy_n_per_m
        ix = c * vx + cxy * vy + kx * zx + k_xy * zy
        iy = c * vy + cyx * vx + ky * zy + k_xy * zx
        if f_mu:
            s = f_mu / math.sqrt(vx * vx + vy * vy + self.seal_v_eps_m_per_s**2)
            ix, iy = ix + s * vx, iy + s * vy
        if self.joint is not None:
            ix, iy = ix + jx, iy + jy
            out[9], out[10] = self.joint.rate(jx, vx), self.joint.rate(jy, vy)
        if self.extra_forces:
            z, v = np.array([zx, zy]), np.array([vx, vy])
            for extra in self.extra_forces:
                ex, ey = (float(e) for e in extra(t, z, v))
                ix, iy = ix - ex, iy - ey
        f_x, f_y = float(force[0]), float(force[1])
        # unknowns a = z'' (2) and, with a frame, af = f''; D_m = [[d, dxy], [dyx, d]].
        # housing: m (a + af) + D_m a = F - internal; frame: m_fr af = internal + D_m a + r_fr.
        # Eliminating af: (m I + g D_m) a = b with g = 1 + m / m_fr; a 2x2 solve by hand.
        if self.frame is None:
            g, bx, by = 1.0, f_x - ix, f_y - iy
            rx = ry = m2 = 0.0
        else:
            fr = self.frame
            k_fr, c_fr, m2 = fr.stiffness_n_per_m, fr.damping_ns_per_m, fr.modal_mass_kg
            rx, ry = -k_fr * fx - c_fr * vfx, -k_fr * fy - c_fr * vfy
            g = 1.0 + m_abs / m2
            bx = f_x - ix - m_abs * (ix + rx) / m2
            by = f_y - iy - m_abs * (iy + ry) / m2
        a11 = a22 = m_abs + g * d
        a12, a21 = g * dxy, g * dyx
        det = a11 * a22 - a12 * a21
        ax = (bx * a22 - a12 * by) / det
        ay = (a11 * by - a21 * bx) / det
        out[0:4] = vx, vy, ax, ay
        if self.frame is not None:
            out[4:8] = (vfx, vfy, (ix + d * ax + dxy * ay + rx) / m2,
                        (iy + d * ay + dyx * ax + ry) / m2)
        return out
