"""A multi-mode structure with a softening joint, for tests (shares no code with ``simulated_hw``
or ``analysis``).

A chain of masses on springs, ground - m_1 - m_2 - ... - m_n, driven and measured at m_1 (the
driving point: one force, one probe, one accelerometer), with Rayleigh damping
(``C = a M + b K``, a and b set so the first two modes, the joint stuck, have
``damping_ratio``). Beside the spring between the ground and m_1 sits a joint with friction at
its interface, a parallel-series Iwan element: ``elements`` Jenkins elements (a spring
``k_j / elements`` in series with a Coulomb slider), their slip forces spread evenly
(``2 F_s (i + 1/2) / elements^2``, summing to the joint's slip force F_s). Small motion: all
stuck, the joint adds ``k_j``; as the force level rises more elements slip, so the main mode
softens and damps more (micro-slip), the classic bolted-joint behaviour.

Integration: exact one-step maps of the linear chain (matrix exponential, ``substeps`` steps
per sample), one per number of stuck Jenkins elements: over each step the stuck ones are
springs in the chain and the slipping ones (at their slip force, moving further) a constant
force, the drive taken at mid-step; after each step a slider moves where its spring would
exceed its slip force (rate independent). Every dwell starts from the linear
steady state with the joint stuck and settles for ``settle_s`` before it is recorded; the dwells
of one run are integrated together (vectorised over the dwells), each an independent test.

Usage::

    chain = ChainStructure()                          # three modes, the joint on the first spring
    rec = chain.run([10, 14, 18, 22, 30, 45, 60, 80], force_n=20.0, sensors=Sensors(seed=1))
    rec.to_csv(tmp_path / "level20.csv")              # canonical columns, y axis not driven
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.linalg import expm

from tests.independent_rig.sensors import COLUMNS, Sensors


@dataclass
class IwanJoint:
    """Parallel-series Iwan element: total stuck stiffness [N/m], total slip force [N] (the
    joint's force when every element slips)."""

    stiffness_n_per_m: float = 150e3
    slip_force_n: float = 30.0
    elements: int = 20

    def slip_forces(self) -> np.ndarray:
        """Each element's slip force, evenly spread, summing to ``slip_force_n``."""
        n = self.elements
        return self.slip_force_n * 2 * (np.arange(n) + 0.5) / n**2


@dataclass
class ChainRecord:
    """Canonical columns of one run and what made them."""

    columns: dict[str, np.ndarray]
    fs_hz: float
    freqs_hz: list[float]
    force_n: float

    def to_csv(self, path: str | Path) -> Path:
        path = Path(path)
        table = np.column_stack([self.columns[c] for c in COLUMNS])
        with open(path, "w", newline="") as fh:
            fh.write(",".join(COLUMNS) + "\n")
            np.savetxt(fh, table, delimiter=",", fmt="%.9g")
        return path


@dataclass
class ChainStructure:
    """The chain (see module doc); default modes 16.6, 37 and 69 Hz with the joint stuck (14.1,
    36 and 69 Hz without it)."""

    masses_kg: Sequence[float] = (20.0, 8.0, 5.0)
    springs_n_per_m: Sequence[float] = (300e3, 400e3, 500e3)  # ground-m1, m1-m2, m2-m3
    damping_ratio: float = 0.02
    joint: IwanJoint | None = field(default_factory=IwanJoint)
    fs_hz: float = 2000.0
    substeps: int = 4
    settle_s: float = 2.5
    record_s: float = 0.6

    # --- linear parts ---------------------------------------------------------------------
    def _stiffness(self, joint_stuck: bool) -> np.ndarray:
        n = len(self.masses_kg)
        k = np.zeros((n, n))
        springs = list(self.springs_n_per_m)
        if joint_stuck and self.joint is not None:
            springs[0] += self.joint.stiffness_n_per_m
        k[0, 0] += springs[0]
        for i in range(1, n):
            s = springs[i]
            k[i - 1, i - 1] += s
            k[i, i] += s
            k[i - 1, i] -= s
            k[i, i - 1] -= s
        return k

    def matrices(self, joint_stuck: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mass, damping, stiffness (joint stuck: its stiffness in the first spring; else not).
        The damping is one matrix: Rayleigh on the chain with the joint stuck."""
        m = np.diag(np.asarray(self.masses_kg, dtype=float))
        k_stuck = self._stiffness(True)
        w = np.sqrt(np.sort(np.linalg.eigvals(np.linalg.solve(m, k_stuck)).real))
        z = self.damping_ratio
        # Rayleigh: zeta_i = a / (2 w_i) + b w_i / 2 equal to z at the first two modes
        b = 2 * z / (w[0] + w[1])
        a = b * w[0] * w[1]
        return m, a * m + b * k_stuck, self._stiffness(joint_stuck)

    def natural_hz(self, joint_stuck: bool = True) -> np.ndarray:
        m, _, k = self.matrices(joint_stuck)
        return np.sqrt(np.sort(np.linalg.eigvals(np.linalg.solve(m, k)).real)) / (2 * math.pi)

    def receptance(self, freq_hz: float, joint_stuck: bool = True) -> np.ndarray:
        """Complex displacement of every mass per unit force at m_1 (linear)."""
        m, c, k = self.matrices(joint_stuck)
        w = 2 * math.pi * freq_hz
        f = np.zeros(len(self.masses_kg))
        f[0] = 1.0
        return np.linalg.solve(k - w * w * m + 1j * w * c, f)

    # --- the run ---------------------------------------------------------------------------
    def _stepper(self, h: float, k_first: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact one-step map of the linear chain with ``k_first`` added to its first spring,
        for an input at m_1 held over the step: (A_d^T, b_d)."""
        m, c, k = self.matrices(joint_stuck=False)
        k = k.copy()
        k[0, 0] += k_first
        n = len(self.masses_kg)
        minv = np.linalg.inv(m)
        a = np.zeros((2 * n + 1, 2 * n + 1))
        a[:n, n:2 * n] = np.eye(n)
        a[n:2 * n, :n] = -minv @ k
        a[n:2 * n, n:2 * n] = -minv @ c
        a[n:2 * n, 2 * n] = minv[:, 0]
        e = expm(a * h)
        return e[:2 * n, :2 * n].T, e[:2 * n, 2 * n]

    def run(self, freqs_hz: Sequence[float], force_n: float,
            sensors: Sensors | None = None) -> ChainRecord:
        """Sine dwells of force amplitude ``force_n`` at m_1, one per frequency, back to back."""
        sensors = sensors or Sensors()
        freqs = np.asarray(freqs_hz, dtype=float)
        nd, n = freqs.size, len(self.masses_kg)
        m, c, k_lin = self.matrices(joint_stuck=False)
        minv = np.linalg.inv(m)
        h = 1.0 / (self.fs_hz * self.substeps)
        joint = self.joint
        n_el = joint.elements if joint else 0
        kj_el = joint.stiffness_n_per_m / n_el if joint else 0.0
        fsl = joint.slip_forces() if joint else np.zeros(0)
        # one exact step map per number of stuck elements: stuck ones are springs (in the
        # linear part), slipping ones a constant force, over each step
        maps = [self._stepper(h, s * kj_el) for s in range(n_el + 1)]
        ad_all = np.stack([a for a, _ in maps])  # (n_el + 1, 2n, 2n)
        bd_all = np.stack([b for _, b in maps])  # (n_el + 1, 2n)
        n_settle = int(round(self.settle_s * self.fs_hz))
        n_rec = int(round(self.record_s * self.fs_hz))
        w = 2 * math.pi * freqs
        # start: the linear steady state with the joint stuck, at t = 0
        z0 = np.array([self.receptance(f) for f in freqs]) * force_n  # (nd, n) complex
        state = np.hstack([z0.real, (1j * w[:, None] * z0).real])  # (nd, 2n)
        slider = np.zeros((nd, n_el))  # the joint unstretched at rest
        rec_x = np.empty((nd, n_rec))
        rec_a = np.empty((nd, n_rec))
        rec_f = np.empty((nd, n_rec))

        def joint_force(x1: np.ndarray) -> np.ndarray:
            return np.sum(kj_el * (x1[:, None] - slider), axis=1) if n_el else np.zeros(nd)

        step = 0
        for i in range(n_settle + n_rec):
            for _ in range(self.substeps):
                t_mid = (step + 0.5) * h
                if n_el:
                    x1, v1 = state[:, :1], state[:, n:n + 1]
                    stretch = x1 - slider
                    # slipping: at its slip force and moving further that way
                    slipping = (np.abs(kj_el * stretch) >= fsl * (1 - 1e-9)) & (
                        np.sign(v1) == np.sign(stretch))
                    stuck = ~slipping
                    n_stuck = np.sum(stuck, axis=1)
                    u = (kj_el * np.sum(np.where(stuck, slider, 0.0), axis=1)
                         - np.sum(np.where(slipping, np.sign(stretch) * fsl, 0.0), axis=1))
                    ad, bd = ad_all[n_stuck], bd_all[n_stuck]
                else:
                    u = np.zeros(nd)
                    ad, bd = ad_all[np.zeros(nd, dtype=int)], bd_all[np.zeros(nd, dtype=int)]
                drive = force_n * np.cos(w * t_mid) + u
                state = np.einsum("dj,djk->dk", state, ad) + drive[:, None] * bd
                step += 1
                if n_el:
                    # a slider moves where its spring would exceed its slip force
                    x1 = state[:, :1]
                    stretch = x1 - slider
                    over = np.abs(kj_el * stretch) > fsl
                    slider = np.where(over, x1 - np.sign(stretch) * fsl / kj_el, slider)
            if i >= n_settle:
                j = i - n_settle
                t = step * h
                f_now = force_n * np.cos(w * t)
                x, v = state[:, :n], state[:, n:]
                acc = (-(x @ k_lin.T) - v @ c.T) @ minv.T
                acc += np.outer(f_now - joint_force(x[:, 0]), minv[:, 0])
                rec_x[:, j] = x[:, 0]
                rec_a[:, j] = acc[:, 0]
                rec_f[:, j] = f_now
        return self._columns(freqs, rec_x, rec_a, rec_f, force_n, sensors)

    def _columns(self, freqs: np.ndarray, rec_x: np.ndarray, rec_a: np.ndarray,
                 rec_f: np.ndarray, force_n: float, sensors: Sensors) -> ChainRecord:
        nd, n_rec = rec_x.shape
        total = nd * n_rec
        t = np.arange(total) / self.fs_hz
        clean = {"fx_N": rec_f.ravel(), "fy_N": np.zeros(total), "x_m": rec_x.ravel(),
                 "y_m": np.zeros(total), "ax_mps2": rec_a.ravel(), "ay_mps2": np.zeros(total),
                 "oil_temp_C": np.full(total, 24.0)}
        rng = np.random.default_rng(sensors.seed)
        cols: dict[str, np.ndarray] = {"time_s": t, "freq_hz": np.repeat(freqs, n_rec)}
        for name, arr in clean.items():
            cols[name] = sensors.record(name, t, lambda tt, _a=arr: _a, rng)
        return ChainRecord(cols, self.fs_hz, list(freqs), force_n)
