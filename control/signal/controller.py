"""The amplitude controller: a small object fed with measured complex amplitudes, no I/O.

The two shakers and the two controlled responses (displacement or load along X and Y) are treated
as a 2x2 system around the operating point, ``dR = J dD`` with ``R`` the responses' complex
amplitudes at the fundamental and ``D`` the drives' [V]. The controller keeps an estimate of ``J``
(the drive-to-response matrix, including the seal's friction coupling and the frame's modes),
corrects both drives together with a Newton step ``dD = J^-1 (R* - R)``, and refines ``J`` with
Broyden's rank-one secant update from every correction it makes (so an affine plant, such as a
housing held by dry friction, converges as fast as a linear one).

Only the shape of the motion is prescribed: amplitudes and the phase of Y relative to X. The common
phase is free, and each update takes the target ``R* = A exp(i alpha)`` with ``alpha`` the
least-squares phase of the present response, so the controller never chases an absolute phase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Motion = Literal["x", "y", "circular_forward", "circular_backward", "elliptical"]
MOTIONS: tuple[str, ...] = ("x", "y", "circular_forward", "circular_backward", "elliptical")
#: The largest elasticity of the orbit against the drive a first correction assumes
#: (`DrivePredictor.elasticity`): near break-away a dry housing's is unbounded (the Den Hartog
#: law); past this the step is small enough that the watched raise and Broyden take over.
MAX_ELASTICITY = 4.0


def motion_shape(
    motion: str, amplitude: float, ellipse_ratio: float = 1.0, ellipse_phase_deg: float = -90.0
) -> np.ndarray:
    """Complex target amplitudes (X, Y) of a motion, up to a common phase.

    Conventions: ``x(t) = Re(X e^{iwt})``, ``y(t) = Re(Y e^{iwt})``. Forward circular motion
    turns from +X towards +Y (x = A cos wt, y = A sin wt, so Y = -i X); backward turns the other
    way (Y = +i X). Elliptical: |X| = amplitude, |Y| = ellipse_ratio * amplitude, and Y leads X by
    ``ellipse_phase_deg`` (so -90 is forward circular when the ratio is 1).

    Parameters
    ----------
    motion : str
        One of "x", "y", "circular_forward", "circular_backward", "elliptical".
    amplitude : float
        Amplitude of the fundamental [m or N] (of X, or of Y for "y").
    """
    a = float(amplitude)
    if motion == "x":
        return np.array([a, 0.0], dtype=np.complex128)
    if motion == "y":
        return np.array([0.0, a], dtype=np.complex128)
    if motion == "circular_forward":
        return np.array([a, -1j * a], dtype=np.complex128)
    if motion == "circular_backward":
        return np.array([a, 1j * a], dtype=np.complex128)
    if motion == "elliptical":
        return np.array(
            [a, ellipse_ratio * a * np.exp(1j * math.radians(ellipse_phase_deg))],
            dtype=np.complex128,
        )
    raise ValueError(f"unknown motion {motion!r} (use one of {MOTIONS})")


def orbit_peak_radius(z: np.ndarray) -> float:
    """Largest |(x, y)| over a cycle of the orbit ``x = Re(X e^{iwt}), y = Re(Y e^{iwt})``: the
    semi-major axis, sqrt((|X|^2 + |Y|^2 + |X^2 + Y^2|) / 2) [unit of z]."""
    x, y = complex(z[0]), complex(z[1])
    return math.sqrt(0.5 * (abs(x) ** 2 + abs(y) ** 2 + abs(x * x + y * y)))


def active_axes(shape: np.ndarray) -> np.ndarray:
    """Boolean mask of the axes a motion drives (non-zero target)."""
    return np.abs(np.asarray(shape)) > 0


def wrap_deg(angle_deg: float) -> float:
    """Angle wrapped to (-180, 180] [deg]."""
    a = math.fmod(angle_deg + 180.0, 360.0)
    if a <= 0:
        a += 360.0
    return a - 180.0


@dataclass(frozen=True)
class Tolerance:
    """Tolerance band of a converged step.

    Attributes
    ----------
    amplitude_frac : float
        Allowed relative amplitude error of each driven axis (0.01 = +/-1 %).
    phase_deg : float
        Allowed error of the phase of Y relative to X, two-axis motions only [deg].
    """

    amplitude_frac: float = 0.01
    phase_deg: float = 1.0

    def __post_init__(self) -> None:
        if not 0 < self.amplitude_frac < 1:
            raise ValueError(f"amplitude_frac must be in (0, 1), got {self.amplitude_frac}")
        if not 0 < self.phase_deg < 90:
            raise ValueError(f"phase_deg must be in (0, 90), got {self.phase_deg}")


@dataclass(frozen=True)
class Assessment:
    """How far a measured response is from its target.

    Attributes
    ----------
    amplitude_error : array (2,)
        |R| / |A| - 1 per axis (0 on undriven axes).
    phase_error_deg : float
        Error of arg(R_y / R_x) against the target's, wrapped [deg]; 0 for one-axis motions.
    within : bool
        Inside the tolerance band on every driven axis.
    """

    amplitude_error: np.ndarray
    phase_error_deg: float
    within: bool

    def describe(self) -> str:
        amp = ", ".join(f"{100 * e:+.2f} %" for e in self.amplitude_error)
        return f"amplitude error [{amp}], phase error {self.phase_error_deg:+.2f} deg"


@dataclass
class AmplitudeController:
    """Newton-Broyden amplitude and phase controller for two shakers.

    Parameters
    ----------
    shape : complex array (2,)
        Target complex amplitudes (X, Y) up to a common phase (`motion_shape`).
    jacobian : complex array (2, 2)
        First estimate of dR/dD [response unit per V].
    tolerance : Tolerance
        The band a measured response must be inside.
    max_drive_v : float
        Largest drive amplitude the controller will ask for [V].
    max_growth : float
        A single update changes a drive by at most ``max_growth`` times its amplitude (plus
        ``min_step_v``), so one bad estimate cannot throw the drive far.
    min_step_v : float
        Allowed change of a drive that is still near zero [V].
    response_limit : float, optional
        Largest response a correction may aim at, predicted from the present estimate [response
        unit]; None: no bound. The caller sets it to a margin under the trip level, so the
        controller never learns the plant by tripping.
    limit_on_orbit : bool
        ``response_limit`` bounds the orbit radius (displacement); else each axis (load).
    rescale_first : bool
        J comes from another frequency: the first update scales it by the complex factor that
        fits the measured response (magnitude and phase may have moved through a resonance).
    elasticity : float
        With ``rescale_first``: d ln|R| / d ln|D|, the response's growth against the drive
        measured at another frequency (`DrivePredictor.elasticity`). The rescaled J is the
        secant through the origin, which asks the drive to grow by ``q = |R*| / |R|`` for a
        proportional plant; a response growing as ``|D|^e`` needs ``q^(1/e)``, and the first
        raise is shortened to that (a seal slipping more as the drive rises: at 30 Hz on the
        lubricated rig the secant asked 2.2 V where 1.18 V held the target).
    stuck_fraction : float
        Below this fraction of the target on every driven axis the housing counts as stuck:
        a response that small (a housing held by its seal, or just breaking away) says nothing
        about the slope beyond the dead zone.
    breakaway_growth : float
        While nothing moves (a housing stuck on its seal), each update raises the drive by at
        most this fraction (see `breakaway_drive`).
    """

    shape: np.ndarray
    jacobian: np.ndarray
    tolerance: Tolerance = field(default_factory=Tolerance)
    max_drive_v: float = 9.0
    max_growth: float = 2.0
    min_step_v: float = 0.2
    stuck_fraction: float = 1.0 / 3.0
    prior_only: bool = False
    rescale_first: bool = False
    elasticity: float = 1.0
    response_limit: float | None = None
    limit_on_orbit: bool = True
    breakaway_growth: float = 0.25
    updates: int = 0
    saturated: bool = False
    #: what held the last update back ("" when nothing did): "drive", "response", "breakaway"
    limited_by: str = ""
    _last: tuple[np.ndarray, np.ndarray] | None = None
    _stuck: tuple[np.ndarray, np.ndarray] | None = None

    def __post_init__(self) -> None:
        self.shape = np.asarray(self.shape, dtype=np.complex128).reshape(2)
        self.jacobian = np.array(self.jacobian, dtype=np.complex128).reshape(2, 2)
        self.active = active_axes(self.shape)
        if not self.active.any():
            raise ValueError("the target shape has no driven axis")

    def is_stuck(self, response: np.ndarray) -> bool:
        """Nothing moves: every driven axis under ``stuck_fraction`` of its target."""
        a = self.active
        r = np.asarray(response, dtype=np.complex128)
        return bool(np.all(np.abs(r[a]) < self.stuck_fraction * np.abs(self.shape[a])))

    def note_stuck(self, drive: np.ndarray, response: np.ndarray) -> None:
        """Remember the last drive at which nothing moved: the next update measures J as the
        secant from there (J from before says nothing about the plant beyond a dead zone)."""
        self._last = None
        self.prior_only = True
        self._stuck = (np.array(drive, dtype=np.complex128),
                       np.array(response, dtype=np.complex128))

    # --- assessment -------------------------------------------------------------------------
    def assess(self, response: np.ndarray, band: float = 1.0) -> Assessment:
        """Compare measured complex amplitudes (2,) with the target shape.

        ``band`` scales the tolerance (e.g. 0.5: inside half the band).
        """
        r = np.asarray(response, dtype=np.complex128)
        err = np.zeros(2)
        a = self.active
        err[a] = np.abs(r[a]) / np.abs(self.shape[a]) - 1.0
        phase_err = 0.0
        if a.all():
            if abs(r[0]) > 0 and abs(r[1]) > 0:
                measured = math.degrees(np.angle(r[1] / r[0]))
                wanted = math.degrees(np.angle(self.shape[1] / self.shape[0]))
                phase_err = wrap_deg(measured - wanted)
            else:
                phase_err = 180.0
        within = bool(
            np.all(np.abs(err[a]) <= band * self.tolerance.amplitude_frac)
            and abs(phase_err) <= band * self.tolerance.phase_deg
        )
        return Assessment(err, phase_err, within)

    def target_for(self, response: np.ndarray) -> np.ndarray:
        """R* = A exp(i alpha), alpha the least-squares common phase of ``response``."""
        r = np.asarray(response, dtype=np.complex128)
        inner = np.vdot(self.shape, r)  # sum conj(A) R
        rot = inner / abs(inner) if abs(inner) > 0 else 1.0
        return self.shape * rot

    # --- update -----------------------------------------------------------------------------
    def forget(self) -> None:
        """Drop the last (drive, response) pair: the next measurement starts a new secant."""
        self._last = None

    def learn(self, drive: np.ndarray, response: np.ndarray) -> None:
        """Broyden's rank-one update of J from the change since the last measurement."""
        d = np.asarray(drive, dtype=np.complex128)
        r = np.asarray(response, dtype=np.complex128)
        if self._last is not None:
            d0, r0 = self._last
            a = self.active
            dd = (d - d0)[a]
            dr = (r - r0)[a]
            norm2 = float(np.vdot(dd, dd).real)
            if norm2 > (1e-4 * max(float(np.linalg.norm(d[a])), 1e-3)) ** 2:
                j = self.jacobian[np.ix_(a, a)]
                j_new = j + np.outer(dr - j @ dd, dd.conj()) / norm2
                if _well_conditioned(j_new):
                    self.jacobian[np.ix_(a, a)] = j_new
        self._last = (d.copy(), r.copy())

    def update(self, drive: np.ndarray, response: np.ndarray) -> np.ndarray:
        """The next drive (2,) [V] from the present drive and its measured response.

        The step first refines J (Broyden) from the previous call's pair, then takes the Newton
        step towards the target, bounded by ``max_growth``, by ``response_limit`` (the response
        predicted from J and from the measured secant must stay under it) and by
        ``max_drive_v``. While nothing moves, the drive grows by `breakaway_drive` instead.
        Undriven axes stay at zero.
        """
        d = np.asarray(drive, dtype=np.complex128).copy()
        r = np.asarray(response, dtype=np.complex128)
        a = self.active
        self.limited_by = ""
        if self.is_stuck(r):
            # nothing moves (e.g. the seal sticks): raise the drive gently, learn nothing
            self.note_stuck(d, r)
            return self._bounded(self.breakaway_drive(d, r))
        # the first correction after the housing starts moving probes the slope: near
        # break-away a dry housing's response grows much faster than any secant (the Den
        # Hartog law), so that step is small (``breakaway_growth``) until two moving points
        # have measured the slope
        probing = (self.prior_only or self._stuck is not None) and self._last is None
        if self.prior_only:
            # J is only a nominal guess: take its diagonal from the measured secant first,
            # from the last drive that did not move the housing if there is one (a dead zone
            # makes the secant through the origin too shallow)
            if self._stuck is not None:
                d0, r0 = self._stuck
                self.calibrate_from_ratio(d - d0, r - r0)
            else:
                self.calibrate_from_ratio(d, r)
        secant = False  # J was just made the secant through the origin at (d, r)
        if self.rescale_first:
            self.rescale_first = False
            jd = self.jacobian[np.ix_(a, a)] @ d[a]
            den = complex(np.vdot(jd, jd))
            if abs(den) > 0:
                c = complex(np.vdot(jd, r[a])) / den
                if c != 0 and math.isfinite(abs(c)):
                    self.jacobian = self.jacobian * c
                    self._last = None
                    secant = True
        self.learn(d, r)
        target = self.target_for(r)
        j = self.jacobian[np.ix_(a, a)]
        step = np.linalg.solve(j, (target - r)[a])
        if secant and self.elasticity > 1.0:
            q = float(np.linalg.norm(d[a] + step)) / float(np.linalg.norm(d[a]))
            if q > 1.0:
                # the secant through the origin assumes a proportional response: raise by q^(1/e)
                step *= (q ** (1.0 / self.elasticity) - 1.0) / (q - 1.0)
            # and J is the tangent at the measured point, e times the secant: what bounds the
            # response below and what this step passes on if it converges now (the next
            # amplitude's prediction, the next frequency's elasticity)
            self.jacobian = self.jacobian * self.elasticity
        raising = float(np.linalg.norm(d[a] + step)) > float(np.linalg.norm(d[a]))
        probing = probing and raising
        growth = self.breakaway_growth if probing else self.max_growth
        bound = growth * np.abs(d[a]) + (0.0 if probing else self.min_step_v)
        big = np.abs(step) > bound
        if big.any():  # shrink the whole step (keeps its direction) to respect the bound
            step *= float(np.min(bound[big] / np.abs(step[big])))
            self.limited_by = "growth"
        step *= self._response_bounded_fraction(d, r, step)
        new = np.zeros(2, dtype=np.complex128)
        new[a] = d[a] + step
        return self._bounded(new)

    def predicted_peak(self, drive: np.ndarray, response: np.ndarray,
                       new: np.ndarray) -> float:
        """Largest response predicted at drive ``new`` from the pair (``drive``, ``response``).

        The larger of the linear prediction ``R + J (new - drive)`` and the proportional one
        ``|R| |new| / |drive|`` (the secant through the origin); the orbit radius, or the
        largest axis with ``limit_on_orbit`` False [response unit].
        """
        a = self.active
        d = np.asarray(drive, dtype=np.complex128)
        r = np.asarray(response, dtype=np.complex128)
        n = np.asarray(new, dtype=np.complex128)
        linear = r.copy()
        linear[a] = r[a] + self.jacobian[np.ix_(a, a)] @ (n - d)[a]
        peak = self._peak(linear)
        dn = float(np.linalg.norm(d[a]))
        if dn > 0:
            peak = max(peak, self._peak(r) * float(np.linalg.norm(n[a])) / dn)
        return peak

    def _peak(self, z: np.ndarray) -> float:
        return orbit_peak_radius(z) if self.limit_on_orbit else float(np.max(np.abs(z)))

    def _response_bounded_fraction(self, d: np.ndarray, r: np.ndarray, step: np.ndarray) -> float:
        """Largest fraction s in [0, 1] of ``step`` whose predicted response stays within
        ``response_limit`` (bisection: the prediction grows monotonically along the step)."""
        if self.response_limit is None:
            return 1.0
        a = self.active

        def peak(s: float) -> float:
            n = d.copy()
            n[a] = d[a] + s * step
            return self.predicted_peak(d, r, n)

        lim = self.response_limit
        full, now = peak(1.0), peak(0.0)
        if full <= lim or full <= now:
            return 1.0  # within the bound, or a step that does not raise the response
        self.limited_by = "response"
        if now >= lim:
            return 0.0  # already at the bound: hold, never push further
        lo, hi = 0.0, 1.0
        for _ in range(12):  # 1/4096 of the step: finer is below the noise
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if peak(mid) <= lim else (lo, mid)
        return lo

    def breakaway_drive(self, drive: np.ndarray, response: np.ndarray) -> np.ndarray:
        """The next drive while the housing does not move: a gentle raise sized for the jump
        from stick to slip.

        Held by dry friction at drive D_s, the housing breaks away somewhere above D_s, and
        what it does then is bounded by ``|R| <= g sqrt(|D|^2 - |D_s|^2)`` with g the largest
        gain of J (exact for a dead zone, R = g (|D| - D_0) with D_0 >= D_s, and for the
        Den Hartog law of a spring-held housing with Coulomb friction, g sqrt(D^2 - D_0^2)).
        The new drive keeps that bound within the target (and within ``response_limit``), and
        grows by at most ``breakaway_growth`` per update.
        """
        d = np.asarray(drive, dtype=np.complex128)
        a = self.active
        allowed = float(np.min(np.abs(self.shape[a])))
        if self.response_limit is not None:
            allowed = min(allowed, self.response_limit)
        gain = float(np.linalg.svd(self.jacobian[np.ix_(a, a)], compute_uv=False)[0])
        ds = float(np.linalg.norm(d[a]))
        dn = math.sqrt(ds**2 + (allowed / gain) ** 2) if gain > 0 else ds
        self.limited_by = "breakaway"
        if ds == 0.0:
            # nothing driven yet: along the Newton direction of the target
            new = np.zeros(2, dtype=np.complex128)
            new[a] = np.linalg.solve(self.jacobian[np.ix_(a, a)], self.shape[a])
            nn = float(np.linalg.norm(new[a]))
            return new * (dn / nn) if nn > 0 else new
        return d * min(dn / ds, 1.0 + self.breakaway_growth)

    def _bounded(self, new: np.ndarray) -> np.ndarray:
        new = np.where(self.active, new, 0.0).astype(np.complex128)
        peak = float(np.max(np.abs(new)))
        self.saturated = peak > self.max_drive_v or self.limited_by == "response"
        if peak > self.max_drive_v:
            new *= self.max_drive_v / peak
            self.limited_by = "drive"
        self.updates += 1
        return new

    def calibrate_from_ratio(self, drive: np.ndarray, response: np.ndarray) -> None:
        """Replace J by diag(R_j / D_j) on the driven axes (a secant: through the origin, or
        between two measurements when given their differences)."""
        a = self.active
        d = np.asarray(drive, dtype=np.complex128)
        r = np.asarray(response, dtype=np.complex128)
        if np.any(np.abs(d[a]) == 0) or np.any(np.abs(r[a]) == 0):
            return
        j = np.zeros((2, 2), dtype=np.complex128)
        j[a, a] = r[a] / d[a]
        if _well_conditioned(j[np.ix_(a, a)]):
            self.jacobian = np.where(np.outer(a, a), j, self.jacobian)
            self._last = None
        self.prior_only = False


