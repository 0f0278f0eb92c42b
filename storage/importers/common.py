"""What every importer shares: canonical names, the measured data, options, sample rate."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from storage.errors import ImportDataError

#: canonical name -> (channel name, units, channel kind); None for time and frequency.
CANONICAL: dict[str, tuple[str, str, str] | None] = {
    "time_s": None,
    "freq_hz": None,
    "step": None,
    "fx_N": ("fx", "N", "load_cell"),
    "fy_N": ("fy", "N", "load_cell"),
    "x_m": ("x", "m", "eddy_current_probe"),
    "y_m": ("y", "m", "eddy_current_probe"),
    "vx_mps": ("vx", "m/s", "velocity"),
    "vy_mps": ("vy", "m/s", "velocity"),
    "ax_mps2": ("ax", "m/s^2", "accelerometer"),
    "ay_mps2": ("ay", "m/s^2", "accelerometer"),
    "oil_temp_C": ("t_oil", "degC", "thermocouple"),
    "p_in_Pa": ("p_in", "Pa", "pressure"),
    "p_rec_Pa": ("p_rec", "Pa", "pressure"),
}
#: Columns that are not signals (not scaled, not stored as channels).
NON_SIGNALS = ("time_s", "freq_hz", "step")
FORCES = ("fx_N", "fy_N")
DISPLACEMENTS = ("x_m", "y_m")
#: Any of these is a response (displacement, velocity or acceleration).
RESPONSES = ("x_m", "y_m", "vx_mps", "vy_mps", "ax_mps2", "ay_mps2")
#: Relative disagreement tolerated between --fs and a time column or wf_increment.
FS_TOLERANCE = 1e-3


@dataclass
class MeasuredData:
    """Measured signals read from a file, in canonical names, before they become a run.

    Attributes
    ----------
    signals : dict of str to ndarray
        Canonical name (``fx_N``, ``x_m``...) -> float64 samples, scaled, equal lengths.
    fs_hz : float
        Sample rate [S/s].
    freq_hz : ndarray or None
        Dwell frequency per sample [Hz], when the file has one.
    time_offset_s : float
        Time of the first sample in the file's time base [s] (0 without a time column).
    sources : dict of str to str
        Canonical name -> where it came from (column, variable or TDMS channel).
    source_format : str
        "csv", "mat", "mat-v7.3" or "tdms".
    start_time : str
        ISO 8601 UTC of the first sample when the file says so (TDMS), else "".
    """

    signals: dict[str, np.ndarray]
    fs_hz: float
    freq_hz: np.ndarray | None = None
    step: np.ndarray | None = None
    time_offset_s: float = 0.0
    sources: dict[str, str] = field(default_factory=dict)
    source_format: str = ""
    start_time: str = ""

    @property
    def n_samples(self) -> int:
        return len(next(iter(self.signals.values())))


# --- option parsing ----------------------------------------------------------------------------
def parse_assignments(items: list[str] | None, option: str) -> dict[str, str]:
    """``["fx_N=V1", ...]`` -> ``{"fx_N": "V1"}``; checks canonical names.

    Raises
    ------
    ImportDataError
        For a malformed item, an unknown canonical name or a name given twice.
    """
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise ImportDataError(f"{option} {item!r}: expected CANONICAL=VALUE, e.g. fx_N=V1")
        if key not in CANONICAL:
            raise ImportDataError(
                f"{option} {item!r}: {key!r} is not a canonical name ({', '.join(CANONICAL)})"
            )
        if key in out:
            raise ImportDataError(f"{option}: {key!r} given twice")
        out[key] = value
    return out


def parse_scale(items: list[str] | None) -> dict[str, float]:
    """``["x_m=1e-3"]`` -> ``{"x_m": 0.001}``; the factor must be a finite number."""
    out: dict[str, float] = {}
    for key, text in parse_assignments(items, "--scale").items():
        try:
            factor = float(text)
        except ValueError:
            factor = math.nan
        if not math.isfinite(factor) or factor == 0:
            raise ImportDataError(f"--scale {key}={text}: factor must be a finite non-zero number")
        if key in NON_SIGNALS:
            raise ImportDataError(f"--scale {key}: only signal columns can be scaled")
        out[key] = factor
    return out


def _select(available: list[str], mapping: Mapping[str, str], where: str,
            what: str) -> dict[str, str]:
    """Canonical -> source name: canonical names present, overridden by the mapping."""
    chosen = {c: c for c in CANONICAL if c in available}
    for canon, src in mapping.items():
        if canon not in CANONICAL:
            raise ImportDataError(f"{where}: {canon!r} is not a canonical name")
        chosen[canon] = src
    # a column mapped to another canonical name is no longer also that name's source
    for canon in list(chosen):
        if canon not in mapping and canon in mapping.values():
            del chosen[canon]
    if not any(c in chosen for c in FORCES) or not any(c in chosen for c in RESPONSES):
        raise ImportDataError(
            f"{where}: need at least one force (fx_N or fy_N) and one response (x_m, y_m, "
            f"vx_mps, vy_mps, ax_mps2 or ay_mps2); found {sorted(chosen) or 'none'} among "
            f"{what} {available}; map them with --map fx_N=NAME --map x_m=NAME"
        )
    return chosen


# --- the skeleton every format's reader ends in --------------------------------------------------
@dataclass
class ReadColumns:
    """What a format's reader found: the chosen columns before any check, and what the file says
    about its own timing. Each reader (CSV, MAT, TDMS) only opens its format and fills this;
    `measured_from` does the rest the same way for all of them.

    Attributes
    ----------
    columns : dict of str to ndarray
        Canonical name -> the raw vector as read (unscaled, not yet checked).
    sources : dict of str to str
        Canonical name -> how the file names it ("column 'x'", "variable 'x'", ...), for errors.
    source_format : str
        "csv", "mat", "mat-v7.3" or "tdms".
    line_of : callable or None
        Sample index -> its line in a text file, for errors ("line 12"); None for arrays, whose
        errors name "sample i" (of the vector, for the time vector).
    time_quantum_s : float or None
        The rounding of a printed time column [s]; None: the float's own resolution.
    stated_rate : (str, float) or None
        A sample rate the file states apart from a time column [Hz], and what states it
        ("variable 'Fs'", "wf_increment of channel 'g/x'").
    start_time : str
        ISO 8601 UTC of the first sample when the file says so, else "".
    """

    columns: dict[str, np.ndarray]
    sources: dict[str, str]
    source_format: str
    line_of: Callable[[int], str] | None = None
    time_quantum_s: float | None = None
    stated_rate: tuple[str, float] | None = None
    start_time: str = ""


def measured_from(read: ReadColumns, where: str, fs_hz: float | None,
                  scale: Mapping[str, float] | None) -> MeasuredData:
    """Check the columns (finite, equal lengths, plausible), find the sample rate (a time
    column, a rate the file states and ``fs_hz`` must agree), scale: the measured data."""
    name_of = read.sources.__getitem__
    place_of = read.line_of or (lambda i: f"sample {i}")
    _check_finite(read.columns, where, name_of, place_of)
    fs_found, offset, what = None, 0.0, ""
    if "time_s" in read.columns:
        t = read.columns["time_s"]
        quantum = 4 * np.finfo(float).eps * float(np.max(np.abs(t))) if len(t) else 0.0
        if read.time_quantum_s is not None:
            quantum = max(quantum, read.time_quantum_s)
        time_place = read.line_of or (lambda i: f"{read.sources['time_s']} sample {i}")
        fs_found = _rate_from_time(t, quantum, time_place, where)
        offset, what = float(t[0]), f"the time {read.sources['time_s']}"
    if read.stated_rate is not None:
        stated, rate = read.stated_rate
        if fs_found is not None and abs(rate - fs_found) > FS_TOLERANCE * fs_found:
            raise ImportDataError(f"{where}: {stated} says {rate:.9g} Hz, {what} says "
                                  f"{fs_found:.9g} Hz")
        fs_found, what = rate, stated
    fs = _resolve_fs(fs_hz, fs_found, what, where)
    return _finish(read.columns, fs, scale or {}, read.sources, read.source_format, where,
                   name_of, offset, read.start_time)


# --- sample rate -------------------------------------------------------------------------------
def _rate_from_time(t: np.ndarray, quantum_s: float, line_of: Any, where: str) -> float:
    """Sample rate [S/s] of a time column after checking it is uniformly sampled.

    ``quantum_s`` is the rounding of the printed times; ``line_of(i)`` names row i's place.
    """
    n = len(t)
    if n < 2:
        raise ImportDataError(f"{where}: {n} sample(s): too few to find a sample rate")
    dt = np.diff(t)
    dt_ref = (t[-1] - t[0]) / (n - 1)
    if not dt_ref > 0:
        raise ImportDataError(f"{where}: time_s does not increase ({t[0]!r} to {t[-1]!r})")
    tol = 0.01 * dt_ref + 2 * quantum_s
    bad = np.flatnonzero(np.abs(dt - dt_ref) > tol)
    if bad.size:
        i = int(bad[0]) + 1
        raise ImportDataError(
            f"{where}, {line_of(i)}: time_s is not uniformly sampled: step {dt[i - 1]:.9g} s "
            f"from the previous sample, the mean step is {dt_ref:.9g} s"
        )
    drift = np.abs(t - (t[0] + dt_ref * np.arange(n)))
    i = int(np.argmax(drift))
    if drift[i] > 0.25 * dt_ref + 2 * quantum_s:
        raise ImportDataError(
            f"{where}, {line_of(i)}: time_s is not uniformly sampled: {t[i]:.9g} s is "
            f"{drift[i]:.3g} s off the uniform grid"
        )
    return 1.0 / dt_ref


def _resolve_fs(fs_hz: float | None, fs_found: float | None, what: str, where: str) -> float:
    if fs_hz is not None and not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ImportDataError(f"--fs {fs_hz}: must be a positive sample rate [Hz]")
    if fs_found is None:
        if fs_hz is None:
            raise ImportDataError(
                f"{where}: no time_s column and no sample rate: give --fs HZ or map time_s"
            )
        return float(fs_hz)
    if fs_hz is not None and abs(fs_hz - fs_found) > FS_TOLERANCE * fs_found:
        raise ImportDataError(
            f"{where}: --fs {fs_hz:g} Hz disagrees with {what} ({fs_found:.9g} Hz)"
        )
    return float(fs_hz) if fs_hz is not None else float(fs_found)


def _check_finite(columns: dict[str, np.ndarray], where: str, name_of: Any,
                  place_of: Any) -> None:
    """Measured samples must be finite numbers (NaN would poison every later fit)."""
    for canon, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            i = int(bad[0])
            raise ImportDataError(
                f"{where}, {place_of(i)}, {name_of(canon)}: {values[i]} is not a finite number"
            )


def _finish(columns: dict[str, np.ndarray], fs_hz: float, scale: Mapping[str, float],
            sources: dict[str, str], fmt: str, where: str, name_of: Any,
            time_offset_s: float = 0.0, start_time: str = "") -> MeasuredData:
    lengths = {c: len(v) for c, v in columns.items()}
    if len(set(lengths.values())) > 1:
        desc = ", ".join(f"{name_of(c)} has {n}" for c, n in lengths.items())
        raise ImportDataError(f"{where}: signals differ in length: {desc}")
    if next(iter(lengths.values())) == 0:
        raise ImportDataError(f"{where}: no samples")
    for canon in scale:
        if canon not in columns:
            raise ImportDataError(f"{where}: --scale {canon}: no such signal is imported")
    signals = {c: np.asarray(v, dtype=np.float64) * scale.get(c, 1.0)
               for c, v in columns.items() if c not in NON_SIGNALS}
    for canon, values in signals.items():
        _check_plausible(canon, values, where, name_of(canon))
    return MeasuredData(signals=signals, fs_hz=fs_hz, freq_hz=columns.get("freq_hz"),
                        step=columns.get("step"),
                        time_offset_s=time_offset_s, sources=sources, source_format=fmt,
                        start_time=start_time)




#: Ranges no signal of a test rig reaches in SI units: beyond them the column is in other units
#: or is another quantity (an accelerometer mapped as a displacement). Wide on purpose: a
#: positioning stage moves 0.25 m (EMPS), a probe sees less than the 127 um clearance.
PLAUSIBLE_SPAN = {"x_m": 1.0, "y_m": 1.0, "vx_mps": 100.0, "vy_mps": 100.0, "fx_N": 1e5,
                  "fy_N": 1e5, "ax_mps2": 1e5, "ay_mps2": 1e5, "p_in_Pa": 1e8, "p_rec_Pa": 1e8}
PLAUSIBLE_TEMPERATURE_C = (-60.0, 300.0)


def _check_plausible(canon: str, values: np.ndarray, where: str, name: str) -> None:
    if canon == "oil_temp_C":
        lo, hi = float(np.min(values)), float(np.max(values))
        if lo < PLAUSIBLE_TEMPERATURE_C[0] or hi > PLAUSIBLE_TEMPERATURE_C[1]:
            raise ImportDataError(f"{where}, {name}: oil temperature from {lo:g} to {hi:g} degC "
                                  "is not in degC (check the column or --scale)")
        return
    limit = PLAUSIBLE_SPAN.get(canon)
    if limit is None:
        return
    span = float(np.max(values) - np.min(values))
    if span > limit:
        unit = CANONICAL[canon][1] if CANONICAL.get(canon) else ""  # type: ignore[index]
        raise ImportDataError(
            f"{where}, {name}: {canon} spans {span:.4g} {unit}, more than any test rig's "
            f"{limit:g} {unit}: another quantity or other units (check --map, or --scale "
            f"{canon}=FACTOR, e.g. 1e-6 for micrometres)")


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes (hex), read in 1 MiB pieces."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
