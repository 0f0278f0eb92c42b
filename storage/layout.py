"""What a run file holds, and how it is laid out (``format="sfdrig-run"``, ``format_version=2``)::

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

Version 2 adds only descriptions, no data: the root's ``layout`` and ``time_axis``, the time-axis
recipe on every signal (``time_start``, ``time_increment``, ``time_units``), and units and
conventions on every table column (``<column>_units``, ``<column>_description``). A version 1
file holds the same data and reads the same. Every description is defined here once
(`LAYOUT_TEXT`, `STEP_COLUMNS`, `HARMONICS_ATTRS`...) and also used by the exporters;
``docs/run-files.md`` is the guide for readers without our code.

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

from storage.records import EVENT_KINDS, STATUSES, STEP_KEYS, EventRecord, StepRecord

__all__ = ["EVENT_KINDS", "STATUSES", "STEP_KEYS"]  # said in storage.records, laid out here

FORMAT = "sfdrig-run"
#: HDF5 file-format bounds: the 1.10 format is the oldest that supports SWMR, and capping it
#: there keeps run files readable by HDF5 1.10-1.14 tools (HDFView, MATLAB, h5dump) even when
#: h5py is built on a newer library.
LIBVER = ("v110", "v110")
#: 2: descriptions added (layout, time-axis recipe, column units and conventions); data as in 1.
FORMAT_VERSION = 2
KINDS = ("sweep", "static", "impact", "probe_calibration", "flow", "imported", "commissioning")
N_HARMONICS = 5
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


#: The root attribute ``layout``: what each object holds, for a reader without our code.
LAYOUT_TEXT = """\
sfdrig run file (format sfdrig-run, see format_version). One run of the squeeze-film-damper rig.
Root attributes: the run (run_id, kind, start_time/stop_time ISO 8601 UTC, status, status_reason,
operator, notes), its conditions (lubricated: the film was full of oil for the whole run; the
daemon refuses to switch the pump on during a dry run), sample_rate_hz, and JSON texts
channel_map (the wiring), rig_config (the rig description) and test_spec (what was asked).
/channels/<name>: analog inputs, float64, engineering units (attribute units), one value per
  sample; attributes kind, sensor, gain_v_per_unit, offset_v, physical_channel.
/drive/<name>: the shaker drive volts written, same samples.
  Time of sample k of every signal: time_start + k * time_increment [s] (attributes on each
  signal), i.e. k / sample_rate_hz seconds after start_time. All signals are simultaneous.
/steps: one row per step (a dwell of a sweep, or one point of a static, impact, probe-calibration
  or flow test); units and meaning of each column in the attributes <column>_units and
  <column>_description. Samples first_sample .. last_sample-1 are the step's record.
/step_harmonics: complex (step, channel, harmonic 1..5), channel order in attribute channels,
  units in attribute units; peak amplitude |Z|, phase from run time 0 (see its attributes).
/step_drive_v: complex (step, drive), the 1X of every drive [V], same convention.
/events: time (ISO 8601 UTC), sample, kind, message of every state change, trip, abort, operator
  entry and fault.