def _well_conditioned(j: np.ndarray) -> bool:
    if not np.all(np.isfinite(j)):
        return False
    s = np.linalg.svd(j, compute_uv=False)
    return bool(s[-1] > 0 and s[0] / s[-1] < 1e6)


@dataclass
class _Point:
    freq_hz: float
    shape: np.ndarray  # target (2,) complex, common phase removed
    drive: np.ndarray  # drive (2,) for that target, same common phase [V]
    jacobian: np.ndarray  # (2, 2)


class DrivePredictor:
    """Remembers converged steps and predicts the drive and the matrix J for the next one.

    Prediction, in order of preference: (1) a converged step at the same frequency: move along
    its tangent, ``D = D_i + J_i^-1 (A - A_i)`` (exact for an affine plant such as a housing with
    dry friction); for orbit targets (``orbit``) its size from the friction law through two or
    three steps there whose targets had this shape (`_friction_law`); (2) the two nearest
    converged frequencies at the same target: linear extrapolation of the drive in frequency;
    (3) the nearest frequency's tangent; (4) nothing: the caller's prior.

    ``orbit``: the targets are orbits (displacement), which friction makes grow unlike the
    drive; a load follows the drive in proportion (the shaker's force), and its tangent is
    exact.
    """

    def __init__(self, orbit: bool = True) -> None:
        self._points: list[_Point] = []
        self.orbit = orbit

    def __len__(self) -> int:
        return len(self._points)

    def remember(
        self, freq_hz: float, shape: np.ndarray, response: np.ndarray, drive: np.ndarray,
        jacobian: np.ndarray,
    ) -> None:
        """Store a converged step: target ``shape``, measured ``response``, ``drive`` and J."""
        r = np.asarray(response, dtype=np.complex128)
        s = np.asarray(shape, dtype=np.complex128)
        inner = np.vdot(s, r)
        rot = inner / abs(inner) if abs(inner) > 0 else 1.0
        # express the drive for a response of exactly the target shape with zero common phase
        self._points.append(_Point(
            float(freq_hz), s.copy(), np.asarray(drive, dtype=np.complex128) / rot,
            np.array(jacobian, dtype=np.complex128),
        ))

    @staticmethod
    def _friction_law(here: list[_Point], s: np.ndarray) -> float | None:
        """The size of the drive |D| [V] for target ``s`` from the converged steps at its
        frequency whose targets had its shape (``k s``); None where fewer than two.

        A linear housing with Coulomb friction (the seal; the fundamental of its force, F_f,
        in phase with the velocity) answers ``F = (K + iC) A + i F_f A / |A|``, so
        ``|D|^2 = a |A|^2 + b |A| + c`` (a = |Z|^2, b = 2 C F_f, c = F_f^2, per gain^2):
        fitted through the nearest three steps, else a straight line through the nearest two
        (the law at resonance, where the friction is in phase with all of Z A). The tangent
        of one step is a straight line through a point measured over a few millivolts: on the
        lubricated rig it missed the next amplitude up by -2 to +15 %; the law by -1.8 to
        +0.1 % (the film stiffens the orbit as it grows, which the law leaves out: it errs
        low, on the safe side)."""
        ns = float(np.linalg.norm(s))
        if ns == 0:
            return None
        alike: list[tuple[float, float]] = []  # (k, |D|)
        for p in here:
            k = float(np.vdot(s, p.shape).real) / ns**2
            if k > 0 and np.allclose(p.shape, k * s, rtol=1e-9, atol=0):
                alike.append((k, float(np.linalg.norm(p.drive))))
        alike.sort(key=lambda kd: abs(math.log(kd[0])))
        if len(alike) < 2:
            return None
        near = alike[:3]
        ks = np.array([k for k, _ in near])
        ds = np.array([d for _, d in near])
        if np.min(np.abs(np.subtract.outer(ks, ks)) + np.eye(len(ks))) <= 1e-6 * float(ks.max()):
            return None
        d = np.nan
        if len(near) == 3:
            a, b, c = np.linalg.solve(np.vander(ks, 3), ds**2)
            if a > 0 and a + b + c > 0:
                d = math.sqrt(a + b + c)
        if not d > 0:  # the straight line through the nearest two
            slope = (ds[1] - ds[0]) / (ks[1] - ks[0])
            d = ds[0] + slope * (1.0 - ks[0]) if slope > 0 else np.nan
        return float(d) if d > 0 and math.isfinite(d) else None

    def knows(self, freq_hz: float) -> bool:
        """A converged step at this frequency is remembered."""
        return any(abs(p.freq_hz - freq_hz) <= 1e-9 * max(1.0, freq_hz) for p in self._points)

    def elasticity(self, freq_hz: float, shape: np.ndarray) -> float:
        """d ln|R| / d ln|D| along the drive at the converged step nearest in frequency (at the
        same target if one is remembered): its tangent over its secant through the origin,
        ``Re <A, J D> / |A|^2``, held to [1, `MAX_ELASTICITY`]; 1 (proportional) when nothing is
        remembered. A seal that slips more as the drive rises makes the orbit grow faster than
        the drive (measured on the lubricated rig: 1.5 at 38 um, 3.7 at 13 um)."""
        if not self._points:
            return 1.0
        s = np.asarray(shape, dtype=np.complex128)
        same = [p for p in self._points if np.allclose(p.shape, s, rtol=1e-9, atol=0)]
        p = min(same or self._points,
                key=lambda p: (abs(p.freq_hz - freq_hz), float(np.linalg.norm(p.shape - s))))
        e = float(np.vdot(p.shape, p.jacobian @ p.drive).real
                  / max(float(np.vdot(p.shape, p.shape).real), 1e-300))
        return min(max(e, 1.0), MAX_ELASTICITY) if math.isfinite(e) else 1.0

    def predict(self, freq_hz: float, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(drive (2,), J (2, 2)) for target ``shape`` at ``freq_hz`` with zero common phase."""
        if not self._points:
            return None
        s = np.asarray(shape, dtype=np.complex128)
        a = active_axes(s)

        def tangent(p: _Point) -> np.ndarray:
            j = p.jacobian[np.ix_(a, a)]
            out = np.zeros(2, dtype=np.complex128)
            out[a] = p.drive[a] + np.linalg.solve(j, (s - p.shape)[a])
            return out

        def same_f(p: _Point) -> bool:
            return abs(p.freq_hz - freq_hz) <= 1e-9 * max(1.0, freq_hz)

        here = [p for p in self._points if same_f(p)]
        if here:
            best = min(here, key=lambda p: float(np.linalg.norm(p.shape - s)))
            drive = tangent(best)
            size = self._friction_law(here, s) if self.orbit else None
            if size is not None and float(np.linalg.norm(drive)) > 0:
                drive *= size / float(np.linalg.norm(drive))  # the tangent's direction
            return drive, best.jacobian.copy()
        same_target = [p for p in self._points if np.allclose(p.shape, s, rtol=1e-9, atol=0)]
        if len(same_target) >= 2:
            near = sorted(same_target, key=lambda p: abs(p.freq_hz - freq_hz))[:2]
            p1, p2 = near
            if abs(p1.freq_hz - p2.freq_hz) > 0:
                slope = (p1.drive - p2.drive) / (p1.freq_hz - p2.freq_hz)
                drive = p1.drive + slope * (freq_hz - p1.freq_hz)
                # never extrapolate to less than half or more than twice the nearest drive
                ratio = float(np.linalg.norm(drive)) / max(float(np.linalg.norm(p1.drive)), 1e-12)
                if 0.5 <= ratio <= 2.0:
                    return drive, p1.jacobian.copy()
                return p1.drive.copy(), p1.jacobian.copy()
        nearest = min(self._points, key=lambda p: abs(p.freq_hz - freq_hz))
        return tangent(nearest), nearest.jacobian.copy()


@dataclass
class ProportionalController(AmplitudeController):
    """A plain proportional level controller, for comparison (the classic sine-control loop).

    Each driven axis is scaled by the ratio of target to measured amplitude, independently of the
    other; in two-axis motions the Y drive is also turned by the phase error. No matrix, no
    learning: what a single-channel sine controller does on each shaker. ``gain`` 1 is the
    plain ratio update ``D <- D A / |R|``; below 1 it moves only part of the way.
    """

    gain: float = 1.0

    def update(self, drive: np.ndarray, response: np.ndarray) -> np.ndarray:
        d = np.asarray(drive, dtype=np.complex128).copy()
        r = np.asarray(response, dtype=np.complex128)
        g = 1.0 + self.max_growth
        new = d.copy()
        for j in np.flatnonzero(self.active):
            want = abs(self.shape[j])
            if abs(r[j]) < self.stuck_fraction * want:
                new[j] = d[j] * g
            else:
                ratio = 1.0 + self.gain * (want / abs(r[j]) - 1.0)
                new[j] = d[j] * min(max(ratio, 1.0 / g), g)
        if self.active.all():
            new[1] *= np.exp(-1j * self.gain * math.radians(self.assess(r).phase_error_deg))
        return self._bounded(new)
