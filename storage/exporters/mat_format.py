"""MATLAB export: one ``<stem>.mat``, v5 (scipy.io.loadmat and every MATLAB) while the samples fit
in ``V5_MAX_BYTES``, else v7.3 (HDF5, MATLAB R2006b on, h5py), written block by block.

Variables: ``Fs`` [Hz], ``time_s``, ``step``, ``freq_hz`` and one column vector per signal (the
export's column names), and the structs ``steps`` (the step table, one field per column),
``harmonics`` (``Z`` complex (step, channel, harmonic), ``amplitude``, ``phase_deg``,
``channels``, ``columns``, ``units``), ``drive_1x`` (``Z`` (step, drive)), ``channels`` (the
channel table), ``events``, ``conditions``, ``conventions``; ``sfdrig_export`` is the metadata
JSON (`sfdrig import` restores the run from it) and ``README`` says all this in words. Lists of
text are cell arrays in v5 and char matrices (one row each, padded with blanks) in v7.3.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from storage.exporters.common import ExportSet, Progress
from storage.exporters.files import AtomicFiles

#: Bytes of samples above which the export is v7.3 (v5 stores a variable in at most 2 GB, and
#: its writer holds everything in memory).
V5_MAX_BYTES = 1 << 30

README = """\
sfdrig run {run_id} exported {exported_at} ({fmt}).
time_s, step, freq_hz and one column vector per signal, engineering units (channels.units):
  time_s = run time [s] (sample / Fs after conditions.start_time);
  step = index of the step whose record holds the sample, -1 outside; freq_hz its frequency.
steps: the step table (target_value in target_units: m, N or Pa by target_kind; freq_hz 0 for
  steps without excitation, see conventions.step_fields_by_kind).
harmonics.Z(step, channel, h): complex peak amplitude of harmonic h (1X..5X), in the channel's
  units; z(t) = real(Z * exp(1i*h*2*pi*freq_hz*t)) with t = time_s (phase from run time 0).
