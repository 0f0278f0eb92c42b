"""From measured data to a run file: choose the reader, segment into dwells, write atomically."""

from __future__ import annotations

import math
import os
import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from storage.errors import ImportDataError
from storage.importers.common import CANONICAL, MeasuredData, file_sha256
from storage.importers.conditions import Conditions
from storage.importers.csv_format import read_csv
from storage.importers.mat_format import read_mat
from storage.importers.restore import export_metadata, restore_export
from storage.importers.segments import Segmentation, segment_record
from storage.importers.tdms_format import read_tdms
from storage.layout import KINDS, utc_now_iso
from storage.records import StepRecord
from storage.runfile import RunWriter

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


def derive_displacement(data: MeasuredData, steps: list[dict[str, Any]]) -> list[str]:
    """Displacement from acceleration or velocity where the file has none, per dwell.

    Within each dwell the first ``N_DERIVED_HARMONICS`` harmonics of the dwell frequency are
    fitted (least squares) and divided by (i k w)^2 or (i k w); outside dwells the derived signal
    is 0. What is not periodic at the dwell frequency (noise, drift) is left out: say so.
    Returns the notes describing what was derived.
    """
    notes = []
    for axis in ("x", "y"):
        disp = f"{axis}_m"
        if disp in data.signals:
            continue
        found = [(src, n) for src, n in ((f"v{axis}_mps", 1), (f"a{axis}_mps2", 2))
                 if src in data.signals]
        if not found:
            continue
        src, power = found[0]
        sig = data.signals[src]
        out = np.zeros_like(sig)
        for st in steps:
            a, b, f = int(st["first_sample"]), int(st["last_sample"]), float(st["freq_hz"])
            t = np.arange(a, b) / data.fs_hz
            k = np.arange(1, N_DERIVED_HARMONICS + 1)
            k = k[k * f < 0.45 * data.fs_hz]
            basis = np.exp(2j * math.pi * f * np.outer(t, k))
            design = np.column_stack([np.ones_like(t), basis.real, basis.imag])
            coef, *_ = np.linalg.lstsq(design, sig[a:b], rcond=None)
            amp = coef[1:1 + k.size] - 1j * coef[1 + k.size:]
            amp = amp / (1j * 2 * math.pi * f * k) ** power
            out[a:b] = np.real(basis @ amp)
        data.signals[disp] = out
        data.sources[disp] = (f"derived from {data.sources.get(src, src)} (first "
                              f"{N_DERIVED_HARMONICS} harmonics per dwell divided by (i k w)^"
                              f"{power}; 0 outside dwells)")
        notes.append(f"{disp} {data.sources[disp]}")
    return notes


#: Harmonics kept when displacement is rebuilt from acceleration or velocity.
N_DERIVED_HARMONICS = 5


def write_imported_run(data: MeasuredData, out: str | Path, source: str | Path, *,
                       kind: str = "imported", notes: str = "", operator: str = "",
                       run_id: str | None = None, overwrite: bool = False,
                       extra_spec: Mapping[str, Any] | None = None,
                       conditions: Conditions | None = None,
                       rig_config: Mapping[str, Any] | None = None,
                       require_steps: bool = False) -> Path:
    """Write measured data as a run file, atomically (temporary file, then rename).

    Channels are those of `CANONICAL` present (SI units); steps come from `segment_record`
    (frequency, amplitude and motion changes, or the step column); the conditions are stored
    as the daemon stores them (``lubricated`` attribute, ``motion`` per step, ``rig_config``)
    and, with their sources and the evidence of what was inferred, in ``test_spec.conditions``.
    With ``require_steps``, data without a frequency or a step column, of which no step (dwell)
    can be made, is refused, naming the columns it lacks (`sfdrig import` without
    ``--no-steps``).
    """
    out = Path(out)
    source = Path(source)
    cond = conditions or Conditions(sources={k: "not stated" for k in
                                             ("lubricated", "motion", "seal", "rig")})
    _refuse_what_cannot_be_written(data, out, source, kind, overwrite, require_steps)
    seg = segment_record(data.signals, data.fs_hz, data.freq_hz, data.step, cond.motion)
    derived = derive_displacement(data, seg.steps)
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
    spec_json = {**_import_spec(data, source, cond, seg, derived, order), **(extra_spec or {})}
    run_id = run_id or f"imported-{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{out.stem}"
    # A hidden unique name beside the target (same file system, so the rename is atomic);
    # created by HDF5 itself so it gets the usual permissions (mkstemp would make it 0600).
    tmp = out.parent / f".{out.name}.{uuid.uuid4().hex[:12]}.tmp"
    try:
        with RunWriter.create(
            tmp, run_id, kind, channels, [], data.fs_hz, operator=operator, notes=notes,
            test_spec=spec_json, start_time=data.start_time or None, overwrite=False,
            swmr=False, flush_interval_s=0, compression="gzip",
            rig_config=dict(rig_config) if rig_config else None,
            lubricated=bool(cond.lubricated),
        ) as w:
            block = 1 << 20
            n = data.n_samples
            for a in range(0, n, block):
                b = min(a + block, n)
                w.on_block(a, np.stack([data.signals[c][a:b] for c in order]), None)
            for i, step in enumerate(seg.steps):
                w.on_step(StepRecord.from_wire(step, i))
            w.on_event("info", f"imported from {source} ({data.source_format})", 0)
            for sw in seg.sweeps:
                w.on_event("info", f"sine sweep {sw['f_start_hz']:g} to {sw['f_stop_hz']:g} Hz "
                           "(not a dwell)", sw["first_sample"])
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out


