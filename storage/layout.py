"""What a run file holds, and how it is laid out (``format="sfdrig-run"``, ``format_version=1``)::

    /                 root attrs: run_id, kind, start/stop time, operator, notes, software_version,
                      sample_rate_hz, channel_map, rig_config, test_spec (JSON), lubricated,
                      status, status_reason
    /channels/<ai>    float64 1-D, engineering units; attrs units, kind, sensor, gain_v_per_unit,
                      offset_v, physical_channel
    /drive/<ao>       float64 1-D, drive volts written, same time base
    /steps            compound, one row per dwell
    /step_harmonics   complex128 (n_steps, n_ai, 5), attr ``channels`` (JSON list)
    /step_drive_v     complex128 (n_steps, n_ao), attr ``channels`` (JSON list)
    /events           compound (time, sample, kind, message)
    /results          empty group, for analysis only

The writer (`storage.runfile`) and the reader (`storage.reader`) share these definitions; this
module creates the empty layout and turns a step or an event into its rows. Strings are
fixed-length UTF-8: variable-length data lives in the global heap, which SWMR readers cannot
follow safely while the file grows.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from typing import Any

import h5py
import numpy as np

FORMAT = "sfdrig-run"
#: HDF5 file-format bounds: the 1.10 format is the oldest that supports SWMR, and capping it
#: there keeps run files readable by HDF5 1.10-1.14 tools (HDFView, MATLAB, h5dump) even when
#: h5py is built on a newer library.
LIBVER = ("v110", "v110")
FORMAT_VERSION = 1
KINDS = ("sweep", "static", "impact", "probe_calibration", "flow", "imported")
STATUSES = ("running", "completed", "aborted", "failed")
EVENT_KINDS = ("state", "limit_trip", "abort", "fault", "pump", "operator", "warning", "error",
               "info")
N_HARMONICS = 5
STEP_KEYS = (
    "index", "freq_hz", "target_kind", "target_value", "motion", "first_sample", "last_sample",
    "updates", "converged", "reason",
)
CHANNEL_ATTRS = ("units", "kind", "sensor", "gain_v_per_unit", "offset_v", "physical_channel")

_REASON_BYTES = 512
_EXTRA_BYTES = 4096
_MESSAGE_BYTES = 1024
STEP_DTYPE = np.dtype([
    ("index", "<i8"),
    ("freq_hz", "<f8"),
    ("target_kind", h5py.string_dtype("utf-8", 16)),
    ("target_value", "<f8"),
    ("motion", h5py.string_dtype("utf-8", 24)),
    ("first_sample", "<i8"),
    ("last_sample", "<i8"),
    ("updates", "<i8"),
    ("converged", "?"),
    ("reason", h5py.string_dtype("utf-8", _REASON_BYTES)),
    ("extra", h5py.string_dtype("utf-8", _EXTRA_BYTES)),  # JSON of keys beyond contract A
])
EVENT_DTYPE = np.dtype([
    ("time", h5py.string_dtype("utf-8", 32)),
    ("sample", "<i8"),
    ("kind", h5py.string_dtype("utf-8", 16)),
    ("message", h5py.string_dtype("utf-8", _MESSAGE_BYTES)),
])


def utc_now_iso() -> str:
    """Current UTC time, ISO 8601 with milliseconds (e.g. ``2026-01-02T03:04:05.678+00:00``)."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def installed_software_version() -> str:
    """Installed sfdrig version (read from package metadata, not by importing sfdrig)."""
    try:
        return f"sfdrig {metadata.version('sfdrig')}"
    except metadata.PackageNotFoundError:
        return "sfdrig (unknown version)"


def hdf5_text(text: Any) -> str:
    """``text`` as a string HDF5 stores whole, whatever it holds: a NUL (which ends an HDF5
    string, and which h5py refuses in variable-length ones) is written as the two characters
    ``\\0``; a lone UTF-16 surrogate (not encodable as UTF-8) as its escape, e.g. ``\\ud800``."""
    return (str(text).replace("\x00", "\\0")
            .encode("utf-8", errors="backslashreplace").decode("utf-8"))


