"""CSV export: the samples, and beside them the step, harmonics, channel and event tables, the
conditions (the importer's conditions file) and the metadata (``<stem>.run.json``)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from storage.exporters.common import ExportSet, Progress
from storage.exporters.files import AtomicFiles
from storage.importers.conditions import MOTIONS, RECORD_TABLE

#: Files of a CSV export of run file RUN.h5, beside each other in the output folder.
SUFFIXES = (".csv", ".steps.csv", ".harmonics.csv", ".channels.csv", ".events.csv",
            ".csv.conditions.toml", ".run.json")


def write_csv(exp: ExportSet, out_dir: Path, progress: Progress | None = None,
              overwrite: bool = False) -> list[Path]:
    """Write ``exp`` as ``<stem>.csv`` (``time_s, step, freq_hz`` and one column per signal,
    every value with 17 significant digits, so it reads back bit for bit) and its tables."""
    stem = exp.stem
    with AtomicFiles(out_dir, [stem + s for s in SUFFIXES], overwrite) as files:
        header = ["time_s", "step", "freq_hz"] + [c.column for c in exp.columns]
        with open(files.tmp(stem + ".csv"), "w", encoding="utf-8", newline="") as fh:
            fh.write(",".join(header) + "\n")
            for _, block in exp.blocks(progress=progress):
                np.savetxt(fh, np.column_stack([block[h] for h in header]), fmt="%.17g",
                           delimiter=",")
        _table(files.tmp(stem + ".steps.csv"), exp.step_table())
        _table(files.tmp(stem + ".harmonics.csv"), exp.harmonics_table())
        _table(files.tmp(stem + ".channels.csv"), exp.channel_table())
        _table(files.tmp(stem + ".events.csv"), exp.event_table())
        files.tmp(stem + ".csv.conditions.toml").write_text(conditions_toml(exp),
                                                            encoding="utf-8")
        files.tmp(stem + ".run.json").write_text(json.dumps(exp.metadata(), indent=1),
                                                 encoding="utf-8")
    return files.paths


def _cell(value: Any) -> Any:
    """A cell every CSV reader parses: numpy scalars as the plain numbers they hold (the repr of
    ``np.float64(2.5)`` is not a number), floats with 17 digits, booleans as 0 and 1."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else "nan"
    return value


def _table(path: Path, cols: dict[str, list[Any]]) -> None:
    with open(path, "w", encoding="utf-8", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for row in zip(*cols.values(), strict=True):
            w.writerow([_cell(v) for v in row])


def conditions_toml(exp: ExportSet) -> str:
    """The conditions in the importer's conditions-file form (``lubricated``, ``motion`` when
    every step has one, ``seal`` when stated: `sfdrig import` of the CSV reads them), then every
    other condition of the run in the table ``[run]`` (kind, status, times, the sample rate...),
    which the importer does not read."""
    cond = exp.conditions()
    lines = [f"# conditions of run {cond.get('run_id', '')} (sfdrig export), read by "
             "sfdrig import; [run] is a record of the run, not read",
             f"lubricated = {'true' if cond['lubricated'] else 'false'}"]
    if cond["motion"] in MOTIONS:
        lines.append(f'motion = "{cond["motion"]}"')
    seal = cond["seal"]
    if seal in ("none", "unknown"):
        lines.append(f'seal = "{seal}"')
    elif seal:
        lines.append(f"seal = {float(seal)!r}  # the seal's friction force F_mu [N]")
    lines += ["", f"[{RECORD_TABLE}]"]
    for key, value in cond.items():
        if key not in ("lubricated", "motion", "seal"):
            lines.append(f"{key} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


def _toml_value(value: Any) -> str:
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else "nan"
    return json.dumps(str(value))  # a TOML basic string: JSON's escapes are TOML's
