"""Import measured data from elsewhere (CSV, MATLAB .mat, NI TDMS) into a run file.

Canonical signals (all optional except at least one force and one displacement)::

    time_s      sample times [s] (uniformly sampled), or give fs_hz
    freq_hz     excitation frequency of the dwell each sample belongs to [Hz]
    fx_N fy_N   forces [N]              -> channels fx, fy
    x_m y_m     displacements [m]       -> channels x, y
    ax_mps2 ay_mps2 accelerations [m/s^2] -> channels ax, ay
    oil_temp_C  oil temperature [degC]  -> channel t_oil

Columns (variables, TDMS channels) named like a canonical signal are used as they are; others are
mapped with ``mapping={"fx_N": "V1"}`` (CLI ``--map fx_N=V1``) and scaled with
``scale={"x_m": 1e-3}`` (``--scale x_m=1e-3``). The import is all-or-nothing: everything is read and
checked in memory, written to a temporary file beside the target and renamed into place only when
complete. Every error names the file and the line, column or variable at fault.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
import re
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from storage.errors import ImportDataError
from storage.runfile import KINDS, RunWriter, utc_now_iso

#: canonical name -> (channel name, units, channel kind); None for time and frequency.
CANONICAL: dict[str, tuple[str, str, str] | None] = {
    "time_s": None,
    "freq_hz": None,
    "fx_N": ("fx", "N", "load_cell"),
    "fy_N": ("fy", "N", "load_cell"),
    "x_m": ("x", "m", "eddy_current_probe"),
    "y_m": ("y", "m", "eddy_current_probe"),
    "ax_mps2": ("ax", "m/s^2", "accelerometer"),
    "ay_mps2": ("ay", "m/s^2", "accelerometer"),
    "oil_temp_C": ("t_oil", "degC", "thermocouple"),
}
FORCES = ("fx_N", "fy_N")
DISPLACEMENTS = ("x_m", "y_m")
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
        if key in ("time_s", "freq_hz"):
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
    if not any(c in chosen for c in FORCES) or not any(c in chosen for c in DISPLACEMENTS):
        raise ImportDataError(
            f"{where}: need at least one force (fx_N or fy_N) and one displacement (x_m or y_m); "
            f"found {sorted(chosen) or 'none'} among {what} {available}; map them with "
            "--map fx_N=NAME --map x_m=NAME"
        )
    return chosen


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
               for c, v in columns.items() if c not in ("time_s", "freq_hz")}
    return MeasuredData(signals=signals, fs_hz=fs_hz, freq_hz=columns.get("freq_hz"),
                        time_offset_s=time_offset_s, sources=sources, source_format=fmt,
                        start_time=start_time)


# --- CSV ---------------------------------------------------------------------------------------
def _decimals_quantum(texts: list[str]) -> float:
    """Half a unit of the last printed digit of a column of numbers [same units]."""
    worst = 0.0
    for s in texts:
        s = s.strip().strip('"').lower()
        mant, _, exp = s.partition("e")
        digits = len(mant.partition(".")[2])
        try:
            q = 0.5 * 10.0 ** (int(exp or 0) - digits)
        except ValueError:
            continue
        worst = max(worst, q)
    return worst


def read_csv(path: str | Path, mapping: Mapping[str, str] | None = None,
             fs_hz: float | None = None, scale: Mapping[str, float] | None = None) -> MeasuredData:
    """Read a CSV file with a header row into canonical signals.

    Copes with a byte-order mark, quoted header names, a trailing delimiter on every line, blank
    trailing lines, and ``,`` / ``;`` / tab delimiters. Only the columns used are parsed.

    Parameters
    ----------
    path : str or Path
    mapping : dict, optional
        Canonical name -> column name.
    fs_hz : float, optional
        Sample rate [Hz]; required without a time_s column, checked against one.
    scale : dict, optional
        Canonical name -> factor applied to the column.

    Raises
    ------
    ImportDataError
        Naming the line and column of a non-numeric cell, a short row, a non-uniform time step.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise ImportDataError(f"{path}: cannot read: {err.strerror}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise ImportDataError(f"{path}, line {line}: not UTF-8 text ({err.reason})") from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    first = 0
    while first < len(lines) and not lines[first].strip():
        first += 1
    if first >= len(lines):
        raise ImportDataError(f"{path}: empty file (no header row)")
    header_line = lines[first]
    delim = ","
    if "," not in header_line:
        delim = ";" if ";" in header_line else ("\t" if "\t" in header_line else ",")
    header = [h.strip() for h in next(csv.reader([header_line], delimiter=delim))]
    while header and header[-1] == "":  # trailing delimiter
        header.pop()
    if not header:
        raise ImportDataError(f"{path}, line {first + 1}: empty header row")
    for j, h in enumerate(header):
        if h == "":
            raise ImportDataError(f"{path}, line {first + 1}: column {j + 1} has no name")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise ImportDataError(f"{path}, line {first + 1}: duplicate column names {dup}")
    if all(_is_number(h) for h in header):
        raise ImportDataError(f"{path}, line {first + 1}: no header row (the first line holds "
                              "numbers); add a header line naming the columns")
    chosen = _select(header, mapping or {}, str(path), "columns")
    for canon, col in chosen.items():
        if col not in header:
            raise ImportDataError(
                f"{path}: --map {canon}={col}: no column {col!r} (columns: {header})"
            )
    body = lines[first + 1:]
    line_no = np.arange(first + 2, first + 2 + len(body))
    if "" in body:  # empty lines inside the data: drop them, keep the numbering
        keep = [i for i, line in enumerate(body) if line]
        body = [body[i] for i in keep]
        line_no = line_no[keep]
    if not body:
        raise ImportDataError(f"{path}: header only, no data rows")
    idx = {canon: header.index(col) for canon, col in chosen.items()}
    cols = sorted(set(idx.values()))
    data = _parse_columns(path, body, line_no, header, delim, cols)
    columns = {canon: data[cols.index(j)] for canon, j in idx.items()}

    def name_of(canon: str) -> str:
        return f"column {chosen[canon]!r}"

    def line_of(i: int) -> str:
        return f"line {int(line_no[i])}"

    where = str(path)
    _check_finite(columns, where, name_of, line_of)
    fs_found, offset = None, 0.0
    if "time_s" in columns:
        t_col = idx["time_s"]
        quantum = _decimals_quantum([_cell(s, delim, t_col) for s in body[:: max(1, len(body)
                                                                                // 1000)]])
        quantum = max(quantum, 4 * np.finfo(float).eps * float(np.max(np.abs(columns["time_s"]))))
        fs_found = _rate_from_time(columns["time_s"], quantum, line_of, where)
        offset = float(columns["time_s"][0])
    fs = _resolve_fs(fs_hz, fs_found, f"the time column {chosen.get('time_s')!r}", where)
    sources = {c: f"column {col!r}" for c, col in chosen.items()}
    return _finish(columns, fs, scale or {}, sources, "csv", where, name_of, offset)


def _widths_ok(text: str, delim: str, n_cols: int) -> bool:
    """Every line has ``n_cols`` cells, or one more that is empty (a trailing delimiter).
    Vectorised: counting per line in Python costs seconds on million-line files."""
    buf = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    ends = np.append(np.flatnonzero(buf == ord("\n")), buf.size)
    delims = np.flatnonzero(buf == ord(delim))
    counts = np.diff(np.concatenate(([0], np.searchsorted(delims, ends))))
    trailing = buf[np.maximum(ends - 1, 0)] == ord(delim)
    return bool(np.all((counts == n_cols - 1) | ((counts == n_cols) & trailing)))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _cell(line: str, delim: str, j: int) -> str:
    cells = line.split(delim)
    return cells[j] if j < len(cells) else ""


def _parse_columns(path: Path, body: list[str], line_no: np.ndarray, header: list[str],
                   delim: str, cols: list[int]) -> list[np.ndarray]:
    """Parse columns ``cols`` of the data rows; fast path via numpy, exact errors otherwise."""
    n_cols = len(header)
    text = "\n".join(body)
    if '"' not in text and _widths_ok(text, delim, n_cols):  # quotes would fool the count
        try:
            arr = np.loadtxt(io.StringIO(text), delimiter=delim, usecols=cols, ndmin=2,
                             dtype=np.float64, comments=None)
        except ValueError:
            pass  # the slow path names the line and column
        else:
            if arr.shape == (len(body), len(cols)):
                return [np.ascontiguousarray(arr[:, k]) for k in range(len(cols))]
    # Slow path: locate the first fault exactly.
    out = np.empty((len(cols), len(body)))
    for i, row in enumerate(csv.reader(body, delimiter=delim)):
        where = f"{path}, line {int(line_no[i])}"
        extra = row[n_cols:]
        if len(row) < n_cols:
            raise ImportDataError(f"{where}: {len(row)} cell(s), the header has {n_cols} columns")
        if any(c.strip() for c in extra):
            raise ImportDataError(
                f"{where}: {len(row)} cells, the header has {n_cols} columns"
            )
        for k, j in enumerate(cols):
            cell = row[j].strip()
            try:
                out[k, i] = float(cell)
            except ValueError:
                what = "empty cell" if not cell else f"{cell!r} is not a number"
                raise ImportDataError(f"{where}, column {header[j]!r}: {what}") from None
    return list(out)


# --- MATLAB ------------------------------------------------------------------------------------
_MAT_REF = re.compile(
    r"^(?P<path>[A-Za-z]\w*(?:\.[A-Za-z]\w*)*)"
    r"(?:\(\s*(?::\s*,\s*(?P<col>\d+)|(?P<row>\d+)\s*,\s*:)\s*\))?$"
)


def _parse_mat_ref(ref: str, where: str) -> tuple[list[str], int | None, int | None]:
    m = _MAT_REF.match(ref.strip())
    if not m:
        raise ImportDataError(
            f"{where}: {ref!r} is not a variable reference (use NAME, NAME.FIELD, NAME(:,COL) "
            "or NAME(ROW,:), 1-based as in MATLAB)"
        )
    col = int(m["col"]) if m["col"] else None
    row = int(m["row"]) if m["row"] else None
    if col == 0 or row == 0:
        raise ImportDataError(f"{where}: {ref!r}: MATLAB indices start at 1")
    return m["path"].split("."), col, row


def _vector(arr: Any, ref: str, col: int | None, row: int | None, where: str) -> np.ndarray:
    a = np.asarray(arr)
    if a.dtype.kind not in "fiub":
        raise ImportDataError(f"{where}: variable {ref!r} is not numeric (type {a.dtype})")
    if col is not None or row is not None:
        if a.ndim != 2:
            raise ImportDataError(f"{where}: {ref!r}: indexing needs a 2-D matrix, the variable "
                                  f"has shape {a.shape}")
        k = (col if col is not None else row or 0) - 1
        axis_len = a.shape[1] if col is not None else a.shape[0]
        if k >= axis_len:
            raise ImportDataError(f"{where}: {ref!r}: index {k + 1} exceeds the variable's "
                                  f"shape {a.shape}")
        a = a[:, k] if col is not None else a[k, :]
    a = np.squeeze(a)
    if a.ndim != 1:
        raise ImportDataError(f"{where}: variable {ref!r} has shape {np.shape(arr)}, not a vector "
                              "(select a column with NAME(:,COL))")
    return a.astype(np.float64)


def read_mat(path: str | Path, mapping: Mapping[str, str] | None = None,
             fs_hz: float | None = None, scale: Mapping[str, float] | None = None) -> MeasuredData:
    """Read a MATLAB .mat file (v4-v7 with scipy, v7.3 with h5py) into canonical signals.

    Variables are referenced as ``NAME``, ``STRUCT.FIELD`` or a matrix column ``NAME(:,COL)``
    (1-based, MATLAB order).
    """
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise ImportDataError(f"{where}: no such file")
    mapping = dict(mapping or {})
    if h5py.is_hdf5(path):
        fmt = "mat-v7.3"
        try:
            f = h5py.File(path, "r")
        except OSError as err:
            raise ImportDataError(
                f"{where}: cannot open as a v7.3 .mat (HDF5) file: {err}"
            ) from None
        with f:
            available = [k for k in f if not k.startswith("#")]

            def fetch(parts: list[str], ref: str) -> np.ndarray:
                obj: Any = f
                for p in parts:
                    if not isinstance(obj, h5py.Group) or p not in obj:
                        raise ImportDataError(f"{where}: no variable {ref!r} (variables: "
                                              f"{available})")
                    obj = obj[p]
                if not isinstance(obj, h5py.Dataset):
                    raise ImportDataError(f"{where}: {ref!r} is a struct, not a numeric variable")
                mcls = obj.attrs.get("MATLAB_class", b"double")
                mcls = mcls.decode() if isinstance(mcls, bytes) else str(mcls)
                if mcls in ("char", "cell", "struct", "logical") or obj.dtype.kind not in "fiu":
                    raise ImportDataError(f"{where}: variable {ref!r} is MATLAB {mcls}, not "
                                          "numeric")
                # MATLAB is column-major: an (m, n) matrix is stored as (n, m).
                return np.asarray(obj[()]).T

            columns, sources = _read_mat_vars(fetch, available, mapping, where)
    else:
        fmt = "mat"
        import scipy.io

        try:
            variables = scipy.io.loadmat(path, squeeze_me=False, struct_as_record=True)
        except NotImplementedError as err:
            raise ImportDataError(f"{where}: {err}") from None
        except Exception as err:  # scipy raises a variety of errors on bad files
            raise ImportDataError(f"{where}: not a readable .mat file: {err}") from None
        available = [k for k in variables if not k.startswith("__")]

        def fetch(parts: list[str], ref: str) -> np.ndarray:
            if parts[0] not in variables:
                raise ImportDataError(f"{where}: no variable {ref!r} (variables: {available})")
            obj: Any = variables[parts[0]]
            for p in parts[1:]:
                names = getattr(getattr(obj, "dtype", None), "names", None) or ()
                if p not in names:
                    raise ImportDataError(f"{where}: no field {p!r} in {ref!r} (fields: "
                                          f"{list(names)})")
                obj = obj[p]
                while isinstance(obj, np.ndarray) and obj.dtype == object and obj.size == 1:
                    obj = obj.flat[0]
                if isinstance(obj, np.ndarray) and obj.dtype.names is None and obj.size == 1 \
                        and obj.dtype == object:
                    obj = obj.flat[0]
            while isinstance(obj, np.ndarray) and obj.dtype == object and obj.size == 1:
                obj = obj.flat[0]
            if isinstance(obj, np.ndarray) and obj.dtype.names:
                raise ImportDataError(f"{where}: {ref!r} is a struct, not a numeric variable")
            return np.asarray(obj)

        columns, sources = _read_mat_vars(fetch, available, mapping, where)

    def name_of(canon: str) -> str:
        return sources[canon]

    _check_finite(columns, where, name_of, lambda i: f"sample {i}")
    fs_found, offset = None, 0.0
    if "time_s" in columns:
        t = columns["time_s"]
        fs_found = _rate_from_time(t, 4 * np.finfo(float).eps * float(np.max(np.abs(t))),
                                   lambda i: f"{sources['time_s']} sample {i}", where)
        offset = float(t[0])
    fs = _resolve_fs(fs_hz, fs_found, f"the time vector {sources.get('time_s')}", where)
    return _finish(columns, fs, scale or {}, sources, fmt, where, name_of, offset)


def _read_mat_vars(fetch: Any, available: list[str], mapping: dict[str, str],
                   where: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    chosen = _select(available, mapping, where, "variables")
    columns: dict[str, np.ndarray] = {}
    sources: dict[str, str] = {}
    for canon, ref in chosen.items():
        parts, col, row = _parse_mat_ref(ref, where)
        arr = fetch(parts, ref)
        columns[canon] = _vector(arr, ref, col, row, where)
        sources[canon] = f"variable {ref!r}"
    return columns, sources


# --- TDMS --------------------------------------------------------------------------------------
def read_tdms(path: str | Path, mapping: Mapping[str, str] | None = None,
              fs_hz: float | None = None, scale: Mapping[str, float] | None = None) -> MeasuredData:
    """Read an NI TDMS file (as LabVIEW writes it: groups of channels, ``wf_increment`` [s]).

    Channels are referenced as ``GROUP/CHANNEL`` or, when unique across groups, ``CHANNEL``.
    The sample rate is ``1 / wf_increment`` (checked against ``fs_hz`` when both are given).
    """
    from nptdms import TdmsFile

    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise ImportDataError(f"{where}: no such file")
    with open(path, "rb") as fh:
        if fh.read(4) != b"TDSm":
            raise ImportDataError(f"{where}: not a TDMS file (no 'TDSm' lead-in)")
    try:
        tdms = TdmsFile.read(path)
    except Exception as err:  # npTDMS raises ValueError, KeyError, struct.error... on bad files
        raise ImportDataError(f"{where}: not a readable TDMS file: {err}") from None
    if not any(g.channels() for g in tdms.groups()):
        raise ImportDataError(f"{where}: no channels (empty or damaged TDMS file)")
    by_full: dict[str, Any] = {}
    by_short: dict[str, list[Any]] = {}
    for group in tdms.groups():
        for ch in group.channels():
            by_full[f"{group.name}/{ch.name}"] = ch
            by_short.setdefault(ch.name, []).append(ch)
    available = list(by_full)
    unique_short = [n for n, chs in by_short.items() if len(chs) == 1]
    chosen = _select(unique_short + available, mapping or {}, where, "channels")
    columns: dict[str, np.ndarray] = {}
    sources: dict[str, str] = {}
    increments: dict[str, float] = {}
    start_time = ""
    for canon, ref in chosen.items():
        if ref in by_full:
            ch = by_full[ref]
        elif ref in by_short and len(by_short[ref]) == 1:
            ch = by_short[ref][0]
        elif ref in by_short:
            raise ImportDataError(f"{where}: channel name {ref!r} is in several groups; use "
                                  f"GROUP/CHANNEL (one of {[c.path for c in by_short[ref]]})")
        else:
            raise ImportDataError(f"{where}: no channel {ref!r} (channels: {available})")
        label = f"channel '{ch.group_name}/{ch.name}'"
        data = ch[:]
        if getattr(data, "dtype", np.dtype(object)).kind not in "fiu":
            raise ImportDataError(f"{where}: {label} is not numeric (type {data.dtype})")
        columns[canon] = np.asarray(data, dtype=np.float64)
        sources[canon] = label
        inc = ch.properties.get("wf_increment")
        if inc is not None and canon != "time_s":
            if not float(inc) > 0:
                raise ImportDataError(f"{where}: {label} has wf_increment {inc}, not positive")
            increments[label] = float(inc)
        t0 = ch.properties.get("wf_start_time")
        if t0 is not None and not start_time:
            start_time = _tdms_time(t0)
    _check_finite(columns, where, sources.__getitem__, lambda i: f"sample {i}")
    fs_found = None
    what = ""
    if "time_s" in columns:
        t = columns["time_s"]
        fs_found = _rate_from_time(t, 4 * np.finfo(float).eps * float(np.max(np.abs(t))),
                                   lambda i: f"{sources['time_s']} sample {i}", where)
        what = f"the time channel {sources['time_s']}"
    if increments:
        vals = list(increments.values())
        if max(vals) - min(vals) > FS_TOLERANCE * min(vals):
            desc = ", ".join(f"{k}: {v:g} s" for k, v in increments.items())
            raise ImportDataError(f"{where}: channels have different wf_increment ({desc})")
        fs_inc = 1.0 / vals[0]
        if fs_found is not None and abs(fs_found - fs_inc) > FS_TOLERANCE * fs_inc:
            raise ImportDataError(f"{where}: wf_increment says {fs_inc:.9g} Hz, {what} says "
                                  f"{fs_found:.9g} Hz")
        fs_found, what = fs_inc, f"wf_increment of {next(iter(increments))}"
    fs = _resolve_fs(fs_hz, fs_found, what, where)
    offset = float(columns["time_s"][0]) if "time_s" in columns else 0.0
    return _finish(columns, fs, scale or {}, sources, "tdms", where, sources.__getitem__, offset,
                   start_time)


def _tdms_time(value: Any) -> str:
    try:
        ts = np.datetime64(value, "us")
        return datetime.fromisoformat(str(ts)).replace(tzinfo=UTC).isoformat(
            timespec="milliseconds")
    except (ValueError, TypeError):
        return ""


# --- run file ----------------------------------------------------------------------------------
READERS = {".csv": read_csv, ".txt": read_csv, ".mat": read_mat, ".tdms": read_tdms}


def read_measured(path: str | Path, mapping: Mapping[str, str] | None = None,
                  fs_hz: float | None = None,
                  scale: Mapping[str, float] | None = None) -> MeasuredData:
    """Read any supported file (by extension: .csv/.txt, .mat, .tdms) into canonical signals."""
    path = Path(path)
    reader = READERS.get(path.suffix.lower())
    if reader is None:
        raise ImportDataError(f"{path}: unknown file type {path.suffix!r} (supported: "
                              f"{', '.join(READERS)})")
    return reader(path, mapping, fs_hz, scale)


def dwell_steps(freq_hz: np.ndarray) -> list[dict[str, Any]]:
    """One step per run of constant, positive excitation frequency (contract A step dicts).

    Runs of NaN or non-positive frequency (transitions, rests) are not dwells.
    """
    f = np.asarray(freq_hz, dtype=np.float64)
    if f.size == 0:
        return []
    change = np.flatnonzero(np.diff(f) != 0) + 1
    bounds = np.concatenate(([0], change, [f.size]))
    steps: list[dict[str, Any]] = []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        value = float(f[a])
        if not (math.isfinite(value) and value > 0):
            continue
        steps.append({
            "index": len(steps), "freq_hz": value, "target_kind": "", "target_value": math.nan,
            "motion": "", "first_sample": int(a), "last_sample": int(b), "updates": 0,
            "converged": True, "reason": "", "harmonics": {}, "drive_v": {},
        })
    return steps


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_imported_run(data: MeasuredData, out: str | Path, source: str | Path, *,
                       kind: str = "imported", notes: str = "", operator: str = "",
                       run_id: str | None = None, overwrite: bool = False,
                       extra_spec: Mapping[str, Any] | None = None) -> Path:
    """Write measured data as a run file, atomically (temporary file, then rename).

    Channels are fx, fy, x, y, ax, ay, t_oil (those present), in N, m, m/s^2, degC; steps come
    from runs of constant ``freq_hz``.
    """
    out = Path(out)
    source = Path(source)
    if kind not in KINDS:
        raise ImportDataError(f"--kind {kind!r} is not one of {KINDS}")
    if out.exists() and not overwrite:
        raise ImportDataError(f"{out}: exists already (choose another --out or overwrite)")
    if not out.parent.is_dir():
        raise ImportDataError(f"{out.parent}: output directory does not exist")
    channels = []
    order = []
    for canon, spec in CANONICAL.items():
        if spec is None or canon not in data.signals:
            continue
        name, units, ch_kind = spec
        channels.append({"name": name, "units": units, "kind": ch_kind,
                         "sensor": f"imported: {data.sources.get(canon, canon)}",
                         "physical_channel": ""})
        order.append(canon)
    spec_json = {
        "source_file": str(source.resolve()), "source_format": data.source_format,
        "source_sha256": _sha256(source), "imported_at": utc_now_iso(),
        "signals": {c: data.sources.get(c, "") for c in order}, "time_offset_s":
        data.time_offset_s, "n_samples": data.n_samples,
    }
    if data.freq_hz is not None:
        spec_json["freq_source"] = data.sources.get("freq_hz", "")
    spec_json.update(extra_spec or {})
    run_id = run_id or f"imported-{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{out.stem}"
    # A hidden unique name beside the target (same file system, so the rename is atomic);
    # created by HDF5 itself so it gets the usual permissions (mkstemp would make it 0600).
    tmp = out.parent / f".{out.name}.{uuid.uuid4().hex[:12]}.tmp"
    try:
        with RunWriter.create(
            tmp, run_id, kind, channels, [], data.fs_hz, operator=operator, notes=notes,
            test_spec=spec_json, start_time=data.start_time or None, overwrite=False,
            swmr=False, flush_interval_s=0, compression="gzip",
        ) as w:
            block = 1 << 20
            n = data.n_samples
            for a in range(0, n, block):
                b = min(a + block, n)
                w.on_block(a, np.stack([data.signals[c][a:b] for c in order]), None)
            if data.freq_hz is not None:
                for step in dwell_steps(data.freq_hz):
                    w.on_step(step)
            w.on_event("info", f"imported from {source} ({data.source_format})", 0)
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out


def import_file(path: str | Path, out: str | Path, *, mapping: Mapping[str, str] | None = None,
                fs_hz: float | None = None, scale: Mapping[str, float] | None = None,
                kind: str = "imported", notes: str = "", operator: str = "",
                run_id: str | None = None, overwrite: bool = False) -> Path:
    """Import a measured-data file (CSV, .mat, .tdms) into run file ``out``, all or nothing.

    Parameters
    ----------
    path : str or Path
        The measured data.
    out : str or Path
        The run file to create (refused if it exists unless ``overwrite``).
    mapping : dict, optional
        Canonical name -> column, variable or channel name.
    fs_hz : float, optional
        Sample rate [Hz] when the file has no time base.
    scale : dict, optional
        Canonical name -> factor.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ImportDataError
        Naming the file and the line, column or variable at fault; ``out`` is then untouched.
    """
    data = read_measured(path, mapping, fs_hz, scale)
    return write_imported_run(data, out, path, kind=kind, notes=notes, operator=operator,
                              run_id=run_id, overwrite=overwrite,
                              extra_spec={"mapping": dict(mapping or {}),
                                          "scale": dict(scale or {})})
