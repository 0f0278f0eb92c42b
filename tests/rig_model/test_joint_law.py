"""The rig kernel's joint law (``physics._joint_step``): Bouc-Wen of exponent 1, Dahl at shape 1,
elastic unloading at shape 0, integrated exactly per step (issue 24, deliverable 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig_model.physics import _joint_step
from tests.analysis.test_diagnose_hysteresis import bouc_wen_harmonic_balance
from tests.independent_hb.rig import BoucWen, bouc_wen_force

K0, F_S = 2e6, 20.0  # a seal stiffer than the rods: ~10 um of pre-sliding


def _cycles(z: np.ndarray, shape: float, k0: float = K0, f_s: float = F_S) -> np.ndarray:
    f = np.zeros_like(z)
    for i in range(1, z.size):
        f[i] = _joint_step(f[i - 1], z[i] - z[i - 1], k0, f_s, shape)
    return f


@pytest.mark.parametrize("shape", [0.0, 0.5, 1.0])
def test_stepped_sine_has_the_harmonic_balance_fundamental(shape):
    amp, steps, cycles = 13e-6, 2000, 4
    th = np.arange(cycles * steps + 1) * 2 * math.pi / steps
    f = _cycles(amp * np.sin(th), shape)[-steps - 1:-1]
    c1 = 2 * np.fft.rfft(f)[1] / steps
    want_eq, want_loss = bouc_wen_harmonic_balance(K0, F_S, amp, (1 + shape) / 2,
                                                   (1 - shape) / 2)
    assert -c1.imag / amp == pytest.approx(want_eq, rel=2e-3)
    assert c1.real / amp == pytest.approx(want_loss, rel=2e-3)


def test_shape_zero_is_the_hb_generators_bouc_wen_seal():
    # the independent generator's own law (beta = gamma = 1/2), its periodic steady state
    th = np.arange(400) * 2 * math.pi / 400
    z = 25e-6 * np.sin(th)
    want = bouc_wen_force(z[None, :], BoucWen(force_n=F_S, stiffness_n_per_m=K0))[0]
    got = _cycles(np.tile(z, 30), 0.0)[-400:]
    np.testing.assert_allclose(got, want, atol=1e-9 * F_S)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(f0=st.floats(-1.0, 1.0), dz=st.floats(-30e-6, 30e-6), shape=st.floats(0.0, 1.0),
       split=st.floats(0.05, 0.95))
def test_one_step_is_exact_and_bounded(f0, dz, shape, split):
    # exact per step: one step equals two of its parts (across the branch change at F = 0
    # too), and the force never leaves [-F_s, F_s]
    one = _joint_step(f0 * F_S, dz, K0, F_S, shape)
    two = _joint_step(_joint_step(f0 * F_S, split * dz, K0, F_S, shape), (1 - split) * dz,
                      K0, F_S, shape)
    assert one == pytest.approx(two, abs=1e-9 * F_S)
    assert abs(one) <= F_S * (1 + 1e-12)
    # stiffness at the start: k0 (1 - u) loading, k0 (1 - shape u) unloading (u = sgn F/F_s)
    h = 1e-12
    u = f0 if math.copysign(1.0, dz) > 0 else -f0  # the step's direction, -0.0 included
    slope = (_joint_step(f0 * F_S, math.copysign(h, dz), K0, F_S, shape) - f0 * F_S) / h
    want = K0 * (1 - u) if u >= 0 else K0 * (1 - shape * u)
    assert abs(slope) == pytest.approx(want, rel=1e-3, abs=1e-3 * K0)