drive_1x.Z(step, drive): the 1X of every drive [V], same convention.
conditions: the run (lubricated, seal, motion, kind, status...). sfdrig_export: all of it as JSON
  (jsondecode), which sfdrig import reads to restore the run."""


def _cellstr(values: list[Any]) -> np.ndarray:
    arr = np.empty((len(values), 1), dtype=object)
    for i, v in enumerate(values):
        arr[i, 0] = str(v)
    return arr


def _column(values: list[Any]) -> Any:
    if values and all(isinstance(v, str) for v in values):
        return _cellstr(values)
    if values and all(isinstance(v, bool) for v in values):
        return np.asarray(values, dtype=bool).reshape(-1, 1)
    return np.asarray(values, dtype=np.float64).reshape(-1, 1)


def _tables(exp: ExportSet) -> dict[str, Any]:
    """Every variable but the samples, as scipy.io.savemat takes them."""
    z, d = exp.harmonics()
    ai = [c for c in exp.columns if c.group == "channels"]
    ao = [c for c in exp.columns if c.group == "drive"]
    cond = {k: (v if v is not None else "") for k, v in exp.conditions().items()}
    meta = exp.metadata()
    conv = {k: (json.dumps(v, indent=1) if isinstance(v, dict) else v)
            for k, v in meta["conventions"].items()}
    return {
        "Fs": float(exp.fs),
        "steps": {k: _column(v) for k, v in exp.step_table().items()},
        "harmonics": {"Z": z, "amplitude": np.abs(z), "phase_deg": np.degrees(np.angle(z)),
                      "channels": _cellstr([c.name for c in ai]),
                      "columns": _cellstr([c.column for c in ai]),
                      "units": _cellstr([c.units for c in ai]),
                      "convention": meta["conventions"]["harmonics"]["phase_reference"]},
        "drive_1x": {"Z": d, "channels": _cellstr([c.name for c in ao]),
                     "units": _cellstr(["V"] * len(ao))},
        "channels": {k: _column(v) for k, v in exp.channel_table().items()},
        "events": {k: _column(v) for k, v in exp.event_table().items()},
        "conditions": cond,
        "conventions": conv,
        "sfdrig_export": json.dumps(meta),
    }


def write_mat(exp: ExportSet, out_dir: Path, progress: Progress | None = None,
              overwrite: bool = False, v5_max_bytes: int = V5_MAX_BYTES) -> list[Path]:
    """Write ``exp`` as ``<stem>.mat`` (v5, or v7.3 past ``v5_max_bytes`` of samples)."""
    name = exp.stem + ".mat"
    n_cols = 3 + len(exp.columns)
    v73 = exp.n_samples * n_cols * 8 > v5_max_bytes
    with AtomicFiles(out_dir, [name], overwrite) as files:
        tables = _tables(exp)
        fmt = "MAT v7.3 (HDF5)" if v73 else "MAT v5"
        tables["README"] = README.format(run_id=exp.run.run_id, exported_at=exp.exported_at,
                                         fmt=fmt)
        if v73:
            _write_v73(files.tmp(name), exp, tables, progress)
        else:
            import scipy.io

            columns = {k: np.empty((exp.n_samples, 1)) for k in
                       ["time_s", "step", "freq_hz"] + [c.column for c in exp.columns]}
            for offset, block in exp.blocks(progress=progress):
                for k, v in block.items():
                    columns[k][offset:offset + len(v), 0] = v
            scipy.io.savemat(files.tmp(name), {**columns, **tables}, do_compression=False,
                             oned_as="column", long_field_names=True)
    return files.paths


# --- v7.3: HDF5 with MATLAB's conventions --------------------------------------------------------
def _mat_header() -> bytes:
    text = (f"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: "
            f"{datetime.now(UTC):%a %b %d %H:%M:%S %Y} HDF5 schema 1.00 .").encode("ascii")
    return text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"


def _cls(obj: h5py.HLObject, name: str) -> None:
    obj.attrs["MATLAB_class"] = np.bytes_(name)


def _put(g: h5py.Group, key: str, value: Any) -> None:
    """One MATLAB value under ``g``: numbers, logicals, complex arrays, text, lists of text (a
    char matrix), structs (dicts). MATLAB arrays are column-major: stored transposed."""
    if isinstance(value, dict):
        sub = g.create_group(key)
        _cls(sub, "struct")
        sub.attrs["MATLAB_fields"] = np.array(
            [np.frombuffer(k.encode(), dtype="S1") for k in value],
            dtype=h5py.vlen_dtype(np.dtype("S1")))
        for k, v in value.items():
            _put(sub, k, v)
        return
    if isinstance(value, str):
        value = np.array([value], dtype=object)
    arr = np.asarray(value)
    if arr.dtype == object:  # text: a char matrix, one row per entry
        texts = [str(v) for v in arr.ravel()]
        width = max((len(t) for t in texts), default=0)
        if not texts or width == 0:
            ds = g.create_dataset(key, data=np.array([0, 0], dtype=np.uint64))
            ds.attrs["MATLAB_empty"] = np.uint8(1)
            _cls(ds, "char")
            return
        codes = np.array([[ord(ch) if ord(ch) < 65536 else 63 for ch in t.ljust(width)]
                          for t in texts], dtype=np.uint16)
        ds = g.create_dataset(key, data=codes.T)
        _cls(ds, "char")
        ds.attrs["MATLAB_int_decode"] = np.int32(2)
        return
    if arr.ndim < 2:
        arr = arr.reshape(1, -1) if arr.ndim == 1 else arr.reshape(1, 1)
    if arr.dtype == bool:
        ds = g.create_dataset(key, data=arr.astype(np.uint8).T)
        _cls(ds, "logical")
        ds.attrs["MATLAB_int_decode"] = np.int32(1)
    elif np.iscomplexobj(arr):
        cplx = np.dtype([("real", "<f8"), ("imag", "<f8")])
        data = np.empty(arr.shape, dtype=cplx)
        data["real"], data["imag"] = arr.real, arr.imag
        _cls(g.create_dataset(key, data=data.T), "double")
    else:
        _cls(g.create_dataset(key, data=np.asarray(arr, dtype=np.float64).T), "double")


def _write_v73(path: Path, exp: ExportSet, tables: dict[str, Any],
               progress: Progress | None) -> None:
    n = exp.n_samples
    names = ["time_s", "step", "freq_hz"] + [c.column for c in exp.columns]
    with h5py.File(path, "w", userblock_size=512, libver=("earliest", "v110")) as f:
        dsets = {}
        for k in names:  # MATLAB n x 1 is stored as HDF5 (1, n)
            ds = f.create_dataset(k, shape=(1, n), dtype="<f8", chunks=(1, max(1, min(n, 1 << 16))),
                                  compression="gzip", compression_opts=1)
            _cls(ds, "double")
            dsets[k] = ds
        for offset, block in exp.blocks(progress=progress):
            for k, v in block.items():
                dsets[k][0, offset:offset + len(v)] = v
        for k, v in tables.items():
            _put(f, k, v)
    with open(path, "r+b") as fh:
        fh.write(_mat_header())
