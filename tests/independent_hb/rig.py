"""The sealed-SFD rig of the reference report, as linear matrices and nonlinear laws per dwell.

Written from the report (``sealed-sfd-report.txt``, sections III, IV and VI): housing
M = 9.7 kg with the plenum's oil M_f = 0.62 kg; the rods K_sx = 788 kN/m, K_sy = 823 kN/m with
their residual damping C_rv = 370 N.s/m (footnote 2, Table 4); the film of the 127 mm x
25.4 mm damper at c = 127 um, its damping from the short-length open-end formula (eq. 16, the
centred journal: C = mu D (L/c)^3 pi / 2) and its added mass from eq. 15
(D = rho pi R (2L)^3 / (20 c)); the oil ISO VG 2 (rho = 736 kg/m^3) at 3.17 cP (Table 5),
whose viscosity follows eq. 1 (mu ~ exp(-0.01665 T)) when it warms.

Coordinates: z = (x, y), the housing relative to the journal (what a probe reads), and with a
frame mode the frame's absolute x displacement f (the journal and the rods stand on the frame;
the shaker on the ground). The housing's absolute x acceleration is z_x'' + f''. Every force
between the housing and the journal (rods, film, seal) reacts on the frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tests.independent_hb.balance import Balance, NonlinearForces

HOUSING_MASS_KG = 9.7
PLENUM_OIL_KG = 0.62
STIFFNESS_X_N_PER_M = 788e3
STIFFNESS_Y_N_PER_M = 823e3
RESIDUAL_DAMPING_NS_PER_M = 370.0
CLEARANCE_M = 127e-6
DIAMETER_M = 0.127
LENGTH_M = 0.0254
OIL_DENSITY_KG_PER_M3 = 736.0
OIL_VISCOSITY_PA_S = 3.17e-3
OIL_TEMP_C = 24.0
#: eq. 1: mu(T) = 2.8 cP exp(-0.01665 (T - 23.6))
VISCOSITY_PER_C = 0.01665


def film_damping(viscosity_pa_s: float = OIL_VISCOSITY_PA_S) -> float:
    """Eq. 16 at the centre (eps = 0): the film's direct damping [N.s/m]."""
    return viscosity_pa_s * DIAMETER_M * (LENGTH_M / CLEARANCE_M) ** 3 * math.pi / 2.0


def film_added_mass() -> float:
    """Eq. 15: the film's direct added mass [kg]."""
    radius = DIAMETER_M / 2.0
    return 0.5 * OIL_DENSITY_KG_PER_M3 * math.pi * radius * (2 * LENGTH_M) ** 3 / (10 * CLEARANCE_M)


@dataclass(frozen=True)
class Frame:
    """The main frame's mode in x (the report's impact tests: ~47 Hz)."""

    mass_kg: float = 100.0
    frequency_hz: float = 47.0
    damping_ratio: float = 0.02

    @property
    def stiffness_n_per_m(self) -> float:
        return self.mass_kg * (2 * math.pi * self.frequency_hz) ** 2


@dataclass(frozen=True)
class BoucWen:
    """A smooth hysteretic seal (Bouc-Wen, n = 1, beta = gamma = 1/2): F = F_s w with
    dw/dz = (k0 / F_s) (1 - (beta sgn(w dz) + gamma) |w|): stiffness k0 while it pre-slides,
    saturating at F_s while it slides; unloading is elastic at k0."""

    force_n: float = 20.0
    stiffness_n_per_m: float = 2e6


@dataclass(frozen=True)
class Iwan:
    """A Masing/Iwan joint (outside the library's Bouc-Wen family): ``elements`` Jenkins
    elements in parallel, each a spring ``stiffness_n_per_m / elements`` in series with a
    Coulomb slider, their slip displacements spread uniformly over (0, ``max_slip_m``]. Its
    backbone is ``k_j z (1 - z / (2 z_max))`` up to full slip (a parabola, not the exponential
    of a Dahl/Bouc-Wen element of exponent 1) and it unloads along the backbone scaled twice
    (Masing's rule), so its loss grows with the cube of the amplitude at small amplitude."""

    stiffness_n_per_m: float = 2.4e5
    max_slip_m: float = 60e-6
    elements: int = 40

    def slips_m(self) -> np.ndarray:
        return self.max_slip_m * (np.arange(self.elements) + 0.5) / self.elements


