"""What every exporter shares: the selection (steps, channels), column names, the tables, the
run's conditions and the metadata (``sfdrig-export``) that lets `sfdrig import` restore the run.

Conventions (the same in CSV, MAT and TDMS; see ``docs/run-files.md``):

- a signal's column is the importer's canonical name where the channel is one (``fx_N``,
  ``ax_mps2``, ``oil_temp_C``...), else ``<channel>_<units>`` (``x1_m``, ``q_in_Lpm``,
  ``shaker_x_V``); engineering units, drives in volts;
- ``time_s`` is run time (sample / sample_rate_hz), so an export of some steps keeps the run's
  clock and the harmonics' phase reference (run sample 0);
- ``step`` per sample: the step index inside a step's record, -1 outside; ``freq_hz`` per sample:
  that step's frequency, 0 outside (the importer's step and frequency columns);
- harmonics are peak amplitudes with the phase of ``Re(Z exp(i h w t))``, t = ``time_s``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from storage.errors import ExportError
from storage.importers.common import CANONICAL
from storage.importers.restore import EXPORT_FORMAT, EXPORT_VERSION
from storage.layout import (
    EVENT_COLUMNS,
    HARMONICS_ATTRS,
    N_HARMONICS,
    STEP_COLUMNS,
    STEP_FIELDS_BY_KIND,
    TARGET_UNITS,
    installed_software_version,
    utc_now_iso,
)
from storage.reader import RunData
from storage.run_row import seal_friction_n, seal_of

#: Samples read and written per block.
BLOCK_SAMPLES = 1 << 18
#: Called with (samples done, samples in all) as an export goes on.
Progress = Callable[[int, int], None]

_UNIT_SUFFIX = {"N": "N", "m": "m", "m/s": "mps", "m/s^2": "mps2", "degC": "C", "Pa": "Pa",
                "L/min": "Lpm", "V": "V", "": ""}
#: Root attributes copied into the conditions as they are.
RUN_ATTRS = ("run_id", "kind", "status", "status_reason", "start_time", "stop_time", "operator",
             "notes", "software_version", "sample_rate_hz", "lubricated", "format_version")
#: Root attributes holding JSON text.
JSON_ATTRS = ("channel_map", "rig_config", "test_spec")


def column_name(channel: str, units: str) -> str:
    """The export's column for a channel: the canonical name where the channel is one (so
    `sfdrig import` knows it without ``--map``), else ``<channel>_<units>``; a valid MATLAB and
    TDMS name (letters, digits, underscores, starting with a letter, at most 63 characters)."""
    for canon, spec in CANONICAL.items():
        if spec is not None and spec[0] == channel and spec[1] == units:
            return canon
    suffix = _UNIT_SUFFIX.get(units, re.sub(r"[^A-Za-z0-9]+", "", units.replace("/", "p")))
    name = re.sub(r"[^A-Za-z0-9_]", "_", f"{channel}_{suffix}" if suffix else channel)
    if not name[0].isalpha():
        name = "c_" + name
    return name[:63]


def parse_steps(text: str | None, n_steps: int, where: str) -> tuple[int, int] | None:
    """``--steps N`` or ``N-M``: steps as people count them, from 1 (as `sfdrig sweep`'s table
    and `watch` show them), inclusive -> (first, last) as the file's step indices (from 0), or
    None for all."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", text)
    if not m:
        raise ExportError(f"--steps {text!r}: expected N or N-M (steps counted from 1, "
                          "inclusive, e.g. 2-5)")
    a = int(m[1])
    b = int(m[2]) if m[2] is not None else a
    if b < a:
        raise ExportError(f"--steps {text}: the range runs backwards ({a} > {b})")
    if n_steps == 0:
        raise ExportError(f"{where}: --steps {text}: the run has no steps")
    if a < 1 or b > n_steps:
        raise ExportError(f"{where}: --steps {text}: the run has steps 1-{n_steps} (counted "
                          "from 1)")
    return a - 1, b - 1


@dataclass
class Column:
    """One exported signal: its run name, export column, group (channels or drive) and attrs."""

    name: str
    column: str
    group: str
    attrs: dict[str, Any]

    @property
    def units(self) -> str:
        return str(self.attrs.get("units", ""))


