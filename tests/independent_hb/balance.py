"""Multi-harmonic balance with alternating frequency/time (AFT) evaluation of nonlinear forces.

A periodic motion of period 2 pi / omega is held as complex harmonics ``Q[d, n]`` (dof d,
harmonic n = 0..H): ``q_d(t) = Re(sum_n Q[d, n] exp(i n omega t))`` (Q[d, 0] real). Per harmonic
the linear part is a dynamic stiffness matrix ``S(n omega) = K - (n omega)^2 M + i n omega C``;
the nonlinear forces are evaluated on ``n_time`` points of one period from the motion (inverse
FFT), transformed back (FFT) and truncated to H harmonics. The balance is solved by Newton's
method with a finite-difference Jacobian evaluated in one batched call (every perturbed unknown
vector at once, so a hysteretic law integrated over the period costs one loop over time, not
one per column).

Displacement control: the fundamental of one dof (the controlled axis) is prescribed and the
shaker force's fundamental on it is an unknown in its place; every other harmonic of every dof
is free and forced only by the nonlinear terms (the shaker is a pure sine).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: ``forces(z, v) -> f``: nonlinear forces on the dofs from displacements and velocities
#: (each ``(batch, n_dof, n_time)`` over one period, uniformly sampled from phase 0), same shape.
NonlinearForces = Callable[[np.ndarray, np.ndarray], np.ndarray]


def to_time(q: np.ndarray, n_time: int) -> np.ndarray:
    """Samples over one period (``(..., n_time)``) of harmonics ``q`` (``(..., H + 1)``)."""
    spec = np.zeros(q.shape[:-1] + (n_time // 2 + 1,), dtype=np.complex128)
    h = q.shape[-1]
    spec[..., 0] = q[..., 0].real * n_time
    spec[..., 1:h] = q[..., 1:] * (n_time / 2.0)
    return np.fft.irfft(spec, n=n_time, axis=-1)


def to_harmonics(x: np.ndarray, n_harmonics: int) -> np.ndarray:
    """Harmonics 0..H (``(..., H + 1)``) of samples ``x`` over one period (``(..., n_time)``)."""
    n_time = x.shape[-1]
    spec = np.fft.rfft(x, axis=-1)[..., : n_harmonics + 1]
    out = spec * (2.0 / n_time)
    out[..., 0] = spec[..., 0].real / n_time
    return out


@dataclass(frozen=True)
class Balance:
    """The harmonic balance of one dwell.

    ``mass``, ``damping``, ``stiffness``: ``(n_dof, n_dof)`` linear matrices; ``forces``: the
    nonlinear forces (None: linear); ``omega``: rad/s; ``controlled``: the dof whose fundamental
    is prescribed (``amplitude``, real: the phase reference) with the shaker force on it unknown.
    """

    mass: np.ndarray
    damping: np.ndarray
    stiffness: np.ndarray
    omega: float
    amplitude: float
    controlled: int = 0
    forces: NonlinearForces | None = None
    n_harmonics: int = 21
    n_time: int = 512

    @property
    def n_dof(self) -> int:
        return int(self.mass.shape[0])

    def dynamic_stiffness(self, n: int) -> np.ndarray:
        w = n * self.omega
        return self.stiffness - w * w * self.mass + 1j * w * self.damping

    # -- unknowns <-> (harmonics, force) --------------------------------------------------------
    # Per dof the real unknowns are [Re Q0, Re Q1, Im Q1, ..., Re QH, Im QH]; on the controlled
    # dof, Re Q1 / Im Q1 are replaced by the shaker force's fundamental (Re F1, Im F1).

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(Q (batch, n_dof, H + 1), F1 (batch,))`` from unknowns ``x`` (``(batch, n)``)."""
        h = self.n_harmonics
        x = x.reshape(x.shape[0], self.n_dof, 2 * h + 1)
        q = np.zeros((x.shape[0], self.n_dof, h + 1), dtype=np.complex128)
        q[:, :, 0] = x[:, :, 0]
        q[:, :, 1:] = x[:, :, 1::2] + 1j * x[:, :, 2::2]
        c = self.controlled
        force = q[:, c, 1].copy()
        q[:, c, 1] = self.amplitude
        return q, force

    def pack(self, q: np.ndarray, force: complex) -> np.ndarray:
        """Unknowns from harmonics ``q`` (``(n_dof, H + 1)``) and the shaker force ``force``."""
        q = np.array(q, dtype=np.complex128)
        q[self.controlled, 1] = force
        x = np.zeros((self.n_dof, 2 * self.n_harmonics + 1))
        x[:, 0] = q[:, 0].real
        x[:, 1::2] = q[:, 1:].real
        x[:, 2::2] = q[:, 1:].imag
        return x.ravel()

    def nonlinear_harmonics(self, q: np.ndarray) -> np.ndarray:
        """AFT: the nonlinear forces' harmonics (``(batch, n_dof, H + 1)``) of motions ``q``."""
        if self.forces is None:
            return np.zeros_like(q)
        n = np.arange(self.n_harmonics + 1)
        z = to_time(q, self.n_time)
        v = to_time(1j * n * self.omega * q, self.n_time)
        return to_harmonics(self.forces(z, v), self.n_harmonics)

    def residual(self, x: np.ndarray) -> np.ndarray:
        """Force imbalance per dof and harmonic (real, ``(batch, n)``) of unknowns ``x``."""
        q, force = self.unpack(np.atleast_2d(x))
        r = self.nonlinear_harmonics(q)
        for n in range(self.n_harmonics + 1):
            r[:, :, n] += q[:, :, n] @ self.dynamic_stiffness(n).T
        r[:, self.controlled, 1] -= force
        out = np.zeros((x.shape[0] if x.ndim == 2 else 1, self.n_dof, 2 * self.n_harmonics + 1))
        out[:, :, 0] = r[:, :, 0].real
        out[:, :, 1::2] = r[:, :, 1:].real
        out[:, :, 2::2] = r[:, :, 1:].imag
        return out.reshape(out.shape[0], -1)

    def linear_start(self) -> np.ndarray:
        """Unknowns of the linear system's steady state (the Newton start)."""
        s = self.dynamic_stiffness(1)
        c = self.controlled
        free = [d for d in range(self.n_dof) if d != c]
        q = np.zeros((self.n_dof, self.n_harmonics + 1), dtype=np.complex128)
        q[c, 1] = self.amplitude
        if free:  # the free dofs answer the controlled one's motion
            q[free, 1] = np.linalg.solve(s[np.ix_(free, free)], -s[free, c] * self.amplitude)
        force = complex(s[c] @ q[:, 1])
        return self.pack(q, force)


