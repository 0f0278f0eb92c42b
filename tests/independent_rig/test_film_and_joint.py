"""The generator's cross-coupled film, air entrainment and micro-slipping joint against closed
forms: the coupled receptance by hand, the Dahl loop's peak force and energy per cycle, the air
fraction's steady mean and the energy balance of the thinned film."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.independent_rig import (
    AirEntrainment,
    DahlJoint,
    Dwell,
    Generator,
    RigSpec,
    Sensors,
)

QUIET: dict[str, float] = {}
M_T = 9.7 + 0.62 + RigSpec().added_mass_kg  # M + M_f + D, the film full
C_T = 370.0 + RigSpec().film_damping_ns_per_m


def fundamental(t: np.ndarray, signal: np.ndarray, freq_hz: float, t0: float) -> complex:
    return complex(2 * np.mean(signal * np.exp(-2j * math.pi * freq_hz * (t - t0))))


def _cycle(seg, freq_hz: float, cycles: int = 1, per_cycle: int = 4000) -> np.ndarray:
    return seg.t0_s + np.linspace(0.0, cycles / freq_hz, cycles * per_cycle + 1)


def test_cross_coupled_film_by_hand() -> None:
    """An x dwell (y unforced): y answers the film's cross force, x's force carries y's."""
    cxy, cyx, dxy, dyx = 1200.0, 900.0, 0.8, -0.5
    rig = RigSpec(film_cross_damping_ns_per_m=(cxy, cyx), film_cross_mass_kg=(dxy, dyx))
    f, a = 35.0, 25e-6
    rec = Generator(rig, Sensors(noise=QUIET)).run([Dwell(f, a, "x", record_s=0.2)])
    seg, t = rec.segments[0], rec.columns["time_s"]
    w = 2 * math.pi * f
    # y: (M_T) y'' + C y' + K_y y = -(C_yx x' + D_yx x'')
    y_want = -(1j * w * cyx - w**2 * dyx) * a / (823e3 - w**2 * M_T + 1j * w * C_T)
    assert fundamental(t, rec.columns["y_m"], f, seg.t0_s) == pytest.approx(y_want, rel=1e-9)
    assert abs(y_want) > 0.1 * a  # the coupling is well above the noise it will meet
    fx_want = (788e3 - w**2 * M_T + 1j * w * C_T) * a + (1j * w * cxy - w**2 * dxy) * y_want
    assert fundamental(t, rec.columns["fx_N"], f, seg.t0_s) == pytest.approx(fx_want, rel=1e-9)
    assert np.max(np.abs(rec.columns["fy_N"])) == 0.0  # unidirectional load


def test_cross_coupled_film_ode_agrees_with_the_closed_form() -> None:
    """The ODE's 2x2 mass solve (forced by a time-varying parameter that does not vary) gives
    the closed form's record, a straight line and a circular orbit."""
    program = [Dwell(25.0, 20e-6, "x", record_s=0.2), Dwell(45.0, 30e-6, "circular_forward",
                                                           record_s=0.2)]
    terms = {"film_cross_damping_ns_per_m": (1200.0, 900.0), "film_cross_mass_kg": (0.8, -0.5)}
    exact = Generator(RigSpec(**terms), Sensors(noise=QUIET)).run(program)  # type: ignore[arg-type]
    ode_rig = RigSpec(residual_damping_ns_per_m=lambda t: 370.0, **terms)  # type: ignore[arg-type]
    ode = Generator(ode_rig, Sensors(noise=QUIET)).run(program)
    for name, scale in (("x_m", 30e-6), ("y_m", 30e-6), ("ax_mps2", 3.0), ("ay_mps2", 3.0),
                        ("fx_N", 50.0), ("fy_N", 50.0)):
        err = np.max(np.abs(ode.columns[name] - exact.columns[name]))
        assert err < 1e-5 * scale, (name, err)


@pytest.mark.parametrize("amplitude_m", [10e-6, 25e-6, 60e-6])
def test_dahl_joint_loop_peak_force_and_energy(amplitude_m: float) -> None:
    """Dry rig, a joint beside the rods' spring: per cycle the shaker's work equals the viscous
    loss plus the Dahl loop's 4 F_s (Z - F_s / k_j tanh(k_j Z / F_s)); the joint's force peaks at
    F_s tanh(k_j Z / F_s) (Z half the stroke: the loop depends on the turning points only)."""
    joint = DahlJoint(stiffness_n_per_m=250e3, slip_force_n=7.5)
    rig = RigSpec(lubricated=False, stiffness_x_n_per_m=788e3 - 250e3, joint=joint)
    f = 30.0
    rec = Generator(rig, Sensors(noise=QUIET)).run([Dwell(f, amplitude_m, "x", record_s=0.1)])
    seg = rec.segments[0]
    t = _cycle(seg, f, cycles=2)
    z, v, fx, state = seg.z(t)[0], seg.v(t)[0], seg.force(t)[0], seg.state(t)
    stroke = 0.5 * (z.max() - z.min())
    work = np.trapezoid(fx * v, t) / 2
    viscous = np.trapezoid(370.0 * v**2, t) / 2
    loop = joint.loop_energy(stroke)
    assert work - viscous == pytest.approx(loop, rel=2e-4)
    assert loop > 0.2 * work  # the joint is a large part of the loss
    top = 7.5 * math.tanh(250e3 * stroke / 7.5)
    assert state[9].max() == pytest.approx(top, rel=1e-5)
    assert state[9].min() == pytest.approx(-top, rel=1e-5)
    assert abs(fundamental(t[:-1], z[:-1], f, seg.t0_s)) == pytest.approx(amplitude_m, rel=2e-3)


