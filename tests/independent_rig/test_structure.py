"""The multi-mode chain with a softening joint against its closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.independent_rig import Sensors
from tests.independent_rig.structure import ChainStructure, IwanJoint

#: whole periods in 0.6 s at 2 kS/s fit a whole number of samples at these frequencies
FREQS = [8.0, 12.0, 14.0, 15.0, 16.0, 18.0, 20.0, 30.0, 36.0, 40.0, 60.0, 70.0]
QUIET = Sensors(noise={})


def _receptances(rec, freqs) -> np.ndarray:
    """Driving-point 1X x / F per dwell (over the whole periods of each dwell)."""
    n = len(rec.columns["x_m"]) // len(freqs)
    out = []
    for i, f in enumerate(freqs):
        sl = slice(i * n, (i + 1) * n)
        t = rec.columns["time_s"][sl]
        k = int(math.floor(0.6 * f))
        m = int(round(k * rec.fs_hz / f))
        e = np.exp(-2j * math.pi * f * t[:m])
        out.append(np.sum(rec.columns["x_m"][sl][:m] * e) / np.sum(rec.columns["fx_N"][sl][:m] * e))
    return np.array(out)


def test_linear_chain_matches_its_receptance():
    chain = ChainStructure(joint=None)
    got = _receptances(chain.run(FREQS, 5.0, QUIET), FREQS)
    want = np.array([chain.receptance(f, joint_stuck=False)[0] for f in FREQS])
    assert np.abs(got / want - 1) == pytest.approx(np.zeros(len(FREQS)), abs=2e-3)
    # three modes, the Rayleigh damping giving the first two 2 %
    fn = chain.natural_hz(joint_stuck=False)
    assert fn.size == 3 and 10 < fn[0] < fn[1] < fn[2] < 80


def test_joint_stuck_at_low_level_slipped_at_high_level():
    """All stuck (forces below the smallest slip force): the chain with k_j in its first spring;
    far above F_s, the joint only adds a bounded friction force: near the chain without it."""
    chain = ChainStructure(joint=IwanJoint(150e3, 30.0))
    low = _receptances(chain.run(FREQS, 0.05, QUIET), FREQS)
    stuck = np.array([chain.receptance(f, joint_stuck=True)[0] for f in FREQS])
    assert np.abs(low / stuck - 1) == pytest.approx(np.zeros(len(FREQS)), abs=5e-3)
    high = _receptances(chain.run(FREQS, 3000.0, QUIET), FREQS)  # joint force <= 1 % of it
    slipped = np.array([chain.receptance(f, joint_stuck=False)[0] for f in FREQS])
    away = [i for i, f in enumerate(FREQS) if f >= 20.0]  # F_s/F small away from the peak
    assert np.abs(high[away] / slipped[away] - 1) == pytest.approx(np.zeros(len(away)),
                                                                   abs=0.03)


def _one_mode(freqs, h) -> tuple[float, float]:
    """Natural frequency [Hz] and damping ratio of 1/H = K - w^2 M + i w C (least squares)."""
    w = 2 * math.pi * np.asarray(freqs)
    d = 1.0 / h
    a = np.column_stack([np.ones_like(w), -(w**2)])
    (k, m), *_ = np.linalg.lstsq(a, d.real, rcond=None)
    c = float(np.mean(d.imag / w))
    return math.sqrt(k / m) / (2 * math.pi), c / (2 * math.sqrt(k * m))


def test_main_mode_softens_and_damps_more_with_level():
    chain = ChainStructure(joint=IwanJoint(150e3, 30.0))
    fine = [14.0, 15.0, 16.0, 18.0]
    modes = [_one_mode(fine, _receptances(chain.run(fine, level, QUIET), fine))
             for level in (0.05, 1.0, 4.0, 16.0)]
    fn = [f for f, _ in modes]
    zeta = [z for _, z in modes]
    stuck, slipped = chain.natural_hz(True)[0], chain.natural_hz(False)[0]
    assert slipped < 0.9 * stuck
    assert fn[0] == pytest.approx(stuck, rel=0.01)  # all stuck
    assert fn[0] > fn[1] > fn[2] > fn[3] > slipped  # softening with the level
    assert zeta[3] > 1.5 * zeta[0] and zeta[0] == pytest.approx(0.02, rel=0.15)
