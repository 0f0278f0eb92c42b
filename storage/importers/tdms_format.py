"""NI TDMS files, as LabVIEW writes them."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from storage.errors import ImportDataError
from storage.importers.common import (
    FS_TOLERANCE,
    MeasuredData,
    ReadColumns,
    _select,
    measured_from,
)


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
            # the first sample is wf_start_offset after wf_start_time (as npTDMS's time track)
            start_time = _tdms_time(t0, float(ch.properties.get("wf_start_offset", 0.0) or 0.0))
    stated = None
    if increments:
        vals = list(increments.values())
        if max(vals) - min(vals) > FS_TOLERANCE * min(vals):
            desc = ", ".join(f"{k}: {v:g} s" for k, v in increments.items())
            raise ImportDataError(f"{where}: channels have different wf_increment ({desc})")
        stated = (f"wf_increment of {next(iter(increments))}", 1.0 / vals[0])
    return measured_from(ReadColumns(columns, sources, "tdms", stated_rate=stated,
                                     start_time=start_time), where, fs_hz, scale)


def _tdms_time(value: Any, offset_s: float = 0.0) -> str:
    try:
        ts = np.datetime64(value, "us") + np.timedelta64(round(offset_s * 1e6), "us")
        return datetime.fromisoformat(str(ts)).replace(tzinfo=UTC).isoformat(
            timespec="milliseconds")
    except (ValueError, TypeError):
        return ""



