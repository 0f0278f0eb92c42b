"""The amplitude controller on known plants, without any I/O."""

from __future__ import annotations

import numpy as np
import pytest

from control.signal.controller import (
    AmplitudeController,
    DrivePredictor,
    Tolerance,
    motion_shape,
    wrap_deg,
)

# A coupled plant: dR = H dD, strong cross terms (friction coupling, frame modes), phases.
H = np.array([[40e-6 * np.exp(-1.1j), 12e-6 * np.exp(0.4j)],
              [-9e-6 * np.exp(2.0j), 35e-6 * np.exp(-0.7j)]])


def _run(ctl: AmplitudeController, plant, drive: np.ndarray,
         max_iter: int = 20) -> tuple[int, np.ndarray]:
    for it in range(max_iter):
        r = plant(drive)
        if ctl.assess(r).within:
            return it, drive
        drive = ctl.update(drive, r)
    raise AssertionError(f"no convergence: {ctl.assess(plant(drive)).describe()}")


def test_motion_shapes_and_direction():
    np.testing.assert_allclose(motion_shape("x", 2.0), [2.0, 0.0])
    np.testing.assert_allclose(motion_shape("y", 2.0), [0.0, 2.0])
    fwd = motion_shape("circular_forward", 1.0)
    # forward: x = cos wt, y = sin wt -> turning from +X to +Y (positive angular velocity)
    wt = np.linspace(0, 2 * np.pi, 100, endpoint=False)
    x, y = (fwd[0] * np.exp(1j * wt)).real, (fwd[1] * np.exp(1j * wt)).real
    assert np.all(x * np.gradient(y) - y * np.gradient(x) > 0)
    bwd = motion_shape("circular_backward", 1.0)
    assert np.angle(bwd[1] / bwd[0]) == pytest.approx(np.pi / 2)
    ell = motion_shape("elliptical", 1.0, 0.5, 30.0)
    assert abs(ell[1]) == pytest.approx(0.5)
    assert np.degrees(np.angle(ell[1] / ell[0])) == pytest.approx(30.0)
    with pytest.raises(ValueError, match="unknown motion"):
        motion_shape("z", 1.0)
    assert wrap_deg(270.0) == pytest.approx(-90.0)


def test_2x2_update_converges_on_a_coupled_linear_plant():
    shape = motion_shape("circular_forward", 30e-6)
    # the controller starts from a diagonal guess with wrong magnitudes and no coupling
    guess = np.diag([60e-6, 20e-6]).astype(complex)
    ctl = AmplitudeController(shape, guess, Tolerance(0.01, 1.0), max_drive_v=10.0)
    iters, drive = _run(ctl, lambda d: H @ d, np.array([0.3, 0.3j]))
    assert iters <= 8
    r = H @ drive
    assert abs(abs(r[0]) / 30e-6 - 1) <= 0.01 and abs(abs(r[1]) / 30e-6 - 1) <= 0.01
    assert abs(wrap_deg(np.degrees(np.angle(r[1] / r[0])) + 90.0)) <= 1.0
    # without the 2x2 treatment (a fixed diagonal gain) the same plant is not brought in
    diag = AmplitudeController(shape, guess, Tolerance(0.01, 1.0), max_drive_v=10.0)
    d = np.array([0.3, 0.3j])
    for _ in range(8):
        diag.jacobian = guess.copy()  # forbid learning: a per-axis proportional loop
        diag._last = None
        d = diag.update(d, H @ d)
    assert not diag.assess(H @ d).within


def test_newton_step_is_exact_with_the_true_matrix():
    shape = motion_shape("elliptical", 20e-6, 0.6, 45.0)
    ctl = AmplitudeController(shape, H.copy(), Tolerance(0.001, 0.1), max_drive_v=10.0,
                              max_growth=100.0)
    d = np.array([0.2 + 0.1j, -0.1j])
    d1 = ctl.update(d, H @ d)
    a = ctl.assess(H @ d1)
    assert a.within
    assert np.max(np.abs(a.amplitude_error)) < 1e-9
    assert abs(a.phase_error_deg) < 1e-7