@dataclass(frozen=True)
class FloorInput:
    """An input nobody measured: a nearby machine shaking the rig through the floor, a force of
    ``force_n`` at ``freq_hz`` on the housing along x, all run long (its phase runs on from the
    run's start). The load cell is between the shaker and the housing: it does not see it."""

    freq_hz: float = 24.7
    force_n: float = 0.1


@dataclass(frozen=True)
class Hidden:
    """Effects hidden in the rig (all off by default); each is switchable on its own.

    ``stiffness_drift``: K_x falls by this fraction over the run; ``warming_c``: the oil warms
    by this much over the run (the film's damping follows eq. 1); ``probe_gain_x`` /
    ``probe_delay_x_s`` are sensor effects (``sensors.SensorModel``) listed here so one object
    says what a case hides."""

    seal_friction_n: float = 0.0
    cubic_k3_n_per_m3: float = 0.0
    stiffness_drift: float = 0.0
    warming_c: float = 0.0
    film_cross_damping_ns_per_m: float = 0.0
    frame: Frame | None = None
    bouc_wen: BoucWen | None = None
    probe_gain_x: float = 1.0
    probe_delay_x_s: float = 0.0
    #: an even spring on x alone, F = k2 z_x^2 (its 2X, and through the motion 3X, ...)
    quadratic_k2_n_per_m2: float = 0.0
    iwan: Iwan | None = None
    floor: FloorInput | None = None


@dataclass(frozen=True)
class Rig:
    """The rig with its hidden effects; ``at(fraction)`` gives the parameters part-way through
    the run (slow drifts are constant over one 1 s dwell)."""

    hidden: Hidden = field(default_factory=Hidden)
    #: the friction law's velocity scale, relative to the dwell's peak velocity (a Coulomb law
    #: regularised so the balance is smooth; 0.2 % of the peak changes the dissipation < 0.1 %)
    friction_smoothing: float = 2e-3

    def oil_temp_c(self, fraction: Any) -> Any:
        """The oil temperature [C] at a fraction of the run (a float or an array of them)."""
        return OIL_TEMP_C + self.hidden.warming_c * fraction

    def film_damping_at(self, fraction: float) -> float:
        rise = self.oil_temp_c(fraction) - OIL_TEMP_C
        return film_damping(OIL_VISCOSITY_PA_S * math.exp(-VISCOSITY_PER_C * rise))

    def stiffness_x_at(self, fraction: float) -> float:
        return STIFFNESS_X_N_PER_M * (1.0 - self.hidden.stiffness_drift * fraction)

    @property
    def n_dof(self) -> int:
        return 3 if self.hidden.frame is not None else 2

    def matrices(self, fraction: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, C, K) over (z_x, z_y[, f]) part-way (``fraction``) through the run."""
        mh, d = HOUSING_MASS_KG + PLENUM_OIL_KG, film_added_mass()
        c = RESIDUAL_DAMPING_NS_PER_M + self.film_damping_at(fraction)
        cx = self.hidden.film_cross_damping_ns_per_m
        kx = self.stiffness_x_at(fraction)
        n = self.n_dof
        m_, c_, k_ = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
        m_[:2, :2] = np.diag([mh + d, mh + d])
        c_[:2, :2] = [[c, cx], [cx, c]]
        k_[:2, :2] = np.diag([kx, STIFFNESS_Y_N_PER_M])
        if (frame := self.hidden.frame) is not None:
            m_[0, 2] = mh  # the housing's absolute acceleration is z'' + f''
            # the frame carries what the housing's connections to it carry (its row: minus row 0's
            # relative terms) on its own spring and damper
            m_[2, 0], m_[2, 2] = -d, frame.mass_kg
            c_[2, :2] = -c_[0, :2]
            c_[2, 2] = 2 * frame.damping_ratio * math.sqrt(frame.stiffness_n_per_m * frame.mass_kg)
            k_[2, 0], k_[2, 2] = -kx, frame.stiffness_n_per_m
        return m_, c_, k_

    def balance(self, freq_hz: float, amplitude_m: float, fraction: float,
                n_harmonics: int = 21, n_time: int = 512) -> Balance:
        """The balance of a dwell holding the x motion's fundamental at ``amplitude_m``."""
        m_, c_, k_ = self.matrices(fraction)
        omega = 2 * math.pi * freq_hz
        return Balance(m_, c_, k_, omega, amplitude_m, controlled=0,
                       forces=self.nonlinear(omega, amplitude_m), n_harmonics=n_harmonics,
                       n_time=n_time)

    def nonlinear(self, omega: float, amplitude_m: float) -> NonlinearForces | None:
        """The nonlinear forces (seal, cubic spring) on the housing, reacting on the frame."""
        h = self.hidden
        if not (h.seal_friction_n or h.cubic_k3_n_per_m3 or h.bouc_wen
                or h.quadratic_k2_n_per_m2 or h.iwan):
            return None
        v_eps = self.friction_smoothing * omega * amplitude_m
        has_frame = h.frame is not None

        def forces(z: np.ndarray, v: np.ndarray) -> np.ndarray:
            out = np.zeros_like(z)
            zxy, vxy = z[:, :2], v[:, :2]
            if h.seal_friction_n:  # against the velocity vector
                speed = np.sqrt(np.sum(vxy**2, axis=1, keepdims=True) + v_eps**2)
                out[:, :2] += h.seal_friction_n * vxy / speed
            if h.cubic_k3_n_per_m3:  # a radially hardening spring
                out[:, :2] += h.cubic_k3_n_per_m3 * np.sum(zxy**2, axis=1, keepdims=True) * zxy
            if h.bouc_wen is not None:
                out[:, :2] += bouc_wen_force(zxy, h.bouc_wen)
            if h.quadratic_k2_n_per_m2:  # even in x: pushes one way on both half cycles
                out[:, 0] += h.quadratic_k2_n_per_m2 * zxy[:, 0] ** 2
            if h.iwan is not None:
                out[:, :2] += iwan_force(zxy, h.iwan)
            if has_frame:
                out[:, 2] = -out[:, 0]
            return out
        return forces


