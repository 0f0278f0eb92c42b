"""Dwell plans recorded on the harmonic-balance rig, written as the canonical CSV an operator
imports (``sfdrig import``).

A plan is lubricated x dwells (5 frequencies 20-60 Hz x 3 displacement amplitudes 13-38 um,
1 s each at 5 kHz) in a seeded shuffled order with the first dwell repeated at the end. The
controller holds the x probe's reading: its fundamental is the dwell's amplitude, so with a
probe gain g the housing moves amplitude / g. Each dwell is the balance's periodic steady state
(the parameters of slow drifts taken at the dwell's middle), its phase 0 at the dwell's start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tests.independent_hb.balance import Solution, solve
from tests.independent_hb.rig import Rig
from tests.independent_hb.sensors import CHANNELS, SensorModel

FREQS_HZ = (20.0, 30.0, 40.0, 50.0, 60.0)
AMPS_M = (13e-6, 25.5e-6, 38e-6)
FS_HZ = 5000.0
DWELL_S = 1.0


@dataclass(frozen=True)
class Dwell:
    freq_hz: float
    amplitude_m: float  # what the x probe reads (the controller's target)


def plan(seed: int) -> list[Dwell]:
    """The grid in a shuffled order (seeded), the first dwell repeated at the end."""
    grid = [Dwell(f, a) for f in FREQS_HZ for a in AMPS_M]
    order = np.random.default_rng(seed).permutation(len(grid))
    dwells = [grid[i] for i in order]
    return [*dwells, dwells[0]]


@dataclass
class DwellRecord:
    """One dwell's truth: the balance solved and where its samples are."""

    dwell: Dwell
    fraction: float  # the dwell's middle, as a fraction of the run
    solution: Solution
    first_sample: int
    n_samples: int

    @property
    def omega(self) -> float:
        return 2 * math.pi * self.dwell.freq_hz

    def true_fundamentals(self) -> dict[str, complex]:
        """The true fundamental of each channel (before the sensors) [channel units]."""
        q, w = self.solution.harmonics, self.omega
        ax = -(w**2) * (q[0, 1] + (q[2, 1] if q.shape[0] > 2 else 0.0))
        return {"fx_N": self.solution.force, "fy_N": 0j, "x_m": q[0, 1], "y_m": q[1, 1],
                "ax_mps2": ax, "ay_mps2": -(w**2) * q[1, 1]}


@dataclass
class Recording:
    """A generated measurement: the canonical columns and each dwell's truth."""

    columns: dict[str, np.ndarray]
    dwells: list[DwellRecord]
    rig: Rig
    sensors: SensorModel

    def to_csv(self, path: Path) -> Path:
        names = ("time_s", "freq_hz", *CHANNELS)
        with open(path, "w", newline="") as fh:
            fh.write(",".join(names) + "\n")
            np.savetxt(fh, np.column_stack([self.columns[c] for c in names]), delimiter=",",
                       fmt="%.9g")
        return path


def sensors_for(rig: Rig, base: SensorModel | None = None) -> SensorModel:
    """The sensor model with the rig's hidden probe faults on the x probe."""
    base = base or SensorModel()
    h = rig.hidden
    gain = {**base.gain, **({"x_m": h.probe_gain_x} if h.probe_gain_x != 1.0 else {})}
    delay = {**base.delay_s, **({"x_m": h.probe_delay_x_s} if h.probe_delay_x_s else {})}
    return SensorModel(noise=base.noise, step=base.step, offset=base.offset,
                       anti_alias_delay_s=base.anti_alias_delay_s, gain=gain, delay_s=delay)


#: balances solved in this process, by (rig, dwells, harmonics): the detectability checks, the
#: threshold friction and the diagnose cases solve the same rig's plan (the rig, its hidden
#: effects and the dwells are frozen, so the key is the whole input; a DwellRecord is read only)
_SOLVED: dict[tuple[Rig, tuple[Dwell, ...], int], tuple[DwellRecord, ...]] = {}


def solve_plan(rig: Rig, dwells: list[Dwell], n_harmonics: int = 21) -> list[DwellRecord]:
    """Each dwell's balance, the controller holding the x probe's reading. 21 harmonics: a
    seal that sticks at low speed (15 N against 10 N of spring at 13 um) makes the balance
    converge slowly in the harmonics (7 -> 45 moves the force's fundamental by 1.5 %, 21 -> 45
    by < 0.5 %; ``test_generator``). Solved once per process for the same input."""
    key = (rig, tuple(dwells), n_harmonics)
    if key not in _SOLVED:
        _SOLVED[key] = tuple(_solve_plan(rig, dwells, n_harmonics))
    return list(_SOLVED[key])