def test_affine_plant_with_a_dead_zone_converges():
    """A housing held by dry friction: nothing moves below a threshold, then R grows affinely."""
    shape = motion_shape("x", 13e-6)

    def plant(d: np.ndarray) -> np.ndarray:
        mag = max(abs(d[0]) - 0.56, 0.0) * 60e-6
        return np.array([mag * np.exp(1j * (np.angle(d[0]) - 1.3)), 0.0])

    ctl = AmplitudeController(shape, np.diag([50e-6, 50e-6]).astype(complex),
                              Tolerance(0.01, 1.0), max_drive_v=9.0, prior_only=True)
    seen: list[float] = []

    def watched(d: np.ndarray) -> np.ndarray:
        seen.append(abs(plant(d)[0]))
        return plant(d)

    iters, drive = _run(ctl, watched, np.array([0.26, 0.0]))
    assert iters <= 8
    assert abs(abs(plant(drive)[0]) / 13e-6 - 1) <= 0.01
    # broken away gently: the response approaches the target from below, never past it
    assert max(seen) <= 13e-6 * 1.01
    assert seen[:4] == [0.0] * 4 and 0 < seen[5] < 13e-6


def test_break_away_jump_is_sized_for_a_den_hartog_housing():
    """A spring-held housing with Coulomb friction: X = sqrt(F^2 - F0^2) / k above F0, so a
    small raise past break-away makes a large jump. The raises are sized for it: the response
    never passes the target while the controller looks for the break-away."""
    k, f0, gain = 635e3, 33.0, 50.0  # the dry rig at 20 Hz [N/m], [N], shaker [N/V]

    def plant(d: np.ndarray) -> np.ndarray:
        f = abs(d[0]) * gain
        mag = np.sqrt(max(f * f - f0 * f0, 0.0)) / k
        return np.array([mag * np.exp(1j * np.angle(d[0])), 0.0])

    target = 20e-6
    ctl = AmplitudeController(motion_shape("x", target), np.diag([50e-6, 50e-6]).astype(complex),
                              Tolerance(0.01, 1.0), max_drive_v=9.0, prior_only=True,
                              response_limit=50.8e-6)
    d = np.array([0.4, 0.0], dtype=complex)  # the first guess: 20 N, stuck
    seen = []
    for _ in range(15):
        r = plant(d)
        seen.append(abs(r[0]))
        if ctl.assess(r).within:
            break
        d = ctl.update(d, r)
    assert ctl.assess(plant(d)).within
    # the old stuck branch tripled the drive (60 N -> 79 um here); now nothing passes the limit
    assert max(seen) <= 50.8e-6


def test_drive_never_exceeds_the_limit_and_inactive_axis_stays_zero():
    shape = motion_shape("y", 1.0)
    ctl = AmplitudeController(shape, np.eye(2, dtype=complex) * 1e-3, max_drive_v=2.0,
                              max_growth=100.0)
    new = ctl.update(np.array([0.0, 0.5]), np.array([0.3, 0.5]))
    assert abs(new[1]) == pytest.approx(2.0)
    assert new[0] == 0
    assert ctl.saturated


def test_assess_reports_amplitude_and_phase_errors():
    ctl = AmplitudeController(motion_shape("circular_forward", 1.0), np.eye(2, dtype=complex))
    a = ctl.assess(np.array([1.005, 0.98 * np.exp(-1j * np.radians(90.5))]))
    np.testing.assert_allclose(a.amplitude_error, [0.005, -0.02], atol=1e-12)
    assert a.phase_error_deg == pytest.approx(-0.5)
    assert not a.within
    assert ctl.assess(np.array([1.005, 0.995 * np.exp(-1j * np.radians(90.5))])).within


def test_predictor_tangent_is_exact_on_an_affine_plant():
    """Drive for a new amplitude at a known frequency, from J at the old one: exact if affine."""
    b = np.array([0.3 + 0.2j, -0.1j])  # friction-like offset

    def drive_for(r: np.ndarray) -> np.ndarray:  # inverse of R = H (D - b)
        return np.linalg.solve(H, r) + b

    pred = DrivePredictor()
    s13 = motion_shape("circular_backward", 13e-6)
    pred.remember(40.0, s13, s13, drive_for(s13), H)
    s38 = motion_shape("circular_backward", 38e-6)
    d, j = pred.predict(40.0, s38)
    np.testing.assert_allclose(d, drive_for(s38), rtol=1e-12)
    np.testing.assert_allclose(j, H)
    assert DrivePredictor().predict(40.0, s38) is None