@dataclass(frozen=True)
class Solution:
    """A converged balance: the harmonics, the shaker force and how well it balances."""

    harmonics: np.ndarray  # (n_dof, H + 1) complex
    force: complex  # the shaker force's fundamental on the controlled dof [N]
    residual_norm: float  # max |imbalance| over dofs and harmonics [N]
    iterations: int


class NotConverged(RuntimeError):
    """The Newton iteration did not balance the harmonics."""


def solve(balance: Balance, tol_n: float = 1e-9, max_iter: int = 50,
          start: np.ndarray | None = None) -> Solution:
    """Newton's method on the balance from ``start`` (default: the linear steady state).

    ``tol_n``: the largest force imbalance [N] accepted on any dof and harmonic. Steps are halved
    while they do not reduce the imbalance (a non-smooth law far from the start)."""
    x = balance.linear_start() if start is None else np.array(start, dtype=np.float64)
    r = balance.residual(x)[0]
    typical = np.full((balance.n_dof, 2 * balance.n_harmonics + 1), balance.amplitude)
    typical[balance.controlled, 1:3] = 1.0  # the force's unknowns [N]
    for it in range(1, max_iter + 1):
        if np.max(np.abs(r)) <= tol_n:
            return _solution(balance, x, r, it - 1)
        step = 1e-6 * (np.abs(x) + typical.ravel())
        perturbed = x[None, :] + np.diag(step)
        jac = ((balance.residual(perturbed) - r[None, :]) / step[:, None]).T
        dx = np.linalg.lstsq(jac, -r, rcond=None)[0]
        lam, norm0 = 1.0, float(np.linalg.norm(r))
        while lam > 1e-4:
            trial = x + lam * dx
            r_trial = balance.residual(trial)[0]
            if np.linalg.norm(r_trial) < norm0:
                break
            lam /= 2.0
        x, r = trial, r_trial
    if np.max(np.abs(r)) <= tol_n:
        return _solution(balance, x, r, max_iter)
    raise NotConverged(f"harmonic balance at {balance.omega / (2 * np.pi):.3f} Hz, amplitude "
                       f"{balance.amplitude:.3g}: imbalance {np.max(np.abs(r)):.3g} N after "
                       f"{max_iter} iterations (tolerance {tol_n:.3g} N)")


def _solution(balance: Balance, x: np.ndarray, r: np.ndarray, iterations: int) -> Solution:
    q, force = balance.unpack(x[None, :])
    return Solution(q[0], complex(force[0]), float(np.max(np.abs(r))), iterations)
