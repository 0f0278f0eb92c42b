"""How long the replay of a steady-state dwell runs before the dwell: long enough for the
model replayed to forget its start from rest, no longer.

A dwell replayed in steady state (``Evaluator``) is preceded by its own force's whole periods;
from rest, the replay's error is a free response of the model that decays with the model's
slowest decay time. The lead spans ``LEAD_DECAYS`` of those (the start's error left at e^-20,
2e-9 of its size: below any record's noise even where a coupled mode decays twice as slowly as
the bound below says), and at least ``LEAD_PERIODS`` periods of the dwell, and never more than
the fixed warm-up it replaces (``Evaluator.warmup_s``, at least 0.5 s: on well-damped rigs 40
to 80 of their decay times, and as long again as the dwell it preceded, since it was rounded up
to the dwell's longest whole-period chunk).

The slowest decay is bounded from the kernel's parameter vector (`slowest_decay_s`): per axis
the housing's mode with the film's mass and damping at the window's viscosity, the cross
terms' mass added and their damping taken off, the spring at half its value (a softening
term, the rods' coupling) so an overdamped mode's slow pole is not overestimated; a relaxing
stiffness's time constant. Where no such bound holds (a micro-slipping joint, whose hysteresis
loop centres over many cycles at small slip; air in the film, whose damping falls with its
mean speed; the frame mode, whose coupling to the housing makes a mode that decays slower
than either alone: bounded by the two uncoupled, the harmonic-balance frame case at held-out
seed 5101 lost its two-mode order), the lead is the fixed warm-up, as before.
"""

from __future__ import annotations

import math

import numpy as np

from rig_model import physics as ph

#: decay times of the slowest mode a steady-state lead spans
LEAD_DECAYS = 20.0
#: periods of the dwell a lead spans at least (a seal's slider settles within its first slips)
LEAD_PERIODS = 3.0


def slowest_decay_s(kp: np.ndarray, fill: float, viscosity_scale: float) -> float:
    """An upper bound on the slowest decay time [s] of the kernel with parameters ``kp`` at
    film fill ``fill`` and viscosity scale ``viscosity_scale`` (module doc); inf where none is
    known."""
    if kp[ph.P_JOINT_ON] or kp[ph.P_AIR_K] > 0.0 or kp[ph.P_FRAME_ON]:
        return math.inf
    film_m = fill * (kp[ph.P_MF] + kp[ph.P_D])
    film_c = fill * kp[ph.P_C0] * viscosity_scale
    cross_m = abs(kp[ph.P_DXY]) + abs(kp[ph.P_DYX])
    cross_c = 0.5 * (abs(kp[ph.P_CXY]) + abs(kp[ph.P_CYX]))
    kx, ky, kxy = kp[ph.P_KX], kp[ph.P_KY], kp[ph.P_KXY]
    # the rods' softest direction: the least eigenvalue of [[K_x, k_xy], [k_xy, K_y]]
    k_soft = 0.5 * (kx + ky) - math.hypot(0.5 * (kx - ky), kxy)
    taus = []
    for m_s, c_s in ((kp[ph.P_M], kp[ph.P_CRV]),
                     (kp[ph.P_M] + kp[ph.P_DM_Y], kp[ph.P_CRV] + kp[ph.P_DC_Y])):
        taus.append(_decay_s(m_s + film_m + cross_m, c_s + film_c - cross_c, 0.5 * k_soft))
    if kp[ph.P_RELAX_KX] > 0.0 or kp[ph.P_RELAX_KY] > 0.0:
        taus.append(float(kp[ph.P_RELAX_TAU]))
    return max(taus)


def _decay_s(m: float, c: float, k: float) -> float:
    """The decay time of m z'' + c z' + k z = 0's slower pole [s] (inf: not damped)."""
    if m <= 0.0 or c <= 0.0 or k <= 0.0:
        return math.inf
    disc = c * c - 4.0 * m * k
    rate = c / (2.0 * m) if disc <= 0.0 else (c - math.sqrt(disc)) / (2.0 * m)
    return 1.0 / rate if rate > 0.0 else math.inf


def steady_lead(kp: np.ndarray, fill: float, viscosity_scale: float, fs: float,
                period_samples: float, longest: int) -> int:
    """Samples of lead before a steady-state dwell of period ``period_samples`` (module doc):
    at most ``longest`` (the fixed warm-up's), rounded up to a power of two so a window's
    forces are made for a few leads only."""
    tau = slowest_decay_s(kp, fill, viscosity_scale)
    if not math.isfinite(tau):
        return longest
    need = max(LEAD_DECAYS * tau * fs, LEAD_PERIODS * period_samples, 1.0)
    return min(longest, 1 << math.ceil(math.log2(need)))
