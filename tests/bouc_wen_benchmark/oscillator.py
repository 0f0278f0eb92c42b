"""The nonlinear-benchmark Bouc-Wen oscillator, written from its publication, not from sfdrig.

J.P. Noel and M. Schoukens, "Hysteretic benchmark with a dynamic nonlinearity" (Workshop on
Nonlinear System Identification Benchmarks, 2016): one mass on a linear spring and damper and a
Bouc-Wen hysteretic force z,

    m y'' + c y' + k y + z = u(t),
    z' = alpha y' - beta (gamma |y'| |z|^(nu - 1) z + delta y' |z|^nu),

with m = 2 kg, c = 10 N.s/m, k = 5e4 N/m, alpha = 5e4 N/m, beta = 1e3 m^-1, gamma = 0.8,
delta = -1.1, nu = 1. With these the loop hardens with amplitude (beta (gamma + delta) < 0: no
saturation) and its damping rises: outside the joint family of `analysis.diagnose` (a
saturating Bouc-Wen), so the honest answer is "unexplained", with the hardening named.

Measured as an operator would: stepped sine (the benchmark's own data are multisines and a
swept sine), 5 frequencies around the 35.6 Hz linear resonance at 3 force levels, each dwell
1 s recorded at 5 kHz after 2 s of settling from the previous dwell's end (continuous motion),
force, displacement and acceleration with white noise at a stated fraction of each channel's
RMS. Integrated by scipy's DOP853 (an 8th-order Runge-Kutta; sfdrig's kernel is a leapfrog).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

M_KG, C_NS_PER_M, K_N_PER_M = 2.0, 10.0, 5e4
ALPHA_N_PER_M, BETA_PER_M, GAMMA, DELTA = 5e4, 1e3, 0.8, -1.1
FS_HZ = 5000.0
FREQS_HZ = (20.0, 27.5, 35.0, 42.5, 50.0)
FORCES_N = (2.0, 8.0, 32.0)
SETTLE_S, DWELL_S = 2.0, 1.0
#: the noise's standard deviation as a fraction of each channel's RMS over the run
NOISE_FRACTION = 1e-3


def _rhs(t: float, s: np.ndarray, force_n: float, w: float) -> list[float]:
    y, v, z = s
    u = force_n * math.sin(w * t)
    dz = ALPHA_N_PER_M * v - BETA_PER_M * (GAMMA * abs(v) * z + DELTA * v * abs(z))
    return [v, (u - C_NS_PER_M * v - K_N_PER_M * y - z) / M_KG, dz]


@dataclass
class Dwell:
    force_n: float
    freq_hz: float
    u: np.ndarray  # force [N]
    y: np.ndarray  # displacement [m]
    a: np.ndarray  # acceleration [m/s^2]

    def fundamental(self, x: np.ndarray) -> complex:
        t = np.arange(x.size) / FS_HZ
        return complex(2 * np.mean(x * np.exp(-2j * math.pi * self.freq_hz * t)))

    def dynamic_stiffness(self) -> complex:
        """U / Y of the fundamentals [N/m], noiseless."""
        return self.fundamental(self.u) / self.fundamental(self.y)


def dwells() -> list[Dwell]:
    """The stepped sine, noiseless, in its measured order (levels ascending)."""
    state = np.zeros(3)
    n = int(DWELL_S * FS_HZ)
    out = []
    for force in FORCES_N:
        for f in FREQS_HZ:
            w = 2 * math.pi * f
            t_rec = SETTLE_S + np.arange(n) / FS_HZ
            sol = solve_ivp(_rhs, (0.0, SETTLE_S + DWELL_S), state, args=(force, w),
                            method="DOP853", t_eval=t_rec, rtol=1e-9,
                            atol=[1e-12, 1e-9, 1e-6], max_step=1 / (20 * f))
            if not sol.success:
                raise RuntimeError(f"DOP853 failed at {force} N, {f} Hz: {sol.message}")
            y, v, z = sol.y
            u = force * np.sin(w * t_rec)
            acc = (u - C_NS_PER_M * v - K_N_PER_M * y - z) / M_KG
            out.append(Dwell(force, f, u, y, acc))
            # the next dwell starts where this one ended (its time origin moves: the force's
            # phase jumps at the step, as a stepped-sine controller's may)
            state = sol.y[:, -1].copy()
    return out


def write_csv(recorded: list[Dwell], path: Path, seed: int) -> Path:
    """The run as an operator's CSV (time, frequency, force, displacement, acceleration)."""
    rng = np.random.default_rng(seed)
    cols = {"freq_hz": np.concatenate([np.full(d.u.size, d.freq_hz) for d in recorded]),
            "fx_N": np.concatenate([d.u for d in recorded]),
            "x_m": np.concatenate([d.y for d in recorded]),
            "ax_mps2": np.concatenate([d.a for d in recorded])}
    for name in ("fx_N", "x_m", "ax_mps2"):
        rms = float(np.sqrt(np.mean(cols[name] ** 2)))
        cols[name] = cols[name] + rng.normal(0.0, NOISE_FRACTION * rms, cols[name].size)
    cols["time_s"] = np.arange(cols["x_m"].size) / FS_HZ
    names = ("time_s", "freq_hz", "fx_N", "x_m", "ax_mps2")
    np.savetxt(path, np.column_stack([cols[c] for c in names]), delimiter=",",
               header=",".join(names), comments="", fmt="%.9g")
    return path


def level_fit(recorded: list[Dwell], force_n: float) -> tuple[float, float]:
    """(natural frequency [Hz], damping ratio) of a linear k - m w^2 + i w c least-squares fit to
    one force level's noiseless dynamic stiffness: the level's equivalent linear oscillator."""
    rows, rhs = [], []
    for d in recorded:
        if d.force_n != force_n:
            continue
        w, z = 2 * math.pi * d.freq_hz, d.dynamic_stiffness()
        rows += [[1.0, -w * w, 0.0], [0.0, 0.0, w]]
        rhs += [z.real, z.imag]
    k, m, c = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0]
    return math.sqrt(k / m) / (2 * math.pi), c / (2 * math.sqrt(k * m))
