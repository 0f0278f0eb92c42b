"""The joint's describing function (``analysis.diagnose.hysteresis``) against its law solved
independently here: Dahl stepped in displacement, and the Bouc-Wen law (every shape) by a
numerical harmonic balance (Runge-Kutta over cycles until periodic, then the fundamental), its
equivalent and loss stiffness per amplitude, as a finding reports them (issue 24, deliverable 4).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose.hysteresis import (
    amplitude_levels,
    describing_function_text,
    joint_describing_function,
    joint_table,
)


def _stepped(k_j: float, f_s: float, amp: float, cycles: int = 4,
             steps: int = 40000) -> tuple[float, float]:
    """Fundamental of the Dahl force stepped in small displacement increments over several
    cycles (the last one kept): dF = k_j (1 - sgn(dz) F / F_s) dz."""
    th = np.linspace(0.0, 2 * math.pi * cycles, cycles * steps + 1)
    z = amp * np.sin(th)
    f = np.zeros_like(z)
    for i in range(1, z.size):
        dz = z[i] - z[i - 1]
        f[i] = f[i - 1] + k_j * (1 - math.copysign(1.0, dz) * f[i - 1] / f_s) * dz
    last = slice((cycles - 1) * steps, cycles * steps)
    return (float(2 * np.mean(f[last] * np.sin(th[last])) / amp),
            float(2 * np.mean(f[last] * np.cos(th[last])) / amp))


def bouc_wen_harmonic_balance(k0: float, f_s: float, amp: float, beta: float, gamma: float,
                              steps: int = 4000, tol: float = 1e-10) -> tuple[float, float]:
    """Numerical harmonic balance of F = F_s w, dw/dz = (k0 / F_s) (1 - (beta sgn(w z')
    + gamma) |w|) under z = A sin(theta): w integrated in theta (classical Runge-Kutta) cycle
    after cycle until it repeats, then the fundamental of the last cycle by the FFT."""
    kappa_amp = k0 * amp / f_s
    h = 2 * math.pi / steps

    def rate(th: float, w: float) -> float:
        dz = math.cos(th)
        return kappa_amp * dz * (1 - (beta * math.copysign(1.0, w * dz) + gamma) * abs(w))

    w = 0.0
    cycle = np.empty(steps)
    for _ in range(50):
        w_start = w
        for i in range(steps):
            th = i * h
            cycle[i] = w
            k1 = rate(th, w)
            k2 = rate(th + h / 2, w + h / 2 * k1)
            k3 = rate(th + h / 2, w + h / 2 * k2)
            k4 = rate(th + h, w + h * k3)
            w += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if abs(w - w_start) < tol:
            break
    # F1 e^{i theta} convention of z = A sin(theta) = Im(A e^{i theta}): in phase with sin is
    # the stiffness, with cos the loss
    c1 = 2 * np.fft.rfft(f_s * cycle)[1] / steps  # = a1 - i b1 for a1 cos + b1 sin
    return float(-c1.imag / amp), float(c1.real / amp)


@pytest.mark.parametrize(("k_j", "f_s", "amp"), [
    (2e6, 20.0, 13e-6),   # a seal stiffer than the rods, ~10 um of pre-sliding
    (2e6, 20.0, 38e-6),
    (3e5, 8.0, 25e-6),    # a rods' clamp
])
def test_dahl_describing_function_matches_the_law_stepped_in_time(k_j, f_s, amp):
    k_eq, k_loss = joint_describing_function(k_j, f_s, amp, shape=1.0)
    want_eq, want_loss = _stepped(k_j, f_s, amp)
    assert k_eq == pytest.approx(want_eq, rel=2e-3)
    assert k_loss == pytest.approx(want_loss, rel=2e-3)


@pytest.mark.parametrize("shape", [0.0, 0.3, 0.7, 1.0])
@pytest.mark.parametrize(("k0", "f_s", "amp"), [
    (2e6, 20.0, 4e-6),    # mostly pre-sliding
    (2e6, 20.0, 13e-6),   # the seal stiffer than the rods at the smallest dwell level
    (2e6, 20.0, 38e-6),   # mostly sliding
])
def test_bouc_wen_describing_function_matches_a_numerical_harmonic_balance(k0, f_s, amp, shape):
    # beta + gamma = 1 (saturation at F_s), beta - gamma = shape
    beta, gamma = (1 + shape) / 2, (1 - shape) / 2
    k_eq, k_loss = joint_describing_function(k0, f_s, amp, shape=shape)
    want_eq, want_loss = bouc_wen_harmonic_balance(k0, f_s, amp, beta, gamma)
    assert k_eq == pytest.approx(want_eq, rel=1e-4)
    assert k_loss == pytest.approx(want_loss, rel=1e-4)


def test_the_smooth_seal_dissipates_less_than_dahl_at_the_same_stiffness_and_slip():
    # elastic unloading (shape 0) keeps the loop narrower than Dahl's, whose unloading
    # stiffens to 2 k0; at full slip both tend to Coulomb's 4 F_s / (pi A)
    for amp in (5e-6, 13e-6, 38e-6):
        _, loss_smooth = joint_describing_function(2e6, 20.0, amp, shape=0.0)
        _, loss_dahl = joint_describing_function(2e6, 20.0, amp, shape=1.0)
        assert loss_smooth < 0.95 * loss_dahl
    _, loss_smooth = joint_describing_function(2e6, 20.0, 2e-3, shape=0.0)
    assert loss_smooth == pytest.approx(4 * 20.0 / (math.pi * 2e-3), rel=0.01)


def test_limits_stuck_and_full_slip():
    for shape in (0.0, 1.0):
        k_eq, k_loss = joint_describing_function(2e6, 20.0, 1e-9, shape=shape)
        assert k_eq == pytest.approx(2e6, rel=1e-3) and k_loss < 1e-3 * k_eq
        # far beyond the pre-sliding distance the loss is Coulomb's, 4 F_s / (pi A)
        k_eq, k_loss = joint_describing_function(2e6, 20.0, 1e-3, shape=shape)
        assert k_loss == pytest.approx(4 * 20.0 / (math.pi * 1e-3), rel=0.02)
        assert k_eq < 0.15 * k_loss


def test_table_per_amplitude_level():
    levels = amplitude_levels([13.1e-6, 12.9e-6, 25e-6, 24.6e-6, 38.2e-6, 37.9e-6, 13e-6])
    assert levels == pytest.approx([13e-6, 24.8e-6, 38.05e-6])
    for shape in (0.0, 1.0):
        rows = joint_table(2e6, 20.0, levels, 40.0, shape)
        assert [r["amplitude_m"] for r in rows] == levels
        # softening with the level, loss per cycle rising
        ks = [r["stiffness_N_per_m"] for r in rows]
        es = [r["energy_per_cycle_J"] for r in rows]
        assert ks[0] > ks[1] > ks[2] and es[0] < es[1] < es[2]
        c = rows[0]["damping_Ns_per_m_at_hz"]["damping_Ns_per_m"]
        assert c == pytest.approx(rows[0]["loss_stiffness_N_per_m"] / (2 * math.pi * 40.0))
        assert rows[0]["stiffness_N_per_m"] == pytest.approx(
            joint_describing_function(2e6, 20.0, levels[0], shape)[0])


def test_a_row_in_words_has_its_numbers_with_units():
    (row,) = joint_table(2e6, 20.0, [13e-6], 40.0, 0.0)
    text = describing_function_text(row)
    k_eq, k_loss = joint_describing_function(2e6, 20.0, 13e-6, 0.0)
    assert text.startswith("at 13 um: stiffness ")
    assert f"{k_eq / 1e3:.4g} kN/m" in text and f"{k_loss / 1e3:.4g} kN/m" in text
    assert f"{k_loss / (2 * math.pi * 40.0):.4g} N.s/m at 40 Hz" in text
