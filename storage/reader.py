"""Run-file reader (contract B): `open_run(path) -> RunData`.

Opens finished runs, runs still being written (SWMR readers: call `RunData.refresh` to see new
samples) and runs whose writer died (everything up to the writer's last flush). A file that is not
an sfdrig run, or is broken, raises `RunFileError` naming the file and the fault.
"""

from __future__ import annotations

import json
import re
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from storage.errors import MissingSignalError, RunFileError
from storage.layout import FORMAT, FORMAT_VERSION, STEP_KEYS, step_of_rows, text_of
from storage.records import StepRecord

#: Canonical signals and where they come from.
CANONICAL_SIGNALS = ("fx", "fy", "x", "y", "ax", "ay", "t_oil")
_REQUIRED_ATTRS = ("format", "format_version", "run_id", "kind", "sample_rate_hz")
# What h5py raises on damaged files (RuntimeError for e.g. a bad global heap).
_H5_ERRORS = (OSError, KeyError, ValueError, TypeError, RuntimeError)
_REQUIRED_OBJECTS = ("channels", "drive", "steps", "step_harmonics", "step_drive_v", "events")


_text = text_of


_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _superblock_problem(path: Path) -> str:
    """Why the file cannot hold what its superblock says ("" when it can, or cannot tell).

    HDF5 skips its own truncation check when opening for SWMR reading (a live writer may be
    extending the file) and then retries unreadable metadata for a very long time, so a truncated
    file left by a dead writer would hang the reader. The version 2/3 superblock records the end
    of the file: a shorter file is truncated.
    """
    size = path.stat().st_size
    with open(path, "rb") as f:
        offset = 0
        while offset + 48 <= size:  # the superblock sits at 0, 512, 1024, 2048... (user block)
            f.seek(offset)
            head = f.read(48)
            if head[:8] == _SIGNATURE:
                break
            offset = 512 if offset == 0 else offset * 2
        else:
            return ""
    version, n_off = head[8], head[9]
    if version < 2 or n_off not in (4, 8):
        return ""
    fmt = "<I" if n_off == 4 else "<Q"
    base = struct.unpack_from(fmt, head, 12)[0]
    stored_eof = struct.unpack_from(fmt, head, 12 + 2 * n_off)[0]
    if size < base + stored_eof:
        return (f"truncated: {size} bytes where the HDF5 superblock records {base + stored_eof} "
                "(or the file is still being created)")
    return ""


def _open_h5(path: Path) -> h5py.File:
    """Open read-only: plainly when the file was closed properly, else as a SWMR reader (a live
    writer, or one that died, leaves the file marked open for writing and a plain open refuses)."""
    if not path.exists():
        raise RunFileError(f"{path}: no such file")
    if path.is_dir():
        raise RunFileError(f"{path}: is a directory, not a run file")
    if not h5py.is_hdf5(path):
        raise RunFileError(f"{path}: not an HDF5 file (no HDF5 signature; truncated or another "
                           "format)")
    try:
        return h5py.File(path, "r")
    except OSError as err:
        message = str(err)
        if "already open for write" not in message:
            raise RunFileError(f"{path}: cannot open as HDF5 (truncated or damaged?): "
                               f"{message}") from None
    problem = _superblock_problem(path)
    if problem:
        raise RunFileError(f"{path}: {problem}")
    try:
        return h5py.File(path, "r", swmr=True)
    except OSError as err:
        raise RunFileError(f"{path}: cannot open as HDF5 (truncated or damaged?): {err}") from None