def test_predictor_extrapolates_along_frequency_at_the_same_target():
    pred = DrivePredictor()
    s = motion_shape("x", 25e-6)

    def drive_at(f: float) -> np.ndarray:  # a drive that grows linearly with frequency
        return np.array([0.5 + 0.01 * f + 0.002j * f, 0.0])

    for f in (20.0, 30.0):
        pred.remember(f, s, s, drive_at(f), np.diag([50e-6, 50e-6]).astype(complex))
    d, _ = pred.predict(40.0, s)
    np.testing.assert_allclose(d, drive_at(40.0), rtol=1e-12)
    # an extrapolation that would more than double the drive is not trusted
    pred2 = DrivePredictor()
    pred2.remember(20.0, s, s, np.array([0.1, 0]), np.eye(2, dtype=complex))
    pred2.remember(21.0, s, s, np.array([1.0, 0]), np.eye(2, dtype=complex))
    d2, _ = pred2.predict(30.0, s)
    np.testing.assert_allclose(d2, [1.0, 0])


def test_the_first_correction_at_a_new_frequency_raises_by_the_elasticity_measured_before():
    """A seal slipping more as the drive rises: the orbit grows as |D|^2.5. The step converged
    at 20 Hz tells that slope (its tangent over its secant); at 30 Hz the first measurement
    holds 44 % of the target, and the secant through the origin would ask 2.3x the drive (the
    orbit 2.3^2.5 = 7.9x the target). Raised by (A/R)^(1/e) it lands on the target."""
    e, s = 2.5, motion_shape("x", 25e-6)

    def plant(c: float):  # R = c |D|^e along X, in phase with the drive
        return lambda d: np.array([c * abs(d[0]) ** e * np.exp(1j * np.angle(d[0])), 0.0])

    d20 = np.array([0.98, 0.0], dtype=complex)
    at20 = plant(25e-6 / 0.98 ** e)
    j20 = np.diag([e * at20(d20)[0] / d20[0], 40e-6])  # the tangent at the converged step
    pred = DrivePredictor()
    pred.remember(20.0, s, at20(d20), d20, j20)
    assert pred.elasticity(30.0, s) == pytest.approx(e)
    at30 = plant(25e-6 / 1.18 ** e)  # 1.18 V holds the target at 30 Hz
    ctl = AmplitudeController(s, j20, max_drive_v=9.0, rescale_first=True,
                              elasticity=pred.elasticity(30.0, s))
    d1 = np.array([0.85, 0.0], dtype=complex)
    new = ctl.update(d1, at30(d1))
    assert abs(at30(new)[0]) == pytest.approx(25e-6, rel=1e-9)
    # J is the tangent at the measured point, not the secant: a step that converges on this
    # correction passes it on (the secant made the next amplitude's tangent ask 18 % too much)
    assert ctl.jacobian[0, 0] == pytest.approx(e * at30(d1)[0] / d1[0], rel=1e-9)
    # with nothing remembered: proportional, the secant through the origin as before
    assert DrivePredictor().elasticity(30.0, s) == 1.0


def test_a_known_frequencys_drive_follows_the_friction_law_through_its_converged_steps():
    """A linear housing with Coulomb friction: |D|^2 = a A^2 + b A + c. Three converged steps
    at 40 Hz, each with a tangent J 30 % off (a last correction of a few millivolts): the drive
    for the next amplitude up is the law's, not the tangent's; two steps give the straight line
    through them."""
    a, b, c = 2.0e9, 2.0e4, 0.16  # |Z|/gain 0.045 V/um, friction 0.4 V; b^2 < 4ac: C < |Z|

    def size(amp: float) -> float:
        return float(np.sqrt(a * amp**2 + b * amp + c))

    pred = DrivePredictor()
    for amp in (13e-6, 19e-6, 25e-6):
        slope = 2 * size(amp) / (2 * a * amp + b)  # dA/d|D|, the true tangent
        j = np.diag([1.3 * slope, 40e-6]).astype(complex)
        s = motion_shape("x", amp)
        pred.remember(40.0, s, s, np.array([size(amp), 0.0], dtype=complex), j)
    d, _ = pred.predict(40.0, motion_shape("x", 32e-6))
    assert abs(d[0]) == pytest.approx(size(32e-6), rel=1e-9)
    two = DrivePredictor()
    for amp in (13e-6, 19e-6):
        s = motion_shape("x", amp)
        two.remember(40.0, s, s, np.array([size(amp), 0.0], dtype=complex),
                     np.diag([40e-6, 40e-6]).astype(complex))
    d2, _ = two.predict(40.0, motion_shape("x", 25e-6))
    line = size(19e-6) + (size(19e-6) - size(13e-6)) * (25 - 19) / (19 - 13)
    assert abs(d2[0]) == pytest.approx(line, rel=1e-9)
