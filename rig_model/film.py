"""What the simulated film does, in closed form: the reference values identification is judged by.

The simulator's film damping follows eq. 16 with the instantaneous eccentricity
``eps(t) = |r(t)| / c`` (``Film.eccentricity_law``), capped at 0.95 as in the kernel. A periodic
motion therefore sees a damping that varies over the cycle; the single coefficient a
frequency-domain identification returns is its energy equivalent:

    C_eq = integral C(eps(t)) v(t)^2 dt / integral v(t)^2 dt   (over one cycle).

Air entrainment and partial fill are not included (they are off in the report's rig).
"""

from __future__ import annotations

import numpy as np

from rig_model.params import RigParams

ECC_CAP = 0.95  # the kernel's cap on eps (eq. 16 diverges at contact)


def eccentricity_factor(eps: np.ndarray | float) -> np.ndarray:
    """Eq. 16's ``(1 + 2 eps^2) / (1 - eps^2)^2``, with eps capped as the kernel does."""
    e2 = np.minimum(np.asarray(eps, dtype=np.float64) ** 2, ECC_CAP**2)
    return (1.0 + 2.0 * e2) / (1.0 - e2) ** 2


def film_viscosity_pa_s(params: RigParams, temperature_c: float | None = None) -> float:
    """Viscosity the simulated film uses at ``temperature_c`` (default: its reference) [Pa.s]."""
    if temperature_c is None:
        return params.film.reference_viscosity()[0]
    return params.film.viscosity_pa_s(temperature_c)


def energy_equivalent_damping(params: RigParams, amplitude_m: float, motion: str = "x",
                              temperature_c: float | None = None, n_points: int = 4096) -> float:
    """Energy-equivalent film damping of the simulated rig for a centred harmonic motion.

    Parameters
    ----------
    params : RigParams
        The simulated rig.
    amplitude_m : float
        Amplitude of the fundamental motion [m] (radius for circular orbits).
    motion : {"x", "y", "circular_forward", "circular_backward"}
        Unidirectional motion along one axis, or a circular centred orbit.
    temperature_c : float, optional
        Oil temperature [degC]; default the film's reference temperature.
    n_points : int
        Points over one cycle for the quadrature.

    Returns
    -------
    float
        ``integral C(eps) v^2 / integral v^2`` [N.s/m].
    """
    if motion not in ("x", "y", "circular_forward", "circular_backward"):
        raise ValueError(f"motion {motion!r} not supported (x, y or circular_*)")
    film = params.film
    c0 = film.eq16_damping_centred(film_viscosity_pa_s(params, temperature_c))
    if not film.eccentricity_law:
        return float(c0)
    if motion.startswith("circular"):
        return float(c0 * eccentricity_factor(amplitude_m / film.clearance_m))
    theta = np.linspace(0.0, 2 * np.pi, n_points, endpoint=False)
    eps = np.abs(amplitude_m * np.cos(theta)) / film.clearance_m
    v2 = np.sin(theta) ** 2
    return float(c0 * np.sum(eccentricity_factor(eps) * v2) / np.sum(v2))


def eq16_damping(params: RigParams, eps: float, temperature_c: float | None = None) -> float:
    """Eq. 16 at a static eccentricity ratio ``eps`` (no energy averaging) [N.s/m]."""
    film = params.film
    c0 = film.eq16_damping_centred(film_viscosity_pa_s(params, temperature_c))
    return float(c0 * eccentricity_factor(eps))