/results: written by the analysis (sfdrig identify), absent or empty otherwise."""

#: The root attribute ``time_axis``.
TIME_AXIS_TEXT = ("t[k] = k / sample_rate_hz seconds after start_time (sample k = 0, 1, ...); "
                  "each signal carries it as time_start [s] + k * time_increment [s]")

#: The step fields' meaning in each kind of test (the attribute ``step_fields_by_kind``).
STEP_FIELDS_BY_KIND = {
    "sweep": "one dwell at freq_hz; target_kind displacement (target_value the amplitude asked "
             "[m], 0-peak) or load (the load amplitude asked [N], 0-peak); motion x, y, "
             "circular_forward, circular_backward or elliptical",
    "static": "one static load: freq_hz 0 (no excitation), target_kind load, target_value the "
              "force asked [N], motion the axis; the analysis uses the means over the record",
    "impact": "one hammer hit: freq_hz 0 (no excitation), target_kind load, target_value the "
              "hammer's peak force measured [N], motion the axis; extra holds trigger_sample, "
              "accepted, rejection, hit, pulse_ms",
    "probe_calibration": "one gauge reading: freq_hz 0, target_kind displacement, target_value "
                         "the dial-gauge reading typed [m], motion the axis",
    "flow": "one supply pressure: freq_hz 0, target_kind pressure, target_value the supply "
            "pressure set [Pa], no motion",
    "commissioning": "one stage of `sfdrig commission` (extra: stage): the rest (freq_hz 0, "
                     "no target) and each shaker's small drive (freq_hz the test frequency, "
                     "target_kind load, target_value the force asked [N], motion the axis, "
                     "harmonics the 1X over the record); the findings are events",
    "imported": "one dwell found in imported data: freq_hz the dwell's frequency, target_kind "
                "empty and target_value NaN (nothing was asked), motion given or inferred "
                "(test_spec.conditions.motion_per_step says which)",
}
#: Units of ``target_value`` by ``target_kind``.
TARGET_UNITS = {"displacement": "m", "load": "N", "pressure": "Pa", "": ""}

#: Units and meaning of every column of ``/steps``.
STEP_COLUMNS: dict[str, tuple[str, str]] = {
    "index": ("", "step number, 0-based, in the order run"),
    "freq_hz": ("Hz", "excitation frequency of the step; 0 for a step without excitation "
                      "(static, impact, probe calibration, flow: see step_fields_by_kind)"),
    "target_kind": ("", "what target_value is: displacement, load, pressure (empty: none)"),
    "target_value": ("m, N or Pa by target_kind", "what the step asked: m for displacement "
                     "(0-peak amplitude), N for load (0-peak amplitude, or a static force, or an "
                     "impact's measured peak), Pa for pressure; NaN when nothing was asked"),
    "motion": ("", "x, y, circular_forward, circular_backward, elliptical (the axis for the "
                   "structure tests; empty for flow)"),
    "first_sample": ("sample", "first sample of the step's record (run sample index, 0-based)"),
    "last_sample": ("sample", "one past the last sample of the record (half-open span)"),
    "updates": ("", "corrections the amplitude controller made in this step"),
    "converged": ("", "the target was reached within the tolerance (always true for imported "
                      "dwells and the structure tests' points)"),
    "reason": ("", "why the step did not converge or ended (empty when it converged)"),
    "extra": ("", "JSON of the step's further keys (e.g. an impact hit's accepted, rejection)"),
}
#: Attributes of ``/step_harmonics`` (besides ``channels`` and ``units``).
HARMONICS_ATTRS = {
    "harmonics": "1X..5X, complex amplitude Z = z_c - i z_s",
    "dimensions": "(step, channel, harmonic): harmonic index 0..4 is 1X..5X of the step's "
                  "freq_hz; channel order in the attribute channels",
    "amplitude_convention": "peak (0-peak, not RMS, not peak-to-peak): |Z| in the channel's "
                            "units",
    "phase_reference": "z(t) = Re(Z exp(i h 2 pi freq_hz t)) with t = sample / sample_rate_hz, "
                       "counted from sample 0 of the run (not from the step's first sample); "
                       "angle(Z) is the phase in radians, z_c = Re Z, z_s = -Im Z",
    "fit": "least squares of a constant plus 1X..5X over the step's samples first_sample .. "
           "last_sample-1 (whole cycles); NaN where the step has no harmonics (freq_hz 0, "
           "imported dwells)",
}
#: Attributes of ``/step_drive_v``.
DRIVE_V_ATTRS = {
    "dimensions": "(step, drive): the 1X of every drive over the step's record; drive order in "
                  "the attribute channels",
    "units": "V",
    "amplitude_convention": HARMONICS_ATTRS["amplitude_convention"],
    "phase_reference": HARMONICS_ATTRS["phase_reference"],
}
#: Units and meaning of every column of ``/events``.
EVENT_COLUMNS: dict[str, tuple[str, str]] = {
    "time": ("ISO 8601 UTC", "when the event was logged"),
    "sample": ("sample", "run sample index at the event (time: sample / sample_rate_hz s)"),
    "kind": ("", "one of " + ", ".join(EVENT_KINDS)),
    "message": ("", "what happened, in words"),
}


def describe_columns(ds: h5py.Dataset, columns: Mapping[str, tuple[str, str]]) -> None:
    """Attributes ``<column>_units`` and ``<column>_description`` for every column."""
    for name, (units, text) in columns.items():
        ds.attrs[f"{name}_units"] = units
        ds.attrs[f"{name}_description"] = text


def time_axis_attrs(sample_rate_hz: float) -> dict[str, Any]:
    """The time-axis recipe of a signal: t[k] = time_start + k * time_increment [s]."""
    return {"time_start": 0.0, "time_increment": 1.0 / float(sample_rate_hz),
            "time_units": "s", "time_reference": "root attribute start_time (UTC)"}


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
    f.attrs["layout"] = LAYOUT_TEXT
    f.attrs["time_axis"] = TIME_AXIS_TEXT
    time_axis = time_axis_attrs(float(attrs["sample_rate_hz"]))
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
        ds.attrs.update(time_axis)
        samples.append(ds)
    g = f.create_group("drive")
    for name in ao_names:
        ds = g.create_dataset(
            name, shape=(0,), maxshape=(None,), dtype="<f8", chunks=(chunk_samples,), **opts,
        )
        ds.attrs["units"] = "V"
        ds.attrs["kind"] = "shaker_drive"
        ds.attrs.update(time_axis)
        samples.append(ds)
    ai_names = [c["name"] for c in chans]
    n_ai, n_ao = len(ai_names), len(ao_names)
    steps = f.create_dataset(
        "steps", shape=(0,), maxshape=(None,), dtype=STEP_DTYPE, chunks=(64,),
        compression="gzip", compression_opts=4,
    )
    describe_columns(steps, STEP_COLUMNS)
    steps.attrs["step_fields_by_kind"] = json.dumps(STEP_FIELDS_BY_KIND, indent=1)
    steps.attrs["target_value_units_by_target_kind"] = json.dumps(
        {k: v for k, v in TARGET_UNITS.items() if k})
    harm = f.create_dataset(
        "step_harmonics", shape=(0, n_ai, N_HARMONICS), maxshape=(None, n_ai, N_HARMONICS),
        dtype="<c16", chunks=(16, n_ai, N_HARMONICS),
    )
    harm.attrs["channels"] = json.dumps(ai_names)
    harm.attrs.update(HARMONICS_ATTRS)
    harm.attrs["units"] = json.dumps([str(c.get("units") or "") for c in chans])
    if n_ao:
        drive_v = f.create_dataset(
            "step_drive_v", shape=(0, n_ao), maxshape=(None, n_ao), dtype="<c16",
            chunks=(64, n_ao),
        )
    else:  # chunk dimensions must be positive: an empty fixed dataset
        drive_v = f.create_dataset("step_drive_v", shape=(0, 0), dtype="<c16")
    drive_v.attrs["channels"] = json.dumps(list(ao_names))
    drive_v.attrs.update(DRIVE_V_ATTRS)
    events = f.create_dataset(
        "events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(64,),
        compression="gzip", compression_opts=4,
    )
    describe_columns(events, EVENT_COLUMNS)
    results = f.create_group("results")
    results.attrs["description"] = "written by the analysis (sfdrig identify) only"
    return RunDatasets(samples, steps, harm, drive_v, events)


def step_rows(step: StepRecord, ai_names: Sequence[str],
              ao_names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step as its rows of ``/steps``, ``/step_harmonics`` and ``/step_drive_v``: the
    record's further keys, and harmonics or drives of names the file does not have, go to
    ``extra`` (JSON). Raises ValueError on a value the columns cannot hold."""
    row = np.zeros((), dtype=STEP_DTYPE)
    harm = np.full((len(ai_names), N_HARMONICS), np.nan + 1j * np.nan)
    drive = np.full(len(ao_names), np.nan + 1j * np.nan)
    extra: dict[str, Any] = dict(step.extra)
    try:
        row["index"] = int(step.index)
        row["freq_hz"] = float(step.freq_hz)
        row["target_kind"] = fit_utf8(step.target_kind, 16)
        row["target_value"] = float(step.target_value)
        row["motion"] = fit_utf8(step.motion, 24)
        row["first_sample"] = int(step.first_sample)
        row["last_sample"] = int(step.last_sample)
        row["updates"] = int(step.updates)
        row["converged"] = bool(step.converged)
        row["reason"] = fit_utf8(step.reason, _REASON_BYTES)
    except (TypeError, ValueError, OverflowError) as err:
        raise ValueError(f"malformed step {step.index!r}: {err}") from None
    ai_index = {name: i for i, name in enumerate(ai_names)}
    ao_index = {name: i for i, name in enumerate(ao_names)}
    unknown: dict[str, Any] = {}
    for name, zs in step.harmonics.items():
        if name not in ai_index:
            unknown[name] = [[z.real, z.imag] for z in zs]
            continue
        for k, z in enumerate(list(zs)[:N_HARMONICS]):
            harm[ai_index[name], k] = z
    if unknown:
        extra["harmonics"] = unknown
    for name, z in step.drive_v.items():
        if name in ao_index:
            drive[ao_index[name]] = z
        else:
            extra.setdefault("drive_v", {})[name] = [z.real, z.imag]
    text = json.dumps(extra, default=_jsonable) if extra else ""
    if len(text.encode()) > _EXTRA_BYTES:
        text = json.dumps({"_dropped": f"extra keys too long ({len(text)} chars)"})
    row["extra"] = text.encode()
    return row, harm, drive