class RunData:
    """One run file, open for reading. Use as a context manager or call `close`.

    Attributes
    ----------
    path : Path
    attrs : dict
        Root attributes (strings decoded; JSON attributes left as text, parsed ones are below).
    channel_names : list of str
        Analog-input channels in channel-map order.
    drive_names : list of str
        Shaker drives (``/drive``).
    sample_rate_hz : float
    kind : str
    channel_map, rig_config, test_spec : dict or None
        Parsed JSON attributes (None when empty).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._steps_cache: list[StepRecord] | None = None
        # the datasets' lengths change only at a refresh (SWMR): asked once per channel read,
        # they were a sixth of a transfer-function request's time in `sfdrig web` (issue 25)
        self._n_samples_cache: int | None = None
        self._file = _open_h5(self.path)
        try:
            self._load()
        except RunFileError:
            self._file.close()
            raise
        except _H5_ERRORS as err:
            self._file.close()
            raise RunFileError(f"{self.path}: damaged run file (truncated?): {err}") from None

    # --- loading and validation -------------------------------------------------------------
    def _fail(self, what: str) -> RunFileError:
        return RunFileError(f"{self.path}: {what}")

    def _load(self) -> None:
        f = self._file
        attrs = {k: f.attrs[k] for k in f.attrs}
        if "format" not in attrs:
            raise self._fail("not an sfdrig run file (no 'format' attribute)")
        fmt = _text(attrs["format"])
        if fmt != FORMAT:
            raise self._fail(f"format attribute is {fmt!r}, expected {FORMAT!r}")
        missing = [a for a in _REQUIRED_ATTRS if a not in attrs]
        if missing:
            raise self._fail(f"missing root attribute(s) {missing}")
        version = int(attrs["format_version"])
        if version > FORMAT_VERSION:
            raise self._fail(f"format_version {version} is newer than this reader "
                             f"({FORMAT_VERSION}); update sfdrig")
        self.attrs: dict[str, Any] = {}
        for k, v in attrs.items():
            if isinstance(v, bytes | str):
                self.attrs[k] = _text(v)
            elif isinstance(v, np.generic):
                self.attrs[k] = v.item()
            else:
                self.attrs[k] = v
        missing = [o for o in _REQUIRED_OBJECTS if o not in f]
        if missing:
            raise self._fail(f"missing {', '.join('/' + m for m in missing)}")
        self.sample_rate_hz = float(self.attrs["sample_rate_hz"])
        if not self.sample_rate_hz > 0:
            raise self._fail(f"sample_rate_hz is {self.sample_rate_hz}, not positive")
        self.kind = str(self.attrs["kind"])
        self.run_id = str(self.attrs["run_id"])
        self.channel_map = self._json_attr("channel_map")
        self.rig_config = self._json_attr("rig_config")
        self.test_spec = self._json_attr("test_spec")
        harm_names = self._json_names("step_harmonics")
        drive_names = self._json_names("step_drive_v")
        # Channel order: the step_harmonics attr records the ai order the writer was given
        # (HDF5 groups list members alphabetically).
        in_file = set(f["channels"].keys())
        if set(harm_names) != in_file:
            raise self._fail(f"/channels holds {sorted(in_file)} but /step_harmonics names "
                             f"{harm_names}")
        self.channel_names: list[str] = harm_names
        if set(drive_names) != set(f["drive"].keys()):
            raise self._fail(f"/drive holds {sorted(f['drive'].keys())} but /step_drive_v "
                             f"names {drive_names}")
        self.drive_names: list[str] = drive_names
        for name in self.channel_names:
            self._check_series(f"channels/{name}")
        for name in self.drive_names:
            self._check_series(f"drive/{name}")

    def _json_attr(self, key: str) -> Any:
        text = self.attrs.get(key, "")
        if not text:
            return None
        try:
            return json.loads(text)
        except json.JSONDecodeError as err:
            raise self._fail(f"root attribute {key!r} is not valid JSON: {err}") from None

    def _json_names(self, dset: str) -> list[str]:
        raw = self._file[dset].attrs.get("channels")
        if raw is None:
            raise self._fail(f"/{dset} has no 'channels' attribute")
        try:
            names = json.loads(_text(raw))
        except json.JSONDecodeError as err:
            raise self._fail(f"/{dset} attribute 'channels' is not JSON: {err}") from None
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise self._fail(f"/{dset} attribute 'channels' is not a list of names")
        return names

    def _check_series(self, key: str) -> None:
        obj = self._file[key]
        if not isinstance(obj, h5py.Dataset) or obj.ndim != 1 or obj.dtype.kind != "f":
            raise self._fail(f"/{key} is not a 1-D float dataset")

    # --- live reading ------------------------------------------------------------------------
    def refresh(self) -> None:
        """See what a live SWMR writer has flushed since opening (no-op on closed files)."""
        self._steps_cache = None
        self._n_samples_cache = None
        if not self._file.swmr_mode:
            return
        keys = [f"channels/{n}" for n in self.channel_names]
        keys += [f"drive/{n}" for n in self.drive_names]
        keys += ["steps", "step_harmonics", "step_drive_v", "events"]
        try:
            for key in keys:
                self._file[key].refresh()
        except _H5_ERRORS as err:
            raise self._fail(f"cannot refresh /{key} from the writer: {err}") from None

    @property
    def n_samples(self) -> int:
        """Samples present in every channel and drive (a live or killed writer may have
        flushed some datasets further than others)."""
        if self._n_samples_cache is None:
            lengths = [self._file[f"channels/{n}"].shape[0] for n in self.channel_names]
            lengths += [self._file[f"drive/{n}"].shape[0] for n in self.drive_names]
            self._n_samples_cache = min(lengths) if lengths else 0
        return self._n_samples_cache

    @property
    def duration_s(self) -> float:
        """Recorded time span [s]: ``n_samples / sample_rate_hz``."""
        return self.n_samples / self.sample_rate_hz

    @property
    def status(self) -> str:
        return str(self.attrs.get("status", ""))

    @property
    def start_time(self) -> str:
        return str(self.attrs.get("start_time", ""))

    @property
    def stop_time(self) -> str:
        return str(self.attrs.get("stop_time", ""))

    # --- data ---------------------------------------------------------------------------------
    def channel(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Samples ``[start, stop)`` of analog input ``name`` (or a drive), engineering units.

        Returns
        -------
        ndarray, float64, shape (n,)
        """
        if name in self.channel_names:
            ds = self._file[f"channels/{name}"]
        elif name in self.drive_names:
            ds = self._file[f"drive/{name}"]
        else:
            raise MissingSignalError(
                f"{self.path}: no channel {name!r} (channels {self.channel_names}, drives "
                f"{self.drive_names})"
            )
        n = self.n_samples
        stop = n if stop is None else min(stop, n)
        start = min(max(start, 0), stop)
        try:
            return np.asarray(ds[start:stop], dtype=np.float64)
        except _H5_ERRORS as err:
            raise self._fail(f"cannot read /{ds.name.lstrip('/')}[{start}:{stop}]: {err}") from None

    def channel_attrs(self, name: str) -> dict[str, Any]:
        """The calibration and sensor attributes of one channel (units, kind, gain...)."""
        if name not in self.channel_names and name not in self.drive_names:
            raise MissingSignalError(f"{self.path}: no channel {name!r}")
        group = "channels" if name in self.channel_names else "drive"
        out: dict[str, Any] = {}
        for k, v in self._file[f"{group}/{name}"].attrs.items():
            out[k] = _text(v) if isinstance(v, bytes | str) else np.asarray(v).item()
        return out

    def units(self, name: str) -> str:
        return str(self.channel_attrs(name).get("units", ""))

    def signal(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """A canonical signal: "fx", "fy", "x", "y", "ax", "ay", "t_oil".

        "x" and "y" are the channel of that name (imported runs) or else the mean of the probes
        ``x1, x2, ...`` (``y1, y2, ...``) present in the run. Others are the channel itself.

        Returns
        -------
        ndarray, float64, shape (n,), engineering units (N, m, m/s^2, degC)
        """
        if name not in CANONICAL_SIGNALS:
            raise MissingSignalError(
                f"{self.path}: {name!r} is not a canonical signal {CANONICAL_SIGNALS}"
            )
        if name in self.channel_names:
            return self.channel(name, start, stop)
        if name in ("x", "y"):
            probes = [c for c in self.channel_names if re.fullmatch(rf"{name}\d+", c)]
            if probes:
                acc = self.channel(probes[0], start, stop)
                for p in probes[1:]:
                    acc = acc + self.channel(p, start, stop)
                return acc / len(probes)
            raise MissingSignalError(
                f"{self.path}: no signal {name!r}: neither a channel {name!r} nor probes "
                f"{name}1, {name}2 (channels {self.channel_names})"
            )
        raise MissingSignalError(
            f"{self.path}: no signal {name!r} (channels {self.channel_names})"
        )

    def has_signal(self, name: str) -> bool:
        """Whether `signal` can return ``name``."""
        if name in self.channel_names:
            return True
        return name in ("x", "y") and any(
            re.fullmatch(rf"{name}\d+", c) for c in self.channel_names
        )

    def time_s(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Sample times [s] of samples ``[start, stop)``: ``index / sample_rate_hz``."""
        n = self.n_samples
        stop = n if stop is None else min(stop, n)
        return np.arange(start, stop) / self.sample_rate_hz

    @property
    def steps(self) -> list[dict[str, Any]]:
        """One dict per step, as the wire carries it (`StepRecord.to_wire`: harmonics and
        drive_v included, the further keys beside the columns); a fresh list each time."""
        return [step.to_wire() for step in self.step_records]

    @property
    def step_records(self) -> list[StepRecord]:
        """One `StepRecord` per step. Read once and cached (until `refresh`)."""
        if self._steps_cache is None:
            try:
                self._steps_cache = self._read_steps()
            except RunFileError:
                raise
            except _H5_ERRORS as err:
                raise self._fail(f"cannot read /steps: {err}") from None
        return list(self._steps_cache)

    def _read_steps(self) -> list[StepRecord]:
        f = self._file
        rows = f["steps"][()]
        harm = f["step_harmonics"][()]
        drive = f["step_drive_v"][()]
        # A live writer may have flushed the table further than the arrays (or the reverse).
        n = min(len(rows), len(harm), len(drive) if self.drive_names else len(rows))
        missing = [k for k in STEP_KEYS if k not in (rows.dtype.names or ())]
        if missing:
            raise self._fail(f"/steps lacks field(s) {missing}")
        no_drive = np.zeros(0, dtype=complex)
        try:
            return [step_of_rows(rows[i], harm[i], drive[i] if self.drive_names else no_drive,
                                 self.channel_names, self.drive_names) for i in range(n)]
        except ValueError as err:
            raise self._fail(f"/steps: {err}") from None

    @property
    def events(self) -> list[dict[str, Any]]:
        """Event log: dicts with ``time`` (ISO 8601 UTC), ``sample``, ``kind``, ``message``."""
        try:
            rows = self._file["events"][()]
        except _H5_ERRORS as err:
            raise self._fail(f"cannot read /events: {err}") from None
        return [
            {"time": _text(r["time"]), "sample": int(r["sample"]), "kind": _text(r["kind"]),
             "message": _text(r["message"])}
            for r in rows
        ]

    @property
    def h5(self) -> h5py.File:
        """The open h5py file (read-only), for what this API does not cover."""
        return self._file

    def results_names(self) -> list[str]:
        """Names under ``/results`` (written by analysis)."""
        if "results" not in self._file:
            return []
        names: list[str] = []
        self._file["results"].visit(names.append)
        return names

    def iter_blocks(self, names: list[str], block: int = 1 << 20) -> Iterator[np.ndarray]:
        """Read channels ``names`` in blocks of ``block`` samples: arrays (len(names), n)."""
        n = self.n_samples
        for start in range(0, n, block):
            stop = min(start + block, n)
            yield np.stack([self.channel(c, start, stop) for c in names])

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> RunData:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"<RunData {self.run_id!r} {self.kind} {self.status} {self.path}, "
                f"{len(self.channel_names)} channels, {self.n_samples} samples>")


def open_run(path: str | Path) -> RunData:
    """Open a run file for reading (finished, being written, or left by a killed writer).

    Raises
    ------
    RunFileError
        When the file is missing, not HDF5, truncated, not an sfdrig run, or lacks a dataset;
        the message names the file and the fault.
    """
    return RunData(path)