def fit_utf8(text: str, n_bytes: int) -> bytes:
    """UTF-8 bytes of `hdf5_text` (``text``) cut to at most ``n_bytes`` on a character
    boundary."""
    raw = hdf5_text(text).encode("utf-8")
    if len(raw) <= n_bytes:
        return raw
    marker = b" [truncated]"
    return raw[: n_bytes - len(marker)].decode("utf-8", errors="ignore").encode() + marker


def json_attr(value: Any, what: str) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        if value:
            try:
                json.loads(value)
            except json.JSONDecodeError as err:
                raise ValueError(f"{what} is a string but not valid JSON: {err}") from None
        return value
    if hasattr(value, "model_dump"):  # a pydantic model, without importing pydantic here
        value = value.model_dump(mode="json")
    try:
        return json.dumps(value, sort_keys=True)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{what} cannot be written as JSON: {err}") from None


def check_name(name: Any, what: str) -> str:
    if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
        raise ValueError(f"{what}: invalid name {name!r} (non-empty, no '/')")
    return name


def default_chunk_samples(sample_rate_hz: float) -> int:
    """About 1/8 s of samples per chunk, a power of two in [4096, 16384] (32-128 kB of
    float64): a completed chunk is compressed inside `RunWriter.on_block`, so small chunks
    spread that work evenly over the blocks instead of stalling one block in every second."""
    n = 2 ** round(math.log2(max(sample_rate_hz / 8.0, 1.0)))
    return int(min(max(n, 4096), 16384))



@dataclass
class RunDatasets:
    """The datasets a run grows: one per channel and drive (in that order), and the tables."""

    samples: list[h5py.Dataset]
    steps: h5py.Dataset
    harmonics: h5py.Dataset
    drive_v: h5py.Dataset
    events: h5py.Dataset


def create_layout(f: h5py.File, chans: Sequence[Mapping[str, Any]], ao_names: Sequence[str],
                  chunk_samples: int, compression: str, attrs: Mapping[str, Any]) -> RunDatasets:
    """Create every group, dataset and attribute of an empty run in ``f`` (SWMR allows no new
    object later)."""
    for key, value in attrs.items():
        f.attrs[key] = value
    opts: dict[str, Any] = {"compression": compression, "shuffle": True}
    if compression == "gzip":
        # Whole chunks are written directly: no chunk cache that could hold a stale copy
        # of a chunk partly written at a flush.
        opts.update(compression_opts=1, rdcc_nbytes=0)
    samples: list[h5py.Dataset] = []
    g = f.create_group("channels")
    for meta in chans:
        ds = g.create_dataset(
            meta["name"], shape=(0,), maxshape=(None,), dtype="<f8",
            chunks=(chunk_samples,), **opts,
        )
        for key in CHANNEL_ATTRS:
            value = meta.get(key)
            if key in ("gain_v_per_unit", "offset_v"):
                ds.attrs[key] = float("nan") if value is None else float(value)
            else:
                ds.attrs[key] = "" if value is None else str(value)
        samples.append(ds)
    g = f.create_group("drive")
    for name in ao_names:
        ds = g.create_dataset(
            name, shape=(0,), maxshape=(None,), dtype="<f8", chunks=(chunk_samples,), **opts,
        )
        ds.attrs["units"] = "V"
        ds.attrs["kind"] = "shaker_drive"
        samples.append(ds)
    ai_names = [c["name"] for c in chans]
    n_ai, n_ao = len(ai_names), len(ao_names)
    steps = f.create_dataset(
        "steps", shape=(0,), maxshape=(None,), dtype=STEP_DTYPE, chunks=(64,),
        compression="gzip", compression_opts=4,
    )
    harm = f.create_dataset(
        "step_harmonics", shape=(0, n_ai, N_HARMONICS), maxshape=(None, n_ai, N_HARMONICS),
        dtype="<c16", chunks=(16, n_ai, N_HARMONICS),
    )
    harm.attrs["channels"] = json.dumps(ai_names)
    harm.attrs["harmonics"] = "1X..5X, complex amplitude Z = z_c - i z_s"
    if n_ao:
        drive_v = f.create_dataset(
            "step_drive_v", shape=(0, n_ao), maxshape=(None, n_ao), dtype="<c16",
            chunks=(64, n_ao),
        )
    else:  # chunk dimensions must be positive: an empty fixed dataset
        drive_v = f.create_dataset("step_drive_v", shape=(0, 0), dtype="<c16")
    drive_v.attrs["channels"] = json.dumps(list(ao_names))
    events = f.create_dataset(
        "events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(64,),
        compression="gzip", compression_opts=4,
    )
    f.create_group("results")
    return RunDatasets(samples, steps, harm, drive_v, events)


