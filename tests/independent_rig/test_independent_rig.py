"""The independent generator against closed forms, the report's numbers and energy balance."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from tests.independent_rig import (
    COLUMNS,
    Dwell,
    FrameMode,
    Generator,
    RigSpec,
    Sensors,
    Sweep,
    delay,
    gain,
    grid,
)

QUIET = {}  # no sensor noise


def fundamental(t: np.ndarray, signal: np.ndarray, freq_hz: float, t0: float) -> complex:
    """Complex amplitude Z of ``Re(Z e^{i w (t - t0)})`` over whole cycles."""
    return complex(2 * np.mean(signal * np.exp(-2j * math.pi * freq_hz * (t - t0))))


def test_shares_no_code_with_simulated_hw() -> None:
    for path in Path(__file__).parent.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n.split(".")[0] in ("rig_model", "simulated_hw", "analysis", "control")
                           for n in names), f"{path.name} imports {names}"


def test_eq15_eq16_and_the_report_force_levels() -> None:
    rig = RigSpec()
    assert rig.added_mass_kg == pytest.approx(7.58, abs=0.005)  # eq. 15
    assert rig.film_damping_ns_per_m == pytest.approx(5060, abs=2)  # eq. 16, 3.17 cP
    rec = Generator(rig, Sensors(noise=QUIET)).run(grid([20, 40, 60], [38e-6], "x"))
    # docs: |K - w^2 M_T + i w (C_rv + C_sfd)| |z| = 32 / 53 / 102 N for 38 um
    forces = [abs(s.force_n[0]) for s in rec.segments]
    assert forces == pytest.approx([32.3, 53.5, 102.5], abs=0.1)
    assert all(s.force_n[1] == 0 for s in rec.segments)


def test_closed_form_record_is_the_steady_state() -> None:
    rec = Generator(RigSpec(), Sensors(noise=QUIET)).run([Dwell(30.0, 25e-6, "circular_forward")])
    seg = rec.segments[0]
    t = rec.columns["time_s"]
    zx = fundamental(t, rec.columns["x_m"], 30.0, seg.t0_s)
    zy = fundamental(t, rec.columns["y_m"], 30.0, seg.t0_s)
    assert zx == pytest.approx(25e-6, abs=1e-12)
    assert zy == pytest.approx(-25e-6j, abs=1e-12)  # forward: y = A sin wt
    w = 2 * math.pi * 30.0
    m_t = 9.7 + 0.62 + RigSpec().added_mass_kg
    c_t = 370 + RigSpec().film_damping_ns_per_m
    fx = fundamental(t, rec.columns["fx_N"], 30.0, seg.t0_s)
    assert fx == pytest.approx((788e3 - w**2 * m_t + 1j * w * c_t) * 25e-6, rel=1e-9)
    ax = fundamental(t, rec.columns["ax_mps2"], 30.0, seg.t0_s)
    assert ax == pytest.approx(-(w**2) * 25e-6, rel=1e-9)


@pytest.mark.parametrize("frame", [None, FrameMode(frequency_hz=39.0, modal_mass_kg=60.0)])
def test_solve_ivp_agrees_with_the_closed_form(frame: FrameMode | None) -> None:
    """A time-varying parameter that does not vary forces the ODE path: same record."""
    program = [Dwell(25.0, 20e-6, "x", record_s=0.2), Dwell(45.0, 30e-6, "y", record_s=0.2)]
    exact = Generator(RigSpec(frame=frame), Sensors(noise=QUIET)).run(program)
    ode_rig = RigSpec(frame=frame, residual_damping_ns_per_m=lambda t: 370.0)
    assert not ode_rig.is_linear_time_invariant
    ode = Generator(ode_rig, Sensors(noise=QUIET)).run(program)
    for name, scale in (("x_m", 30e-6), ("y_m", 30e-6), ("ax_mps2", 3.0), ("ay_mps2", 3.0)):
        err = np.max(np.abs(ode.columns[name] - exact.columns[name]))
        assert err < 1e-5 * scale, (name, err)


def test_frame_mode_moves_the_resonance() -> None:
    """Dry, no seal: one peak at sqrt(K/M) without the frame, two with it."""
    freqs = np.arange(30.0, 60.0, 0.25)
    plain = RigSpec(lubricated=False)
    framed = RigSpec(lubricated=False, frame=FrameMode(frequency_hz=39.0, modal_mass_kg=40.0))
    peak = freqs[np.argmax([abs(plain.receptance(2 * math.pi * f)[0]) for f in freqs])]
    assert peak == pytest.approx(math.sqrt(788e3 / 9.7) / (2 * math.pi), abs=0.25)
    mag = np.array([abs(framed.receptance(2 * math.pi * f)[0]) for f in freqs])
    peaks = np.flatnonzero((mag[1:-1] > mag[:-2]) & (mag[1:-1] > mag[2:])) + 1
    assert len(peaks) == 2


def test_energy_balance_per_cycle_with_the_seal() -> None:
    """Work of the shaker per cycle = energy dissipated by viscous damping and seal friction."""
    rig = RigSpec(seal_friction_n=26.0)
    rec = Generator(rig, Sensors(noise=QUIET)).run(
        [Dwell(40.0, 25e-6, "circular_forward", record_s=0.1)])
    seg = rec.segments[0]
    assert seg.iterations >= 1
    period = 1 / 40.0
    t = seg.t0_s + np.linspace(0, period, 4001)
    f, v = seg.force(t), seg.v(t)
    work = np.trapezoid(np.sum(f * v, axis=0), t)
    speed = np.hypot(v[0], v[1])
    c = 370 + rig.film_damping_ns_per_m
    dissipated = np.trapezoid(c * speed**2 + 26.0 * speed**2 / np.sqrt(
        speed**2 + rig.seal_v_eps_m_per_s**2), t)
    assert work == pytest.approx(dissipated, rel=1e-3)
    # and the circular-orbit closed form: pi C w A^2 + 2 pi A F_mu per axis pair
    a, w = 25e-6, 2 * math.pi * 40.0
    assert work == pytest.approx(2 * math.pi * c * w * a**2 + 2 * math.pi * a * 26.0, rel=3e-3)
    zx = fundamental(t[:-1], seg.z(t[:-1])[0], 40.0, seg.t0_s)
    assert abs(zx) == pytest.approx(25e-6, rel=2e-3)


def test_sensors_noise_is_seeded_and_transforms_are_exact() -> None:
    program = [Dwell(40.0, 25e-6, "x", record_s=0.1)]
    a = Generator(RigSpec(), Sensors(seed=7)).run(program)
    b = Generator(RigSpec(), Sensors(seed=7)).run(program)
    c = Generator(RigSpec(), Sensors(seed=8)).run(program)
    assert np.array_equal(a.columns["fx_N"], b.columns["fx_N"])
    assert not np.array_equal(a.columns["fx_N"], c.columns["fx_N"])
    quiet = Sensors(noise=QUIET)
    quiet.transforms["x_m"] = [gain(1.05), delay(2e-4)]
    clean = Generator(RigSpec(), Sensors(noise=QUIET)).run(program)
    odd = Generator(RigSpec(), quiet).run(program)
    t, t0 = clean.columns["time_s"], clean.segments[0].t0_s
    z_clean = fundamental(t, clean.columns["x_m"], 40.0, t0)
    z_odd = fundamental(t, odd.columns["x_m"], 40.0, t0)
    ratio = z_odd / z_clean
    assert abs(ratio) == pytest.approx(1.05, rel=1e-9)
    assert -np.angle(ratio) / (2 * math.pi * 40.0) == pytest.approx(2e-4, rel=1e-6)
    assert np.array_equal(odd.columns["fx_N"], clean.columns["fx_N"])


def test_extra_force_and_time_varying_parameter() -> None:
    """A cubic spring stiffens the response; a drifting damping changes the force over time."""
    program = [Dwell(50.0, 35e-6, "x", record_s=0.1)]
    base = Generator(RigSpec(), Sensors(noise=QUIET)).run(program).segments[0]
    k3 = 0.2 * 788e3 / (50e-6) ** 2
    stiff = RigSpec()
    stiff.extra_forces.append(lambda t, z, v: -k3 * z**3)
    seg = Generator(stiff, Sensors(noise=QUIET)).run(program).segments[0]
    # describing function of k3 z^3: 3/4 k3 A^2 extra stiffness
    extra_k = (seg.force_n[0] - base.force_n[0]).real / 35e-6
    assert extra_k == pytest.approx(0.75 * k3 * 35e-6**2, rel=0.02)


def test_sweep_frequency_column_and_csv(tmp_path: Path) -> None:
    rec = Generator(RigSpec(), Sensors(seed=1)).run(
        [Dwell(20.0, 13e-6, "x", record_s=0.1), Sweep(20.0, 60.0, 0.5, 30.0)])
    f = rec.columns["freq_hz"]
    n_dwell = rec.segments[0].last_sample
    assert np.all(f[:n_dwell] == 20.0)
    assert f[n_dwell] == pytest.approx(20.0) and f[-1] == pytest.approx(60.0, abs=0.1)
    path = rec.to_csv(tmp_path / "run.csv")
    header = path.read_text().splitlines()[0]
    assert header == ",".join(COLUMNS)
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    assert data.shape == (len(f), len(COLUMNS))
    assert np.allclose(data[:, 4], rec.columns["x_m"], rtol=1e-8, atol=1e-15)


def test_continuous_record_has_transients_that_settle() -> None:
    """One integration through the programme: the first dwell is steady, the second starts
    with a transient that decays to the same steady state as the separate record."""
    # 0.41 s is not a whole number of 30 Hz cycles: the state jumps at the change of dwell
    program = [Dwell(30.0, 25e-6, "x", record_s=0.41), Dwell(50.0, 25e-6, "x", record_s=0.4)]
    rig = RigSpec(lubricated=True)
    apart = Generator(rig, Sensors(noise=QUIET)).run(program)
    through = Generator(rig, Sensors(noise=QUIET)).run(program, continuous=True)
    x_a, x_t = apart.columns["x_m"], through.columns["x_m"]
    n1 = apart.segments[0].last_sample
    assert np.max(np.abs(x_t[:n1] - x_a[:n1])) < 1e-3 * 25e-6  # first dwell: already steady
    jump = np.max(np.abs(x_t[n1:n1 + 50] - x_a[n1:n1 + 50]))
    settled = np.max(np.abs(x_t[-500:] - x_a[-500:]))
    assert jump > 0.05 * 25e-6  # a transient after the change of dwell
    assert settled < 1e-3 * 25e-6  # overdamped lubricated rig: gone within 0.3 s


@pytest.mark.parametrize("ode", [False, True])
def test_cross_stiffness_dwells_follow_the_coupled_receptance(ode: bool) -> None:
    """The rods' cross stiffness k_xy: open-loop dwells of a force on x, then on y, move both
    axes by the 2x2 receptance inv(K - w^2 M_T + i w C_T), K = [[K_x, k_xy], [k_xy, K_y]],
    written here by hand (amplitude and phase; closed-form and ODE paths)."""
    k_x, k_y = 788e3, 823e3
    k_xy = 0.15 * math.sqrt(k_x * k_y)
    damping = (lambda t: 370.0) if ode else 370.0  # a callable forces the ODE path
    rig = RigSpec(stiffness_xy_n_per_m=k_xy, residual_damping_ns_per_m=damping)
    assert rig.is_linear_time_invariant is not ode
    freqs, force_n = (20.0, 45.0, 60.0), 30.0
    program = [Dwell(f, motion=m, force_n=force_n, record_s=0.2) for f in freqs
               for m in ("x", "y")]
    rec = Generator(rig, Sensors(noise=QUIET)).run(program)
    m_t = 9.7 + 0.62 + RigSpec().added_mass_kg
    c_t = 370.0 + RigSpec().film_damping_ns_per_m
    t = rec.columns["time_s"]
    tol = 1e-5 if ode else 1e-9
    for seg in rec.segments:
        w = 2 * math.pi * seg.freq_hz
        dyn = np.array([[k_x, k_xy], [k_xy, k_y]]) + (1j * w * c_t - w**2 * m_t) * np.eye(2)
        forced = 0 if seg.motion == "x" else 1
        expected = np.linalg.inv(dyn)[:, forced] * force_n
        sl = slice(seg.first_sample, seg.last_sample)
        for axis, name in enumerate(("x_m", "y_m")):
            z = fundamental(t[sl], rec.columns[name][sl], seg.freq_hz, seg.t0_s)
            assert z == pytest.approx(expected[axis], rel=tol), (seg.freq_hz, seg.motion, name)
        ay = fundamental(t[sl], rec.columns["ay_mps2"][sl], seg.freq_hz, seg.t0_s)
        assert ay == pytest.approx(-(w**2) * expected[1], rel=tol)
    # the cross response is the coupling's: about -k_xy / K_y of the direct one at 20 Hz
    z_y = fundamental(t[:1000], rec.columns["y_m"][:1000], 20.0, 0.0)
    z_x = fundamental(t[:1000], rec.columns["x_m"][:1000], 20.0, 0.0)
    assert abs(z_y / z_x) > 0.1