def test_dahl_joint_softens_and_damps_more_with_amplitude() -> None:
    """The joint's describing stiffness falls from k_j and its loss factor rises with the
    amplitude (micro-slip), from the dwells' own forces."""
    joint = DahlJoint(stiffness_n_per_m=250e3, slip_force_n=7.5)
    rig = RigSpec(lubricated=False, stiffness_x_n_per_m=788e3 - 250e3, joint=joint)
    linear = RigSpec(lubricated=False, stiffness_x_n_per_m=788e3 - 250e3)
    f = 30.0
    stiff, loss = [], []
    for a in (3e-6, 15e-6, 60e-6):
        seg = Generator(rig, Sensors(noise=QUIET)).run([Dwell(f, a, "x", 0.1)]).segments[0]
        base = Generator(linear, Sensors(noise=QUIET)).run([Dwell(f, a, "x", 0.1)]).segments[0]
        k_eq = (seg.force_n[0] - base.force_n[0]) / a  # the joint's describing function
        stiff.append(k_eq.real)
        loss.append(k_eq.imag / k_eq.real)
    assert stiff[0] == pytest.approx(250e3, rel=0.05)  # nearly stuck at 3 um (F_s/k_j = 30 um)
    assert stiff[0] > stiff[1] > stiff[2]
    assert loss[0] < loss[1] < loss[2]


def test_air_fraction_mean_and_the_thinned_film() -> None:
    """Steady dwell: the air fraction's mean over whole cycles is k mean|v| (the lag's identity);
    the shaker's work per cycle is what the thinned film and C_rv dissipate; with a slow lag the
    force is the quasi-steady receptance's at a = (2/pi) k w A."""
    f, a = 40.0, 38e-6
    w = 2 * math.pi * f
    air = AirEntrainment(coefficient_s_per_m=10.0)
    rig = RigSpec(air=air)
    seg = Generator(rig, Sensors(noise=QUIET)).run([Dwell(f, a, "x", 0.1)]).segments[0]
    t = _cycle(seg, f, cycles=2)
    v, fx, frac = seg.v(t)[0], seg.force(t)[0], seg.state(t)[8]
    mean_speed = np.trapezoid(np.abs(v), t) / (t[-1] - t[0])
    mean_frac = np.trapezoid(frac, t) / (t[-1] - t[0])
    assert mean_frac == pytest.approx(10.0 * mean_speed, rel=1e-4)
    assert mean_frac == pytest.approx(10.0 * 2 / math.pi * w * a, rel=5e-3)
    c_film, d_film = rig.film_damping_ns_per_m, rig.added_mass_kg
    lost = np.trapezoid((370.0 + c_film * (1 - frac) ** 3) * v**2, t)  # type: ignore[operator]
    # the added mass follows the air's ripple: D(t) z'' z' no longer integrates to zero
    pumped = np.trapezoid(d_film * (1 - frac) ** 3 * seg.accel(t)[0] * v, t)  # type: ignore
    assert abs(pumped) < 2e-3 * lost
    assert np.trapezoid(fx * v, t) == pytest.approx(lost + pumped, rel=1e-5)
    # a slow lag (1 s against 25 ms cycles): no ripple, the quasi-steady linear film
    slow = RigSpec(air=AirEntrainment(coefficient_s_per_m=10.0, time_constant_s=1.0))
    seg = Generator(slow, Sensors(noise=QUIET)).run([Dwell(f, a, "x", 0.1)]).segments[0]
    frac0 = 10.0 * 2 / math.pi * w * a
    scale = (1 - frac0) ** 3
    want = (788e3 - w**2 * (10.32 + RigSpec().added_mass_kg * scale)
            + 1j * w * (370.0 + c_film * scale)) * a  # type: ignore[operator]
    assert seg.force_n[0] == pytest.approx(want, rel=2e-3)
    assert scale < 0.85  # the film lost more than 15 % of its damping at this speed
