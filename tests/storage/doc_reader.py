"""A run-file reader written only from docs/run-files.md: h5py and numpy, nothing of sfdrig.

What the page says, and nothing else, is used: the time axis from each signal's ``time_start``
and ``time_increment``, a step's record ``first_sample .. last_sample-1`` from ``/steps``, the
channel order from the ``channels`` attribute (JSON) of ``/step_harmonics``, and the convention
``z(t) = z0 + sum_h Re(Z_h exp(i h 2 pi freq_hz t))`` with t counted from sample 0 of the run.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np


def step_harmonics_from_samples(path: str | Path, channel: str, step: int,
                                n_harmonics: int = 5) -> tuple[np.ndarray, np.ndarray, str]:
    """(Z rebuilt from the raw samples, Z stored in the file, units) of ``channel`` in row
    ``step`` of ``/steps``: complex peak amplitudes of 1X..``n_harmonics``X."""
    with h5py.File(path, "r") as f:
        ds = f["channels"][channel]
        row = f["steps"][step]
        a, b = int(row["first_sample"]), int(row["last_sample"])
        t = ds.attrs["time_start"] + np.arange(a, b) * ds.attrs["time_increment"]
        z = ds[a:b]
        w = 2 * np.pi * float(row["freq_hz"])
        h = np.arange(1, n_harmonics + 1)
        basis = np.column_stack([np.ones_like(t), np.cos(np.outer(w * t, h)),
                                 np.sin(np.outer(w * t, h))])
        coef = np.linalg.lstsq(basis, z, rcond=None)[0]
        rebuilt = coef[1:1 + n_harmonics] - 1j * coef[1 + n_harmonics:]  # Z = z_c - i z_s
        k = json.loads(f["step_harmonics"].attrs["channels"]).index(channel)
        stored = f["step_harmonics"][step, k, :n_harmonics]
        units = ds.attrs["units"]
        units = units.decode() if isinstance(units, bytes) else str(units)
    return rebuilt, stored, units