def _solve_plan(rig: Rig, dwells: list[Dwell], n_harmonics: int) -> list[DwellRecord]:
    n = int(round(DWELL_S * FS_HZ))
    out = []
    for k, d in enumerate(dwells):
        fraction = (k + 0.5) / len(dwells)
        true_amp = d.amplitude_m / rig.hidden.probe_gain_x
        sol = solve(rig.balance(d.freq_hz, true_amp, fraction, n_harmonics=n_harmonics),
                    tol_n=1e-8)
        out.append(DwellRecord(d, fraction, sol, k * n, n))
    return out


def record(rig: Rig, dwells: list[Dwell], seed: int,
           base_sensors: SensorModel | None = None) -> Recording:
    """The measurement of ``dwells`` on ``rig`` (noise seeded by ``seed``)."""
    sensors = sensors_for(rig, base_sensors)
    rng = np.random.default_rng(seed)
    solved = solve_plan(rig, dwells)
    n_total = sum(r.n_samples for r in solved)
    time_s = np.arange(n_total) / FS_HZ
    cols = {c: np.zeros(n_total) for c in CHANNELS}
    cols["time_s"], cols["freq_hz"] = time_s, np.zeros(n_total)
    floor = _floor_response(rig, time_s)
    for r in solved:
        sl = slice(r.first_sample, r.first_sample + r.n_samples)
        t_local = np.arange(r.n_samples) / FS_HZ
        q, w = r.solution.harmonics, r.omega
        nh = np.arange(q.shape[1])
        force = np.zeros(q.shape[1], dtype=np.complex128)
        force[1] = r.solution.force
        frame = q[2] if q.shape[0] > 2 else np.zeros(q.shape[1])
        series = {"fx_N": force, "fy_N": np.zeros(q.shape[1]), "x_m": q[0], "y_m": q[1],
                  "ax_mps2": -((nh * w) ** 2) * (q[0] + frame), "ay_mps2": -((nh * w) ** 2) * q[1]}
        for name, harmonics in series.items():
            extra = floor[name][sl] if name in floor else None
            cols[name][sl] = sensors.record(name, t_local, harmonics, w, rng, extra)
        cols["freq_hz"][sl] = r.dwell.freq_hz
    # the oil temperature drifts continuously (the film's damping follows it per dwell)
    temp = rig.oil_temp_c(time_s / (n_total / FS_HZ))  # linear in the run's fraction
    cols["oil_temp_C"] = sensors.finish("oil_temp_C", temp, rng)
    return Recording(cols, solved, rig, sensors)


def _floor_response(rig: Rig, time_s: np.ndarray) -> dict[str, np.ndarray]:
    """The response to the floor's unmeasured input (``Hidden.floor``) over the run, per
    response channel (the rig's linear dynamic stiffness at its frequency, the parameters of
    the run's middle; superposed on the dwells' balance, which is exact for a linear rig)."""
    floor = rig.hidden.floor
    if floor is None:
        return {}
    m_, c_, k_ = rig.matrices(0.5)
    w = 2 * math.pi * floor.freq_hz
    force = np.zeros(rig.n_dof, dtype=np.complex128)
    force[0] = floor.force_n
    q = np.linalg.solve(k_ - w * w * m_ + 1j * w * c_, force)
    phase = np.exp(1j * w * time_s)
    frame = q[2] if rig.n_dof > 2 else 0.0
    return {"x_m": (q[0] * phase).real, "y_m": (q[1] * phase).real,
            "ax_mps2": (-(w**2) * (q[0] + frame) * phase).real,
            "ay_mps2": (-(w**2) * q[1] * phase).real}


def import_run(rec: Recording, tmp: Path, name: str) -> Path:
    """The recording as an operator's run file: the CSV through ``sfdrig import`` with only the
    minimal conditions (lubricated, x motion, no seal; no rig description)."""
    from sfdrig.cli import main

    csv = rec.to_csv(tmp / f"{name}.csv")
    run = tmp / f"{name}.h5"
    rc = main(["import", str(csv), "--out", str(run), "--lubricated", "--motion", "x",
               "--seal", "none", "--overwrite"])
    if rc != 0:
        raise RuntimeError(f"sfdrig import failed on {csv} (exit {rc})")
    return run
