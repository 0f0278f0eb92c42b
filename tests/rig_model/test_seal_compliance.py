"""The compliant seal (a tangential spring in series with the Coulomb slider, one Iwan element)
against closed forms: statics below and above F_mu, and the elasto-plastic loop's dissipation."""

from __future__ import annotations

import numpy as np
import pytest

from rig_model import RigParams, simulate_response
from rig_model.params import Seal

FS = 10_000.0
K_X = 788e3
F_MU = 26.0


def _rig(kt: float | None) -> RigParams:
    return RigParams(seal=Seal(friction_force_n=F_MU, contact_stiffness_n_per_m=kt))


def _ramp_and_hold(peak_n: float, params: RigParams) -> float:
    """x [m] after a slow 1 s ramp to ``peak_n`` along x and a 1 s hold (dry, no film); the ramp
    is a half cosine, so the load arrives without a jerk that would ring the housing."""
    n = int(2 * FS)
    f = np.zeros((2, n))
    f[0] = peak_n * 0.5 * (1 - np.cos(np.pi * np.clip(np.arange(n) / FS, 0.0, 1.0)))
    tr, _ = simulate_response(f, params, FS, fill=0.0)
    return float(tr.x_m[-1])


@pytest.mark.parametrize("kt", [5e5, 2e6])
def test_below_f_mu_the_housing_moves_on_the_contact_spring(kt: float):
    # rigid sticking holds the housing still; the compliant contact is a spring in parallel
    assert abs(_ramp_and_hold(20.0, _rig(None))) < 1e-12
    assert _ramp_and_hold(20.0, _rig(kt)) == pytest.approx(20.0 / (K_X + kt), rel=2e-3)


@pytest.mark.parametrize("kt", [None, 2e6])
def test_above_f_mu_the_slider_holds_f_mu(kt: float | None):
    # after slipping, the seal holds F_mu against the load: K x = F - F_mu either way
    assert _ramp_and_hold(60.0, _rig(kt)) == pytest.approx((60.0 - F_MU) / K_X, rel=2e-3)


@pytest.mark.parametrize("kt", [1e6, 4e6])
def test_loop_dissipates_four_f_mu_times_amplitude_less_the_elastic_travel(kt: float):
    # an elastic-perfectly-plastic element cycled at amplitude A > F_mu/kt dissipates
    # 4 F_mu (A - F_mu/kt) per cycle (rigid Coulomb: 4 F_mu A)
    freq = 20.0
    n = int(1.0 * FS)
    t = np.arange(n) / FS
    f = np.zeros((2, n))
    f[0] = 60.0 * np.sin(2 * np.pi * freq * t)
    tr, _ = simulate_response(f, _rig(kt), FS, fill=0.0)
    last = slice(n - int(FS / freq) * 4, n)  # four whole cycles in steady state
    x, fr = tr.x_m[last], tr.friction_x_n[last]
    amp = (x.max() - x.min()) / 2
    dx = np.diff(x)
    work = -float(np.sum(0.5 * (fr[1:] + fr[:-1]) * dx)) / 4
    assert amp > 2 * F_MU / kt
    assert work == pytest.approx(4 * F_MU * (amp - F_MU / kt), rel=0.02)


def test_per_axis_mass_and_damping_give_each_axis_its_own_receptance():
    # Table 3's per-axis structure (8.8 kg / 367 N.s/m in X, 9.7 kg / 315 N.s/m in Y), seal off,
    # dry: the steady receptance of each axis is 1 / (K - w^2 M + i w C) of its own axis
    from rig_model.params import Structure

    st = Structure(mass_kg=8.8, mass_y_kg=9.7, residual_damping_ns_per_m=367.0,
                   residual_damping_y_ns_per_m=315.0)
    params = RigParams(structure=st, seal=Seal(enabled=False))
    freq = 30.0
    n = int(3.0 * FS)
    t = np.arange(1, n + 1) / FS
    f = np.vstack([10.0 * np.cos(2 * np.pi * freq * t), 10.0 * np.sin(2 * np.pi * freq * t)])
    tr, _ = simulate_response(f, params, FS, fill=0.0)
    w = 2 * np.pi * freq
    last = slice(n - int(FS / freq) * 20, n)
    ph = np.exp(-1j * w * t[last])
    for z, force, k, m, c in ((tr.x_m, f[0], st.stiffness_x_n_per_m, 8.8, 367.0),
                              (tr.y_m, f[1], st.stiffness_y_n_per_m, 9.7, 315.0)):
        h = np.mean(z[last] * ph) / np.mean(force[last] * ph)
        assert h == pytest.approx(1 / (k - w**2 * m + 1j * w * c), rel=2e-3)
