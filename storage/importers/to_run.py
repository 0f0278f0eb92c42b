"""From measured data to a run file: choose the reader, segment into dwells, write atomically."""

from __future__ import annotations

import hashlib
import math
import os
import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from storage.errors import ImportDataError
from storage.importers.common import CANONICAL, MeasuredData
from storage.importers.csv_format import read_csv
from storage.importers.mat_format import read_mat
from storage.importers.tdms_format import read_tdms
from storage.runfile import KINDS, RunWriter, utc_now_iso

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