def step_rows(step: Mapping[str, Any], index: int, ai_names: Sequence[str],
              ao_names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One dwell's result (contract A step dict) as its rows of ``/steps``,
    ``/step_harmonics`` and ``/step_drive_v``; keys beyond contract A go to ``extra`` (JSON).
    ``index`` is used when the step has none. Raises ValueError on a malformed dict."""
    row = np.zeros((), dtype=STEP_DTYPE)
    harm = np.full((len(ai_names), N_HARMONICS), np.nan + 1j * np.nan)
    drive = np.full(len(ao_names), np.nan + 1j * np.nan)
    extra: dict[str, Any] = {k: v for k, v in step.items()
                             if k not in STEP_KEYS and k not in ("harmonics", "drive_v")}
    try:
        row["index"] = int(step.get("index", index))
        row["freq_hz"] = _float(step.get("freq_hz"))
        row["target_kind"] = fit_utf8(step.get("target_kind") or "", 16)
        row["target_value"] = _float(step.get("target_value"))
        row["motion"] = fit_utf8(step.get("motion") or "", 24)
        row["first_sample"] = int(step.get("first_sample", -1))
        row["last_sample"] = int(step.get("last_sample", -1))
        row["updates"] = int(step.get("updates", 0))
        row["converged"] = bool(step.get("converged", False))
        row["reason"] = fit_utf8(step.get("reason") or "", _REASON_BYTES)
        unknown: dict[str, Any] = {}
        for name, values in (step.get("harmonics") or {}).items():
            if name not in ai_names:
                unknown[name] = values
                continue
            for k, reim in enumerate(list(values)[:N_HARMONICS]):
                harm[list(ai_names).index(name), k] = complex(reim[0], reim[1])
        if unknown:
            extra["harmonics"] = unknown
        for name, reim in (step.get("drive_v") or {}).items():
            if name in ao_names:
                drive[list(ao_names).index(name)] = complex(reim[0], reim[1])
            else:
                extra.setdefault("drive_v", {})[name] = reim
    except (TypeError, ValueError, IndexError) as err:
        raise ValueError(f"malformed step dict: {err}") from None
    text = json.dumps(extra, default=_jsonable) if extra else ""
    if len(text.encode()) > _EXTRA_BYTES:
        text = json.dumps({"_dropped": f"extra keys too long ({len(text)} chars)"})
    row["extra"] = text.encode()
    return row, harm, drive


def event_row(kind: str, message: str, sample: int) -> np.ndarray:
    """One event as its row of ``/events``, stamped with the time now."""
    row = np.zeros((), dtype=EVENT_DTYPE)
    row["time"] = utc_now_iso().encode()
    row["sample"] = int(sample)
    row["kind"] = fit_utf8(kind, 16)
    row["message"] = fit_utf8(message, _MESSAGE_BYTES)
    return row


def _jsonable(value: Any) -> Any:
    """numpy scalars and arrays as plain JSON values; anything else as its text."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return str(value)


def _float(value: Any) -> float:
    return float("nan") if value is None else float(value)