def _refuse_what_cannot_be_written(data: MeasuredData, out: Path, source: Path, kind: str,
                                   overwrite: bool, require_steps: bool) -> None:
    """ImportDataError for a kind, an output or (with ``require_steps``) data that cannot
    make the run file asked for."""
    if kind not in KINDS:
        raise ImportDataError(f"--kind {kind!r} is not one of {KINDS}")
    if out.exists() and not overwrite:
        raise ImportDataError(f"{out}: exists already (choose another --out or overwrite)")
    if not out.parent.is_dir():
        raise ImportDataError(f"{out.parent}: output directory does not exist")
    if require_steps and data.freq_hz is None and data.step is None:
        raise ImportDataError(
            f"{source}: no frequency column (freq_hz) and no step column (step), so no steps "
            "(dwells) can be made of it: map the excitation frequency with --map "
            "freq_hz=COLUMN or the dwell number with --map step=COLUMN, give --freq-hz HZ for "
            "a record at one frequency, or --no-steps to import it without steps (diagnose "
            "judges it in blocks; identify needs steps)")


def _import_spec(data: MeasuredData, source: Path, cond: Conditions, seg: Segmentation,
                 derived: list[str], order: list[str]) -> dict[str, Any]:
    """The imported run's ``test_spec``: where it came from, its signals, its conditions with
    their sources (per step, the motion and why), its sweeps, what was derived, how it was
    cut into steps."""
    cond_json = cond.to_json()
    cond_json["motion_per_step"] = [
        {"step": st["index"], "motion": st["motion"],
         "source": ("inferred from the x/y phase: " + why) if why else cond.sources["motion"]}
        for st, why in zip(seg.steps, seg.motion_evidence, strict=True)]
    spec_json = {
        "source_file": str(source.resolve()), "source_format": data.source_format,
        "source_sha256": file_sha256(source), "imported_at": utc_now_iso(),
        "signals": {c: data.sources.get(c, "") for c in order}, "time_offset_s":
        data.time_offset_s, "n_samples": data.n_samples, "conditions": cond_json,
        "sweeps": seg.sweeps, "derived": derived,
        "segmentation": ("step column " + data.sources.get("step", "") if data.step is not None
                         else "frequency column, amplitude and motion changes"
                         if data.freq_hz is not None else "none (no frequency or step column)"),
    }
    if data.freq_hz is not None:
        spec_json["freq_source"] = data.sources.get("freq_hz", "")
    return spec_json


def with_dwell_frequency(data: MeasuredData, freq_hz: float, where: str) -> MeasuredData:
    """``data`` recorded at one excitation frequency ``freq_hz`` throughout (``--freq-hz``):
    its frequency column, from which the dwells are found as from a file's own."""
    if not (math.isfinite(freq_hz) and freq_hz > 0):
        raise ImportDataError(f"--freq-hz {freq_hz:g}: must be a positive frequency [Hz]")
    if data.freq_hz is not None or data.step is not None:
        column = "freq_hz" if data.freq_hz is not None else "step"
        raise ImportDataError(f"{where}: --freq-hz {freq_hz:g}: the file has a {column} column "
                              f"({data.sources.get(column, column)}); give one or the other")
    if freq_hz >= 0.5 * data.fs_hz:
        raise ImportDataError(f"{where}: --freq-hz {freq_hz:g}: at or above half the sample "
                              f"rate ({data.fs_hz:g} Hz)")
    data.freq_hz = np.full(data.n_samples, float(freq_hz))
    data.sources["freq_hz"] = f"--freq-hz {freq_hz:g}"
    return data


def import_file(path: str | Path, out: str | Path, *, mapping: Mapping[str, str] | None = None,
                fs_hz: float | None = None, scale: Mapping[str, float] | None = None,
                kind: str = "imported", notes: str = "", operator: str = "",
                run_id: str | None = None, overwrite: bool = False,
                conditions: Conditions | None = None,
                rig_config: Mapping[str, Any] | None = None,
                dwell_freq_hz: float | None = None, require_steps: bool = False) -> Path:
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
    conditions : Conditions, optional
        Lubricated or dry, motion, seal (see `storage.importers.conditions`).
    rig_config : dict, optional
        The rig description (validated by the caller), stored as the run's rig_config.
    dwell_freq_hz : float, optional
        The excitation frequency of the whole record [Hz], for a file without a frequency or
        step column (`with_dwell_frequency`).
    require_steps : bool
        Refuse data without a frequency or step column (see `write_imported_run`).

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ImportDataError
        Naming the file and the line, column or variable at fault; ``out`` is then untouched.

    A file `sfdrig export` wrote is restored as the run it came from (`restore_export`).
    """
    meta = export_metadata(Path(path))
    if meta is not None:
        if mapping or scale or fs_hz is not None or dwell_freq_hz is not None:
            raise ImportDataError(f"{path}: an sfdrig export names its own columns, sample rate, "
                                  "steps and units; --map, --scale, --fs and --freq-hz do not "
                                  "apply")
        return restore_export(path, out, meta, run_id=run_id, overwrite=overwrite,
                              conditions=conditions)
    data = read_measured(path, mapping, fs_hz, scale)
    if dwell_freq_hz is not None:
        data = with_dwell_frequency(data, dwell_freq_hz, str(path))
    return write_imported_run(data, out, path, kind=kind, notes=notes, operator=operator,
                              run_id=run_id, overwrite=overwrite,
                              extra_spec={"mapping": dict(mapping or {}),
                                          "scale": dict(scale or {})},
                              conditions=conditions, rig_config=rig_config,
                              require_steps=require_steps)
