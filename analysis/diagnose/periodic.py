"""A linear model's steady state over a dwell of whole periods, exactly and without a lead.

Where the replayed model is linear (no dry friction, no eccentricity law, no cubic or quadratic
spring, no air, no joint, no journal contact: `is_linear`) and its film's fill and viscosity
are constant over the window, the kernel's step over one sample is an affine map of its state s
and the sample's force f (the force ramps from the previous sample's, which the state holds):

    s' = A s + B f,    y = C s + D f    (y: x, y, vx, vy, ax, ay at the sample)

with the kernel's own discretisation (leapfrog, implicit damping, substeps), read from the kernel
by one-sample replays from each unit state and each unit force (`StepMap`). Driven forever by the
N samples of a window of whole periods, its periodic response has the spectrum

    Y_k = (C (z_k I - A)^-1 B + D) F_k,    z_k = exp(2 pi i k / N)

(`StepMap.periodic`): what a replay after an infinitely long lead of the same periods gives, to
rounding, for the cost of a few FFTs instead of a replay of the lead and the window. A lead
replayed from rest leaves the start's error at exp(-lead / tau) of its size: 2e-9 after the 20
decay times of ``lead.py``, but 0.25 % where a lightly damped frame mode (2 % at 47 Hz, tau
0.17 s) decays over a 1 s lead, which no lead a replay can afford removes (20 tau: 3.4 s
before every 1 s dwell).

Evaluated in the eigenbasis of A; where that basis is ill-conditioned (a nearly critically
damped mode: repeated eigenvalues), or a mode does not decay, `step_map` gives None and the
replay keeps its lead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rig_model import physics as ph

#: the kernel's parameters that make its step nonlinear in the state where they are not 0
_NONLINEAR = (ph.P_FMU, ph.P_ECC, ph.P_K3, ph.P_K2, ph.P_AIR_K, ph.P_CONTACT_ON, ph.P_JOINT_ON)
#: the output rows a replay returns (`Evaluator.truth`)
_ROWS = slice(ph.O_X, ph.O_AY + 1)
#: the eigenbasis of A is used up to this condition number (its rounding error times it stays
#: far below any record's noise: 1e-16 * 1e6)
MAX_CONDITION = 1e6


def is_linear(kp: np.ndarray) -> bool:
    """Whether the kernel with parameters ``kp`` steps linearly in its state (module doc)."""
    return all(kp[i] == 0.0 for i in _NONLINEAR)


def _states(kp: np.ndarray) -> list[int]:
    """The kernel's state entries the linear step moves: the housing's, the previous force,
    the frame's where it is on, the relaxing stiffness's where it is on."""
    idx = [ph.S_X, ph.S_Y, ph.S_VX, ph.S_VY, ph.S_FPX, ph.S_FPY]
    if kp[ph.P_FRAME_ON] > 0.5:
        idx += [ph.S_XF, ph.S_YF, ph.S_VXF, ph.S_VYF]
    if kp[ph.P_RELAX_KX] > 0.0 or kp[ph.P_RELAX_KY] > 0.0:
        idx += [ph.S_RX, ph.S_RY]
    return idx


@dataclass
class StepMap:
    """The kernel's one-sample map (module doc) in the eigenbasis of A: eigenvalues ``lam``,
    ``cv`` = C V (6 x n), ``wb`` = V^-1 B (n x 2), ``d`` = D (6 x 2); ``states`` the kernel's
    state entries of s, ``v`` = V."""

    states: list[int]
    lam: np.ndarray
    v: np.ndarray
    cv: np.ndarray
    wb: np.ndarray
    d: np.ndarray
    _h: dict[int, np.ndarray] = field(default_factory=dict)

    def _transfer(self, n: int) -> np.ndarray:
        """(C (z_k I - A)^-1 B + D) at the rfft lines of ``n`` samples, shape (2, 6, K)."""
        hit = self._h.get(n)
        if hit is None:
            z = np.exp(2j * math.pi * np.arange(n // 2 + 1) / n)
            g = 1.0 / (z[:, None] - self.lam[None, :])
            per_mode = np.einsum("oj,ji->joi", self.cv, self.wb).reshape(len(self.lam), -1)
            h = (g @ per_mode).reshape(-1, *self.d.shape) + self.d[None]
            hit = np.ascontiguousarray(h.transpose(2, 1, 0))
            if len(self._h) >= 4:
                self._h.clear()
            self._h[n] = hit
        return hit

    def periodic(self, spectrum: np.ndarray, n: int) -> np.ndarray:
        """The periodic response (6, n) to the force of rfft ``spectrum`` (2, n // 2 + 1)
        repeated forever."""
        y = np.einsum("iok,ik->ok", self._transfer(n), spectrum)
        return np.fft.irfft(y, n=n, axis=1)

    def periodic_state(self, force: np.ndarray) -> np.ndarray:
        """The kernel's whole state (N_STATE,) at the start (and so at the end) of ``force``
        (2, n) repeated forever: s_0 = V (1/n) sum_k (z_k I - Lambda)^-1 V^-1 B F_k."""
        n = force.shape[1]
        z = np.exp(2j * math.pi * np.arange(n) / n)
        u = self.wb @ np.fft.fft(force, axis=1)  # (modes, n)
        q = np.sum(u / (z[None, :] - self.lam[:, None]), axis=1) / n
        s = np.zeros(ph.N_STATE)
        s[self.states] = np.real(self.v @ q)
        return s


def step_map(kp: np.ndarray, fill: float, visc: float) -> StepMap | None:
    """The kernel's one-sample map under ``kp`` at a constant fill and viscosity scale, read
    from the kernel (module doc); None where the model is not linear, a mode does not decay or
    the eigenbasis is ill-conditioned."""
    if not is_linear(kp):
        return None
    states = _states(kp)
    n = len(states)
    a = np.empty((n, n))
    b = np.empty((n, 2))
    c = np.empty((6, n))
    d = np.empty((6, 2))
    fill_1, visc_1 = np.array([fill]), np.array([visc])
    out = np.empty((ph.N_OUT, 1))

    def probe(s: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ph.integrate(f, fill_1, visc_1, kp, s, out)
        return s[states], out[_ROWS, 0]

    zero_f = np.zeros((2, 1))
    for j, entry in enumerate(states):
        s = np.zeros(ph.N_STATE)
        s[entry] = 1.0
        a[:, j], c[:, j] = probe(s, zero_f)
    for i in range(2):
        f = np.zeros((2, 1))
        f[i, 0] = 1.0
        b[:, i], d[:, i] = probe(np.zeros(ph.N_STATE), f)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(c))):
        return None
    lam, v = np.linalg.eig(a)
    if np.max(np.abs(lam)) >= 1.0 or np.linalg.cond(v) > MAX_CONDITION:
        return None
    vinv = np.linalg.inv(v)
    return StepMap(states, lam, v, c @ v, vinv @ b, d)
