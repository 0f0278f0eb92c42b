"""The joint's describing function (``analysis.diagnose.hysteresis``) against the Dahl law
stepped in time: its equivalent and loss stiffness per amplitude, as a finding reports them
(issue 24, deliverable 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose.hysteresis import amplitude_levels, dahl_describing_function, joint_table


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


@pytest.mark.parametrize(("k_j", "f_s", "amp"), [
    (2e6, 20.0, 13e-6),   # a seal stiffer than the rods, ~10 um of pre-sliding
    (2e6, 20.0, 38e-6),
    (3e5, 8.0, 25e-6),    # a rods' clamp
])
def test_describing_function_matches_the_law_stepped_in_time(k_j, f_s, amp):
    k_eq, k_loss = dahl_describing_function(k_j, f_s, amp)
    want_eq, want_loss = _stepped(k_j, f_s, amp)
    assert k_eq == pytest.approx(want_eq, rel=2e-3)
    assert k_loss == pytest.approx(want_loss, rel=2e-3)


def test_limits_stuck_and_full_slip():
    k_eq, k_loss = dahl_describing_function(2e6, 20.0, 1e-9)
    assert k_eq == pytest.approx(2e6, rel=1e-3) and k_loss < 1e-3 * k_eq
    # far beyond the pre-sliding distance the loss is Coulomb's, 4 F_s / (pi A)
    k_eq, k_loss = dahl_describing_function(2e6, 20.0, 1e-3)
    assert k_loss == pytest.approx(4 * 20.0 / (math.pi * 1e-3), rel=0.02)
    assert k_eq < 0.15 * k_loss


def test_table_per_amplitude_level():
    levels = amplitude_levels([13.1e-6, 12.9e-6, 25e-6, 24.6e-6, 38.2e-6, 37.9e-6, 13e-6])
    assert levels == pytest.approx([13e-6, 24.8e-6, 38.05e-6])
    rows = joint_table(2e6, 20.0, levels, 40.0)
    assert [r["amplitude_m"] for r in rows] == levels
    # softening with the level, loss per cycle rising
    ks = [r["stiffness_N_per_m"] for r in rows]
    es = [r["energy_per_cycle_J"] for r in rows]
    assert ks[0] > ks[1] > ks[2] and es[0] < es[1] < es[2]
    c = rows[0]["damping_Ns_per_m_at_hz"]["damping_Ns_per_m"]
    assert c == pytest.approx(rows[0]["loss_stiffness_N_per_m"] / (2 * math.pi * 40.0))
