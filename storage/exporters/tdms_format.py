"""NI TDMS export (npTDMS's writer): one ``<stem>.tdms`` for DIAdem, LabVIEW and npTDMS.

Groups: ``channels`` (one waveform per input, named by its export column, with ``unit_string``,
``sensor``, ``kind``, ``gain_v_per_unit``, ``offset_v``, ``physical_channel`` and the waveform
timing ``wf_start_time``, ``wf_start_offset``, ``wf_increment``), ``drive`` (the drives [V]),
``per_sample`` (``step`` and ``freq_hz``), and the tables ``steps``, ``harmonics``, ``events``
and ``channel_table``, one TDMS channel per column. Root properties: the run's conditions, the
conventions and ``sfdrig_export`` (the metadata JSON `sfdrig import` restores the run from).
Samples are written in segments of `BLOCK_SAMPLES`.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from storage.exporters.common import ExportSet, Progress
from storage.exporters.files import AtomicFiles


def _start_time(exp: ExportSet) -> np.datetime64 | None:
    """wf_start_time: the run's start (UTC, as TDMS stores it), if the run says. Sample k of the
    export is at wf_start_time + wf_start_offset + k * wf_increment, and wf_start_offset is the
    run time of its first sample: so npTDMS's time track is the run's time (``time_s`` of the
    other formats) and its absolute time track the wall-clock time, for a whole run and for an
    export of some steps alike."""
    try:
        t0 = datetime.fromisoformat(str(exp.run.attrs.get("start_time", "")))
    except ValueError:
        return None
    if t0.tzinfo is not None:
        t0 = t0.astimezone(UTC).replace(tzinfo=None)
    return np.datetime64(t0, "us")


def _prop(value: Any) -> Any:
    """A TDMS property value (no None: TDMS has no null)."""
    if value is None:
        return ""
    if isinstance(value, dict | list):
        return json.dumps(value)
    return value


def _table_channels(group: str, cols: dict[str, list[Any]]) -> list[Any]:
    from nptdms import ChannelObject

    out = []
    for k, values in cols.items():
        if values and all(isinstance(v, str) for v in values) or not values:
            data = np.array([str(v) for v in values], dtype=str)
        elif all(isinstance(v, bool) for v in values):
            data = np.asarray(values, dtype=bool)
        else:
            data = np.asarray(values, dtype=np.float64)
        out.append(ChannelObject(group, k, data))
    return out


def write_tdms(exp: ExportSet, out_dir: Path, progress: Progress | None = None,
               overwrite: bool = False) -> list[Path]:
    """Write ``exp`` as ``<stem>.tdms``."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    name = exp.stem + ".tdms"
    meta = exp.metadata()
    root_props = {k: _prop(v) for k, v in exp.conditions().items()}
    root_props.update(name=exp.run.run_id, description=(
        f"sfdrig run {exp.run.run_id}: signals in engineering units (unit_string), drives [V], "
        "steps, harmonics (peak amplitude, phase from run time 0), conditions; see "
        "docs/run-files.md"), conventions=json.dumps(meta["conventions"]),
        sfdrig_export=json.dumps(meta))
    t0 = _start_time(exp)
    timing: dict[str, Any] = {"wf_start_offset": exp.first / exp.fs,
                              "wf_increment": 1.0 / exp.fs, "wf_samples": exp.n_samples}
    if t0 is not None:
        timing["wf_start_time"] = t0
    signal_group = {"channels": "channels", "drive": "drive"}
    with AtomicFiles(out_dir, [name], overwrite) as files, \
            TdmsWriter(str(files.tmp(name))) as w:
        first = True
        for _, block in exp.blocks(progress=progress):
            objs: list[Any] = []
            if first:
                objs += [RootObject(root_props)] + [GroupObject(g) for g in (
                    "channels", "drive", "per_sample", "steps", "harmonics", "events",
                    "channel_table")]
            for c in exp.columns:
                props = {}
                if first:
                    props = {k: _prop(v) for k, v in c.attrs.items()
                             if k not in ("time_start", "time_increment", "time_units",
                                          "time_reference")}
                    props.update(unit_string=c.units, channel=c.name, **timing)
                objs.append(ChannelObject(signal_group[c.group], c.column, block[c.column],
                                          props))
            for k, units in (("step", ""), ("freq_hz", "Hz")):
                props = {"unit_string": units, **timing} if first else {}
                objs.append(ChannelObject("per_sample", k, block[k], props))
            if first:
                objs += _table_channels("steps", exp.step_table())
                objs += _table_channels("harmonics", exp.harmonics_table())
                objs += _table_channels("events", exp.event_table())
                objs += _table_channels("channel_table", exp.channel_table())
            w.write_segment(objs)
            first = False
    return files.paths
