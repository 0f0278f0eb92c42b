"""The rig model's terms added for issue 28 (docs/report-discrepancies.md), each against a closed
form written here: the relaxing stiffness (a Maxwell element beside the rods), the seal's friction
with the film full, the seal contact's and the joint's stiffness per axis. All off by default."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig_model import RigParams, simulate_response
from rig_model.params import Contact, Film, Seal

FS = 10_000.0


def _lockin(sig: np.ndarray, freq_hz: float, t: np.ndarray, last_s: float) -> complex:
    """Complex amplitude over the whole cycles in the last ``last_s`` seconds."""
    n_cyc = math.floor(last_s * freq_hz)
    n = int(round(n_cyc * FS / freq_hz))
    return complex(2.0 * np.mean(sig[-n:] * np.exp(-1j * 2 * np.pi * freq_hz * t[-n:])))


def _dry_linear_rig() -> RigParams:
    """No seal, no journal wall: the rods, the mass and the residual damping only."""
    return RigParams(seal=Seal(enabled=False), contact=Contact(enabled=False))


def _relaxing_rig(k_rx: float, k_ry: float, tau_s: float) -> RigParams:
    p = _dry_linear_rig()
    r = p.effects.relaxing_stiffness
    r.enabled, r.stiffness_x_n_per_m, r.stiffness_y_n_per_m, r.relaxation_time_s = (
        True, k_rx, k_ry, tau_s)
    return p


def test_the_new_terms_are_off_by_default_and_change_no_bit():
    # the nominal rig with each new field at its default, and explicitly neutral, gives the
    # same response to the bit (kernel parameters appended, not reordered)
    t = np.arange(4000) / FS
    force = np.vstack([30 * np.sin(2 * np.pi * 30 * t), 20 * np.cos(2 * np.pi * 30 * t)])
    base, _ = simulate_response(force, RigParams(), FS, fill=1.0)
    p = RigParams()
    p.seal.wet_friction_increase_n = 0.0
    p.seal.contact_stiffness_y_n_per_m = None
    p.effects.relaxing_stiffness.stiffness_y_n_per_m = 5e5  # not enabled: no effect
    same, _ = simulate_response(force, p, FS, fill=1.0)
    assert np.array_equal(base.x_m, same.x_m) and np.array_equal(base.y_m, same.y_m)


def test_relaxing_stiffness_static_reads_the_rods_dynamic_reads_both():
    """A held force: after many tau the deflection is F / K (the rods alone; Table 2's test).
    A harmonic force at 30 Hz: the dynamic stiffness plus w^2 M is K + k_r (w tau)^2 / (1 +
    (w tau)^2) within 0.1 %, the damping C_rv + k_r tau / (1 + (w tau)^2) within 0.5 % (the
    Maxwell element's closed form)."""
    k_y, k_r, tau = 786e3, 137e3, 0.1
    p = _relaxing_rig(0.0, k_r, tau)
    p.structure.stiffness_y_n_per_m = k_y
    # static: 50 N on Y, raised over 50 ms, held 2 s (20 tau)
    t = np.arange(int(2.0 * FS)) / FS
    fy = 50.0 * np.minimum(t / 0.05, 1.0)
    tr, _ = simulate_response(np.vstack([np.zeros_like(t), fy]), p, FS, fill=0.0)
    assert 50.0 / np.mean(tr.y_m[-2000:]) == pytest.approx(k_y, rel=2e-3)
    # dynamic at 30 Hz, 4 s (40 tau) so that the element's transient has died out
    f_hz = 30.0
    w = 2 * math.pi * f_hz
    t = np.arange(int(4.0 * FS)) / FS
    fy = 20.0 * np.cos(w * t)
    tr, _ = simulate_response(np.vstack([np.zeros_like(t), fy]), p, FS, fill=0.0)
    h = _lockin(fy, f_hz, t, 1.0) / _lockin(tr.y_m, f_hz, t, 1.0)
    wt2 = (w * tau) ** 2
    st = p.structure
    k_dyn = k_y + k_r * wt2 / (1 + wt2)  # 921.6 kN/m
    c_dyn = st.residual_damping_y() + k_r * tau / (1 + wt2)  # 370 + 38.5 N.s/m
    assert h.real + w**2 * st.mass_y() == pytest.approx(k_dyn, rel=1e-3)
    assert h.imag / w == pytest.approx(c_dyn, rel=5e-3)
    # X, without its own k_r, is the rods and the mass only
    p2 = _relaxing_rig(0.0, k_r, tau)
    tr, _ = simulate_response(np.vstack([fy, np.zeros_like(t)]), p2, FS, fill=0.0)
    hx = _lockin(fy, f_hz, t, 1.0) / _lockin(tr.x_m, f_hz, t, 1.0)
    assert hx.real + w**2 * 9.7 == pytest.approx(788e3, rel=1e-3)


@pytest.mark.parametrize("fill", [0.0, 0.5, 1.0])
def test_seal_friction_rises_with_the_film_full(fill: float):
    """Slipping all the time (a 2 Hz circular orbit, 400 N), the seal force's magnitude is
    F_mu + fill x the wet increase: 26, 27.5, 29 N, within 0.1 %."""
    p = RigParams(contact=Contact(enabled=False), film=Film(added_mass_kg=0.0,
                                                             damping_scale=1e-6))
    p.seal.wet_friction_increase_n = 3.0
    t = np.arange(int(1.5 * FS)) / FS
    w = 2 * math.pi * 2.0
    force = 400.0 * np.vstack([np.cos(w * t), np.sin(w * t)])
    tr, _ = simulate_response(force, p, FS, fill=fill)
    mag = np.hypot(tr.friction_x_n, tr.friction_y_n)[-5000:]
    assert np.median(mag) == pytest.approx(26.0 + 3.0 * fill, rel=1e-3)


def _held_force(p: RigParams, axis: int, force_n: float, seconds: float) -> tuple[float, float]:
    """A force on one axis, raised over 50 ms and held, dry: the mean displacement [m] and seal
    force [N] along that axis over the last fifth of the record."""
    t = np.arange(int(seconds * FS)) / FS
    force = np.zeros((2, t.size))
    force[axis] = force_n * np.minimum(t / 0.05, 1.0)
    tr, _ = simulate_response(force, p, FS, fill=0.0)
    last = slice(-t.size // 5, None)
    return (float(np.mean((tr.x_m, tr.y_m)[axis][last])),
            float(np.mean((tr.friction_x_n, tr.friction_y_n)[axis][last])))


def test_seal_contact_stiffness_per_axis_while_stuck():
    """A small static force on each axis in turn (5 N, below F_mu = 26 N, so the seal holds):
    the housing moves on the contact, F = (K + k_t) z, with k_t 35 MN/m on X and 22 MN/m on Y."""
    p = RigParams(contact=Contact(enabled=False))
    p.seal.contact_stiffness_n_per_m = 35e6
    p.seal.contact_stiffness_y_n_per_m = 22e6
    for axis, k_s, k_t in ((0, 788e3, 35e6), (1, 823e3, 22e6)):
        z, seal = _held_force(p, axis, 5.0, 0.5)
        assert 5.0 / z == pytest.approx(k_s + k_t, rel=2e-3)
        assert -seal / z == pytest.approx(k_t, rel=1e-3)


def test_joint_per_axis_stuck_stiffness():
    """The micro-slipping joint with its own Y values: stuck (0.5 N, far below F_s = 50 N) it
    adds k_j along each axis: 100 kN/m on X, 400 kN/m on Y (a static force, within 1 %)."""
    p = _dry_linear_rig()
    j = p.effects.joint_microslip
    j.enabled, j.stiffness_n_per_m, j.slip_force_n = True, 100e3, 50.0
    j.stiffness_y_n_per_m, j.slip_force_y_n = 400e3, 50.0
    for axis, k_s, k_j in ((0, 788e3, 100e3), (1, 823e3, 400e3)):
        z, _ = _held_force(p, axis, 0.5, 1.0)
        assert 0.5 / z == pytest.approx(k_s + k_j, rel=1e-2)