@dataclass
class ExportSet:
    """What one export of one run holds (the selected span, columns and steps).

    Attributes
    ----------
    run : RunData
    first, stop : int
        Half-open span of run samples exported.
    columns : list of Column
        Analog inputs (in channel-map order), then the drives.
    steps : list of dict
        The selected steps (contract A dicts, run sample numbering).
    """

    run: RunData
    first: int
    stop: int
    columns: list[Column]
    steps: list[dict[str, Any]]
    exported_at: str = field(default_factory=utc_now_iso)

    @property
    def n_samples(self) -> int:
        return self.stop - self.first

    @property
    def fs(self) -> float:
        return self.run.sample_rate_hz

    @property
    def stem(self) -> str:
        return self.run.path.stem

    def blocks(self, block: int = BLOCK_SAMPLES,
               progress: Progress | None = None) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
        """(offset in the export, column -> samples) block by block, with ``time_s``, ``step``
        and ``freq_hz``."""
        total = self.n_samples
        for a in range(self.first, self.stop, block):
            b = min(a + block, self.stop)
            out = {"time_s": np.arange(a, b) / self.fs}
            step, freq = self.step_columns(a, b)
            out["step"], out["freq_hz"] = step, freq
            for c in self.columns:
                out[c.column] = self.run.channel(c.name, a, b)
            yield a - self.first, out
            if progress is not None:
                progress(b - self.first, total)

    def step_columns(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample step index (-1 outside a record) and frequency (0 outside) of [a, b)."""
        step = np.full(b - a, -1.0)
        freq = np.zeros(b - a)
        for st in self.steps:
            lo, hi = max(st["first_sample"], a), min(st["last_sample"], b)
            if lo < hi:
                step[lo - a:hi - a] = st["index"]
                freq[lo - a:hi - a] = st["freq_hz"]
        return step, freq

    # --- tables -------------------------------------------------------------------------------
    def step_table(self) -> dict[str, list[Any]]:
        """The step table's columns (the run file's ``/steps`` plus ``target_units``, times)."""
        cols: dict[str, list[Any]] = {k: [] for k in STEP_TABLE_COLUMNS}
        for st in self.steps:
            extra = {k: v for k, v in st.items() if k not in STEP_COLUMNS
                     and k not in ("harmonics", "drive_v")}
            row = {**st, "target_units": TARGET_UNITS.get(st["target_kind"], ""),
                   "t_start_s": st["first_sample"] / self.fs,
                   "t_stop_s": st["last_sample"] / self.fs,
                   "extra": json.dumps(jsonable(extra)) if extra else ""}
            for k in cols:
                cols[k].append(row[k])
        return cols

    def harmonics(self) -> tuple[np.ndarray, np.ndarray]:
        """(Z of the inputs (n_steps, n_ai, 5), Z of the drives (n_steps, n_ao)); NaN where a
        step has none."""
        ai = [c for c in self.columns if c.group == "channels"]
        ao = [c for c in self.columns if c.group == "drive"]
        z = np.full((len(self.steps), len(ai), N_HARMONICS), np.nan + 1j * np.nan)
        d = np.full((len(self.steps), len(ao)), np.nan + 1j * np.nan)
        for i, st in enumerate(self.steps):
            for j, c in enumerate(ai):
                for k, (re_, im) in enumerate((st["harmonics"].get(c.name) or [])[:N_HARMONICS]):
                    z[i, j, k] = complex(re_, im)
            for j, c in enumerate(ao):
                if c.name in st["drive_v"]:
                    d[i, j] = complex(*st["drive_v"][c.name])
        return z, d

    def harmonics_table(self) -> dict[str, list[Any]]:
        """The harmonics in long form: one row per step, signal and harmonic (drives: 1X)."""
        z, d = self.harmonics()
        cols: dict[str, list[Any]] = {k: [] for k in HARMONICS_TABLE_COLUMNS}
        ai = [c for c in self.columns if c.group == "channels"]
        ao = [c for c in self.columns if c.group == "drive"]
        for i, st in enumerate(self.steps):
            rows = [(c, k + 1, z[i, j, k]) for j, c in enumerate(ai) for k in range(N_HARMONICS)]
            rows += [(c, 1, d[i, j]) for j, c in enumerate(ao)]
            for c, h, zz in rows:
                if np.isnan(zz.real):
                    continue
                for k, v in (("step", st["index"]), ("channel", c.name), ("column", c.column),
                             ("units", c.units), ("harmonic", h),
                             ("freq_hz", h * st["freq_hz"]), ("amplitude", abs(zz)),
                             ("phase_deg", math.degrees(np.angle(zz))), ("re", zz.real),
                             ("im", zz.imag)):
                    cols[k].append(v)
        return cols

    def channel_table(self) -> dict[str, list[Any]]:
        cols: dict[str, list[Any]] = {k: [] for k in CHANNEL_TABLE_COLUMNS}
        for c in self.columns:
            row = {"column": c.column, "channel": c.name, "group": c.group}
            for k in cols:
                v = row.get(k, c.attrs.get(k, ""))
                cols[k].append(float("nan") if k in ("gain_v_per_unit", "offset_v") and v == ""
                               else v)
        return cols

    def events(self) -> list[dict[str, Any]]:
        """The run's events within the exported span (all of them for a whole run)."""
        whole = self.first == 0 and self.stop == self.run.n_samples
        return [e for e in self.run.events if whole or self.first <= e["sample"] <= self.stop]

    def event_table(self) -> dict[str, list[Any]]:
        ev = self.events()
        return {k: [e[k] for e in ev] for k in EVENT_COLUMNS}

    # --- conditions and metadata ------------------------------------------------------------
    def conditions(self) -> dict[str, Any]:
        """The run's conditions as flat scalars (what a MAT struct or TDMS root property holds)."""
        attrs = self.run.attrs
        out: dict[str, Any] = {k: attrs[k] for k in RUN_ATTRS if k in attrs}
        out["lubricated"] = bool(attrs.get("lubricated", False))
        out["seal"] = self.seal()
        out["seal_friction_N"] = self.seal_friction_n()
        motions = sorted({st["motion"] for st in self.steps if st["motion"]})
        out["motion"] = motions[0] if len(motions) == 1 else ",".join(motions)
        out.update(source_file=str(self.run.path.resolve()), first_sample=self.first,
                   n_samples=self.n_samples, time_start_s=self.first / self.fs,
                   time_increment_s=1.0 / self.fs, exported_at=self.exported_at,
                   exported_by=installed_software_version(), export_version=EXPORT_VERSION)
        return out

    def seal(self) -> str:
        """The end seal as the importer states it (`storage.run_row.seal_of`)."""
        return seal_of(self.run.test_spec, self.run.rig_config)

    def seal_friction_n(self) -> float:
        """The seal's friction force F_mu [N]: 0 for no seal, NaN when unknown or not stated."""
        return seal_friction_n(self.seal())

    def metadata(self) -> dict[str, Any]:
        """Everything `sfdrig import` needs to restore the run, and the conventions, as JSON."""
        run = self.run
        attrs = {k: v for k, v in run.attrs.items() if k not in JSON_ATTRS}
        return jsonable({
            "format": EXPORT_FORMAT, "export_version": EXPORT_VERSION,
            "conditions": self.conditions(),
            "run_attrs": attrs,
            "channel_map": run.channel_map, "rig_config": run.rig_config,
            "test_spec": run.test_spec,
            "columns": [{"column": c.column, "channel": c.name, "group": c.group,
                         "attrs": c.attrs} for c in self.columns],
            "steps": self.steps,
            "events": self.events(),
            "conventions": conventions(),
        })


