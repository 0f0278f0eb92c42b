"""An independent multi-mode generator: a chain of masses and springs per axis, the force on the
first mass (where the probe is), stepped-sine dwells, written as the canonical CSV an operator
imports and imported through ``sfdrig import`` (as the HB generator's runs are).

Written from the textbook, not from diagnose's model: the chain's mass and stiffness matrices,
its modes from ``scipy.linalg.eigh`` (mass-normalised), modal damping (each mode its own ratio:
C = M Phi diag(2 zeta_r w_r) Phi^T M), and each dwell's steady state from the dynamic stiffness
solved at the dwell's frequency, H = [K - w^2 M + i w C]^-1 (no time integration). A mode may
soften and damp more with the force level (``Chain.soft``): the chain's modes are then changed
at that level before C is built. The noise is white, seeded, sized from a stated signal-to-noise
ratio (the RMS of the driven mass' response over the plan against the noise's sd).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.linalg import eigh

FS_HZ = 500.0
DWELL_S = 1.0
#: stepped sine 2-60 Hz on whole hertz, 1 Hz steps below 20 Hz and 3 Hz above; each dwell
#: holds whole periods in whole samples, where the replay finds them (29, 51, 57 and 60 Hz
#: would round to fewer periods than the dwell holds: left out)
FREQS_HZ = tuple(float(f) for f in (*range(2, 20), 20, 23, 26, 32, 35, 38, 41, 44, 47, 50,
                                    53, 56))


@dataclass(frozen=True)
class Chain:
    """Masses [kg] in a line, the first on ``springs[0]`` to ground, each next one on the
    spring between it and the one before; modal damping ratios, lowest mode first."""

    masses: tuple[float, ...]
    springs: tuple[float, ...]
    zetas: tuple[float, ...]
    #: (mode index, frequency ratio, damping ratio) at the highest force level: the mode
    #: softens and damps more linearly in log(level) from the lowest level
    soft: tuple[int, float, float] | None = None

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        n = len(self.masses)
        k = np.zeros((n, n))
        for i, s in enumerate(self.springs):
            k[i, i] += s
            if i > 0:
                k[i - 1, i - 1] += s
                k[i - 1, i] -= s
                k[i, i - 1] -= s
        return np.diag(self.masses), k

    def modes(self, share: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Natural frequencies [rad/s], mass-normalised shapes (columns) and damping ratios
        at a level ``share`` of the way (in log force) from the lowest to the highest."""
        m, k = self.matrices()
        w2, phi = eigh(k, m)
        w = np.sqrt(w2)
        zeta = np.array(self.zetas, dtype=float)
        if self.soft is not None:
            i, ratio, z_hi = self.soft
            w[i] *= 1.0 + share * (ratio - 1.0)
            zeta[i] += share * (z_hi - zeta[i])
        return w, phi, zeta

    def receptance(self, f_hz: float, share: float = 0.0) -> complex:
        """Displacement of the first mass per newton on it at ``f_hz`` [m/N]."""
        w, phi, zeta = self.modes(share)
        m, _ = self.matrices()
        # K and C rebuilt from the (possibly changed) modes: M Phi diag(.) Phi^T M
        mp = m @ phi
        k = mp @ np.diag(w**2) @ mp.T
        c = mp @ np.diag(2 * zeta * w) @ mp.T
        om = 2 * math.pi * f_hz
        dyn = k - om**2 * m + 1j * om * c
        e = np.zeros(len(self.masses))
        e[0] = 1.0
        return complex(np.linalg.solve(dyn, e)[0])

    def natural_hz(self, share: float = 0.0) -> np.ndarray:
        return self.modes(share)[0] / (2 * math.pi)


@dataclass
class Plan:
    """Force levels [N] per axis, the dwell frequencies, the signal-to-noise ratio of the
    response and the force's noise share."""

    levels_n: tuple[float, ...] = (20.0,)
    freqs_hz: tuple[float, ...] = FREQS_HZ
    snr: float = 200.0
    force_noise_share: float = 0.005
    axes: dict[str, Chain] = field(default_factory=dict)


def record_csv(plan: Plan, axis: str, level_n: float, seed: int, path: Path) -> Path:
    """One run: ``axis`` driven at ``level_n`` over the plan's dwells in a seeded shuffled
    order, as a canonical CSV (time, frequency, the axis' force and probe)."""
    chain = plan.axes[axis]
    lo, hi = plan.levels_n[0], plan.levels_n[-1]
    share = math.log(level_n / lo) / math.log(hi / lo) if hi > lo else 0.0
    rng = np.random.default_rng(seed)
    freqs = rng.permutation(np.array(plan.freqs_hz))
    n = int(round(DWELL_S * FS_HZ))
    t_local = np.arange(n) / FS_HZ
    h = {f: chain.receptance(float(f), share) for f in freqs}
    rms = math.sqrt(np.mean([abs(level_n * v) ** 2 / 2 for v in h.values()]))
    z_sd, f_sd = rms / plan.snr, plan.force_noise_share * level_n
    force, resp, fcol, step = [], [], [], []
    for f in freqs:
        e = np.exp(1j * (2 * math.pi * f * t_local + rng.uniform(0, 2 * math.pi)))
        force.append(np.real(level_n * e) + f_sd * rng.standard_normal(n))
        resp.append(np.real(level_n * h[f] * e) + z_sd * rng.standard_normal(n))
        fcol.append(np.full(n, f))
        step.append(np.full(n, float(len(step))))
    # the step column says where each dwell is (the importer would split a dwell whose
    # response is near the noise by cycles)
    cols = {"time_s": np.arange(n * len(freqs)) / FS_HZ, "freq_hz": np.concatenate(fcol),
            "step": np.concatenate(step),
            f"f{axis}_N": np.concatenate(force), f"{axis}_m": np.concatenate(resp)}
    with open(path, "w", newline="") as fh:
        fh.write(",".join(cols) + "\n")
        np.savetxt(fh, np.column_stack(list(cols.values())), delimiter=",", fmt="%.10g")
    return path


def import_runs(plan: Plan, tmp: Path, seed: int) -> list[Path]:
    """Every axis at every level as run files, through ``sfdrig import`` with what an
    operator states (dry, the motion's axis, no seal)."""
    from sfdrig.cli import main

    runs = []
    for a, axis in enumerate(plan.axes):
        for i, level in enumerate(plan.levels_n):
            name = f"{axis}-{level:g}N"
            csv = record_csv(plan, axis, level, seed + 10 * a + i, tmp / f"{name}.csv")
            run = tmp / f"{name}.h5"
            rc = main(["import", str(csv), "--out", str(run), "--dry", "--motion", axis,
                       "--seal", "none", "--overwrite"])
            if rc != 0:
                raise RuntimeError(f"sfdrig import failed on {csv} (exit {rc})")
            runs.append(run)
    return runs