def bouc_wen_force(z: np.ndarray, law: BoucWen, max_periods: int = 40,
                   tol: float = 1e-12) -> np.ndarray:
    """The periodic steady state of the Bouc-Wen force per axis over one period.

    ``z``: ``(..., n_time)`` displacements over one period. Integrated in displacement (the law
    is rate independent), each sample step exactly (elastic unloading at k0 until w = 0, then
    exponential saturation), period after period until w repeats."""
    kappa = law.stiffness_n_per_m / law.force_n
    dz = np.diff(z, axis=-1, append=z[..., :1])
    w = np.zeros(z.shape[:-1])
    out = np.empty_like(z)
    for _ in range(max_periods):
        w_start = w.copy()
        for k in range(z.shape[-1]):
            out[..., k] = w
            w = _bouc_wen_step(w, dz[..., k], kappa)
        if np.max(np.abs(w - w_start)) < tol:
            break
    return law.force_n * out


def iwan_force(z: np.ndarray, law: Iwan) -> np.ndarray:
    """The periodic steady state of the Iwan joint's force per axis over one period.

    ``z``: ``(..., n_time)``. Each Jenkins element's slider follows the spring's end when its
    force would exceed its slip force; after one period every element that slipped has
    forgotten its start (one that never slips carries no force in steady state, its slider
    resting where the spring is unstressed at the period's mean), so the second period is the
    steady state."""
    slip = law.slips_m()  # per element: the spring's stretch at which it slips
    k_e = law.stiffness_n_per_m / law.elements
    mean = np.mean(z, axis=-1, keepdims=True)
    u = np.broadcast_to(mean, z.shape[:-1] + (1,)) + np.zeros(slip.shape)  # slider positions
    out = np.empty_like(z)
    for _ in range(2):
        for k in range(z.shape[-1]):
            zk = z[..., k : k + 1]
            u = np.clip(u, zk - slip, zk + slip)
            out[..., k] = k_e * np.sum(zk - u, axis=-1)
    return out


def _bouc_wen_step(w: np.ndarray, dz: np.ndarray, kappa: float) -> np.ndarray:
    sign = np.where(dz >= 0, 1.0, -1.0)
    u, s = sign * w, np.abs(dz) * kappa  # u: w along the motion; s: the step in units of 1/kappa
    unload = np.minimum(np.maximum(-u, 0.0), s)  # elastic part while u < 0
    u = u + unload
    u = 1.0 - (1.0 - u) * np.exp(-(s - unload))
    return sign * u