STEP_TABLE_COLUMNS = ("index", "freq_hz", "target_kind", "target_value", "target_units",
                      "motion", "first_sample", "last_sample", "t_start_s", "t_stop_s",
                      "updates", "converged", "reason", "extra")
HARMONICS_TABLE_COLUMNS = ("step", "channel", "column", "units", "harmonic", "freq_hz",
                           "amplitude", "phase_deg", "re", "im")
CHANNEL_TABLE_COLUMNS = ("column", "channel", "group", "units", "kind", "sensor",
                         "gain_v_per_unit", "offset_v", "physical_channel")


def conventions() -> dict[str, Any]:
    """The conventions every export states (the run file's own descriptions)."""
    return {
        "time_s": "run time: sample / sample_rate_hz seconds after the run's start_time",
        "step": "per sample: the step index inside a step's record, -1 outside",
        "freq_hz": "per sample: the frequency of the step whose record holds the sample, 0 "
                   "outside (and in steps without excitation)",
        "harmonics": {**HARMONICS_ATTRS,
                      "phase_reference": HARMONICS_ATTRS["phase_reference"]
                      + "; t is the export's time_s",
                      "phase_deg": "angle(Z) in degrees"},
        "steps": {k: {"units": u, "description": d} for k, (u, d) in STEP_COLUMNS.items()},
        "target_units": "units of target_value: m (displacement), N (load), Pa (pressure)",
        "step_fields_by_kind": STEP_FIELDS_BY_KIND,
        "signals": "engineering units (column units, channels table), drives in V; the column "
                   "is the importer's canonical name where there is one, else "
                   "<channel>_<units>",
    }