def step_of_rows(row: np.void, harm: np.ndarray, drive: np.ndarray, ai_names: Sequence[str],
                 ao_names: Sequence[str]) -> StepRecord:
    """The step a row of ``/steps`` and its ``/step_harmonics`` and ``/step_drive_v`` rows hold
    (the inverse of `step_rows`): a channel's harmonics where they are not NaN, ``extra`` merged
    back (an ``extra`` that is not JSON is kept as its text under ``extra``)."""
    harmonics: dict[str, tuple[complex, ...]] = {}
    for c, name in enumerate(ai_names):
        h = harm[c, :N_HARMONICS]
        if not np.all(np.isnan(h.real)):
            harmonics[name] = tuple(complex(z) for z in h)
    drive_v = {name: complex(drive[c]) for c, name in enumerate(ao_names)
               if not np.isnan(drive[c].real)}
    names = row.dtype.names or ()
    extra_text = text_of(row["extra"]) if "extra" in names else ""
    extra: dict[str, Any] = {}
    if extra_text:
        try:
            extra = json.loads(extra_text)
        except json.JSONDecodeError:
            extra = {"extra": extra_text}
        beyond = {"harmonics": extra.pop("harmonics", {}), "drive_v": extra.pop("drive_v", {})}
        try:
            more = StepRecord.from_wire(beyond)
        except ValueError:  # not [re, im] pairs: kept as they are
            extra.update(beyond)
        else:
            harmonics.update(more.harmonics)
            drive_v.update(more.drive_v)
    return StepRecord(
        index=int(row["index"]), freq_hz=float(row["freq_hz"]),
        target_kind=text_of(row["target_kind"]), target_value=float(row["target_value"]),
        motion=text_of(row["motion"]), first_sample=int(row["first_sample"]),
        last_sample=int(row["last_sample"]), updates=int(row["updates"]),
        converged=bool(row["converged"]), reason=text_of(row["reason"]),
        harmonics=harmonics, drive_v=drive_v, extra=extra)


def text_of(value: Any) -> str:
    """A fixed-length string cell (or a string attribute) as text."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray) and value.shape == ():
        return text_of(value[()])
    return str(value)


def event_row(event: EventRecord) -> np.ndarray:
    """One event as its row of ``/events``, stamped with the time now."""
    row = np.zeros((), dtype=EVENT_DTYPE)
    row["time"] = utc_now_iso().encode()
    row["sample"] = int(event.sample)
    row["kind"] = fit_utf8(event.kind, 16)
    row["message"] = fit_utf8(event.message, _MESSAGE_BYTES)
    return row


def _jsonable(value: Any) -> Any:
    """numpy scalars and arrays as plain JSON values; anything else as its text."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return str(value)

