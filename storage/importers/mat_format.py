"""MATLAB .mat files (v4-v7 through scipy, v7.3 through h5py)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from storage.errors import ImportDataError
from storage.importers.common import (
    MeasuredData,
    ReadColumns,
    _select,
    measured_from,
)

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
            stored_rate = _stored_rate(fetch, available, where)
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
        stored_rate = _stored_rate(fetch, available, where)

    stated = None if stored_rate is None else (f"variable {stored_rate[0]!r}", stored_rate[1])
    return measured_from(ReadColumns(columns, sources, fmt, stated_rate=stated), where, fs_hz,
                         scale)


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




#: Variables that hold a sample rate [Hz] in files from the lab's tools.
RATE_NAMES = ("Fs", "fs", "FS", "SampleRate", "sample_rate", "sampling_rate_hz")


def _stored_rate(fetch: Any, available: list[str], where: str) -> tuple[str, float] | None:
    """(name, rate [Hz]) of a scalar sample-rate variable, if the file has one."""
    for name in RATE_NAMES:
        if name not in available:
            continue
        try:
            value = np.asarray(fetch([name], name), dtype=np.float64)
        except (ImportDataError, TypeError, ValueError):
            raise ImportDataError(f"{where}: variable {name!r} is not a numeric sample rate"
                                  ) from None
        if value.size != 1 or not (np.isfinite(value.flat[0]) and value.flat[0] > 0):
            raise ImportDataError(f"{where}: variable {name!r} = {value.ravel()[:3]} is not a "
                                  "positive scalar sample rate [Hz]")
        return name, float(value.flat[0])
    return None