def jsonable(value: Any) -> Any:
    """Plain JSON values: numpy scalars and arrays as lists, NaN and infinities as null
    (standard JSON, which MATLAB's jsondecode and every library read)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return str(value)


def select(run: RunData, steps: str | None = None,
           channels: Sequence[str] | None = None) -> ExportSet:
    """The export of ``run``: the steps ``steps`` (``N`` or ``N-M`` counted from 1, None: the
    whole run) and the
    input channels ``channels`` (None: all); the drives always.

    Raises
    ------
    ExportError
        For a bad step range or an unknown channel, naming the run and what it has.
    """
    where = str(run.path)
    all_steps = run.steps
    picked = parse_steps(steps, len(all_steps), where)
    if picked is None:
        chosen, first, stop = all_steps, 0, run.n_samples
    else:
        chosen = all_steps[picked[0]:picked[1] + 1]
        spans = [(s["first_sample"], s["last_sample"]) for s in chosen
                 if 0 <= s["first_sample"] < s["last_sample"]]
        if not spans:
            raise ExportError(f"{where}: --steps {steps}: those steps hold no samples")
        first = min(a for a, _ in spans)
        stop = min(max(b for _, b in spans), run.n_samples)
    names = list(run.channel_names)
    if channels:
        wanted = [c.strip() for item in channels for c in item.split(",") if c.strip()]
        unknown = [c for c in wanted if c not in names and c not in run.drive_names]
        if unknown:
            raise ExportError(f"{where}: no channel {', '.join(map(repr, unknown))} (channels "
                              f"{', '.join(names)}; drives {', '.join(run.drive_names)})")
        names = [c for c in names if c in wanted]
        if not names:
            raise ExportError(f"{where}: --channels names no input channel (the drives are "
                              f"always exported; channels {', '.join(run.channel_names)})")
    cols = [Column(n, column_name(n, run.units(n)), "channels", run.channel_attrs(n))
            for n in names]
    cols += [Column(n, column_name(n, "V"), "drive", run.channel_attrs(n))
             for n in run.drive_names]
    seen: dict[str, str] = {}
    for c in cols:
        if c.column in seen or c.column in ("time_s", "step", "freq_hz"):
            raise ExportError(f"{where}: channels {seen.get(c.column, c.column)!r} and "
                              f"{c.name!r} would share the column {c.column!r}")
        seen[c.column] = c.name
    if stop <= first:
        raise ExportError(f"{where}: no samples to export")
    return ExportSet(run, first, stop, cols, chosen)


def check_out_dir(out: Path) -> Path:
    """The output folder, created if missing; one-line errors for what cannot be written."""
    if out.exists() and not out.is_dir():
        raise ExportError(f"--out {out}: is a file, not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ExportError(f"--out {out}: cannot create the folder: "
                          f"{err.strerror or err}") from None
    probe = out / ".sfdrig-export-probe"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise ExportError(f"--out {out}: cannot write there: {err.strerror or err}") from None
    return out
