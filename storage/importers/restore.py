"""Files written by `sfdrig export` back into run files: the round trip.

An export carries its metadata (``sfdrig_export``: a MAT variable, a TDMS root property, or
``<stem>.run.json`` beside a CSV): the run's attributes, every channel's attributes, the steps
with their harmonics, the events and the conditions. `sfdrig import` of such a file restores the
run from the samples in the file and that metadata: the same channels, drives, steps, harmonics,
events and conditions (``lubricated``, ``rig_config``, ``test_spec``, ``channel_map``), not a
re-segmented guess. An export of some steps becomes a run starting at the first exported sample:
sample numbers are counted from there, ``start_time`` moves with it and the harmonics' phases are
re-referred to the new time 0 (Z exp(i h w t0)).
"""

from __future__ import annotations

import json
import math
import os
import uuid
from collections.abc import Mapping
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from storage.errors import ImportDataError
from storage.importers.common import file_sha256
from storage.importers.conditions import Conditions
from storage.layout import KINDS, STATUSES, hdf5_text, utc_now_iso
from storage.records import StepRecord
from storage.runfile import RunWriter

#: The metadata's format name and version.
EXPORT_FORMAT = "sfdrig-export"
EXPORT_VERSION = 1


def export_metadata(path: Path) -> dict[str, Any] | None:
    """The metadata of a file `sfdrig export` wrote, or None for any other data file."""
    if not path.is_file():
        return None
    suffix = path.suffix.lower()
    text: Any = None
    try:
        if suffix in (".csv", ".txt"):
            side = path.with_name(path.name[: -len(path.suffix)] + ".run.json")
            text = side.read_text(encoding="utf-8") if side.is_file() else None
        elif suffix == ".mat" and h5py.is_hdf5(path):
            with h5py.File(path, "r") as f:
                ds = f.get("sfdrig_export")
                if isinstance(ds, h5py.Dataset) and ds.dtype == np.uint16:
                    text = np.asarray(ds[()]).T.ravel().tobytes().decode("utf-16-le")
        elif suffix == ".mat":
            import scipy.io

            found = scipy.io.loadmat(path, variable_names=["sfdrig_export"])
            if "sfdrig_export" in found:
                text = str(np.asarray(found["sfdrig_export"]).ravel()[0])
        elif suffix == ".tdms":
            from nptdms import TdmsFile

            text = TdmsFile.read_metadata(path).properties.get("sfdrig_export")
    except (OSError, ValueError, KeyError, UnicodeDecodeError, TypeError):
        return None  # not readable as ours: the format's own reader says why
    except Exception:  # noqa: BLE001 - scipy and npTDMS raise many kinds on foreign files
        return None
    if not text:
        return None
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as err:
        raise ImportDataError(f"{path}: sfdrig export metadata is not valid JSON: {err}") from None
    if not isinstance(meta, dict) or meta.get("format") != EXPORT_FORMAT:
        return None
    if int(meta.get("export_version", 0)) > EXPORT_VERSION:
        raise ImportDataError(f"{path}: export_version {meta['export_version']} is newer than "
                              f"this sfdrig ({EXPORT_VERSION}); update sfdrig")
    return meta


def read_export_signals(path: Path, meta: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The samples of every exported column (engineering units, drives in volts)."""
    where = str(path)
    cols = [c["column"] for c in meta["columns"]]
    suffix = path.suffix.lower()
    out: dict[str, np.ndarray] = {}
    try:
        if suffix in (".csv", ".txt"):
            with open(path, encoding="utf-8") as fh:
                header = [h.strip() for h in fh.readline().strip().split(",")]
            missing = [c for c in cols if c not in header]
            if missing:
                raise ImportDataError(f"{where}: column(s) {missing} of the export are missing")
            idx = [header.index(c) for c in cols]
            data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=idx, ndmin=2)
            out = {c: data[:, i] for i, c in enumerate(cols)}
        elif suffix == ".mat" and h5py.is_hdf5(path):
            with h5py.File(path, "r") as f:
                for c in cols:
                    if c not in f:
                        raise ImportDataError(f"{where}: variable {c!r} of the export is missing")
                    out[c] = np.asarray(f[c][()], dtype=np.float64).ravel()
        elif suffix == ".mat":
            import scipy.io

            found = scipy.io.loadmat(path, variable_names=cols)
            for c in cols:
                if c not in found:
                    raise ImportDataError(f"{where}: variable {c!r} of the export is missing")
                out[c] = np.asarray(found[c], dtype=np.float64).ravel()
        else:
            from nptdms import TdmsFile

            tdms = TdmsFile.read(path)
            for c in meta["columns"]:
                group = "channels" if c["group"] == "channels" else "drive"
                try:
                    out[c["column"]] = np.asarray(tdms[group][c["column"]][:], dtype=np.float64)
                except KeyError:
                    raise ImportDataError(f"{where}: channel '{group}/{c['column']}' of the "
                                          "export is missing") from None
    except ImportDataError:
        raise
    except (OSError, ValueError) as err:
        raise ImportDataError(f"{where}: cannot read the exported samples: {err}") from None
    n = int(meta["conditions"]["n_samples"])
    short = {c: len(v) for c, v in out.items() if len(v) != n}
    if short:
        raise ImportDataError(f"{where}: the metadata says {n} samples, but {short}")
    return out


def _rebased_step(step: dict[str, Any], s0: int, t0: float) -> dict[str, Any]:
    """A step of the export with sample numbers from ``s0`` and phases from time ``t0``."""
    st = dict(step)
    for k in ("freq_hz", "target_value"):
        st[k] = math.nan if st.get(k) is None else float(st[k])
    for k, v in step.items():  # first_sample, last_sample, an impact's trigger_sample
        if k.endswith("_sample") and isinstance(v, int) and v >= 0:
            st[k] = v - s0
    f = st["freq_hz"]
    if s0 and math.isfinite(f):
        w = 2 * math.pi * f
        st["harmonics"] = {
            name: [[z.real, z.imag] for z in (complex(*reim) * np.exp(1j * (h + 1) * w * t0)
                                              for h, reim in enumerate(values))]
            for name, values in (step.get("harmonics") or {}).items()}
        st["drive_v"] = {name: [z.real, z.imag] for name, z in (
            (name, complex(*reim) * np.exp(1j * w * t0))
            for name, reim in (step.get("drive_v") or {}).items())}
    return st


def _shifted_time(iso: str, seconds: float) -> str:
    try:
        t = datetime.fromisoformat(iso)
    except ValueError:
        return iso
    return (t + timedelta(seconds=seconds)).isoformat(timespec="milliseconds")


def _check_conditions(meta: Mapping[str, Any], cond: Conditions | None,
                      where: str) -> dict[str, Any]:
    """Conditions stated at import must agree with the export's, except ``lubricated``, which
    may be corrected (recorded as such). Returns the changes."""
    if cond is None:
        return {}
    exported = meta["conditions"]
    changed: dict[str, Any] = {}
    if cond.lubricated is not None and bool(cond.lubricated) != bool(exported["lubricated"]):
        changed["lubricated"] = {"export": bool(exported["lubricated"]),
                                 "now": bool(cond.lubricated),
                                 "source": cond.sources.get("lubricated", "given")}
    if cond.motion and cond.motion != exported.get("motion"):
        raise ImportDataError(f"{where}: an sfdrig export of run {exported.get('run_id')!r} "
                              f"states each step's motion ({exported.get('motion') or 'none'}); "
                              f"motion {cond.motion} ({cond.sources.get('motion')}) contradicts "
                              "it")
    if cond.seal and cond.seal != exported.get("seal"):
        raise ImportDataError(f"{where}: an sfdrig export of run {exported.get('run_id')!r} "
                              f"states its seal ({exported.get('seal') or 'not stated'}); seal "
                              f"{cond.seal} ({cond.sources.get('seal')}) contradicts it")
    if cond.rig_file is not None:
        raise ImportDataError(f"{where}: an sfdrig export carries its rig_config; --rig does "
                              "not apply")
    return changed


def restore_export(path: str | Path, out: str | Path, meta: Mapping[str, Any], *,
                   run_id: str | None = None, overwrite: bool = False,
                   conditions: Conditions | None = None) -> Path:
    """Write the run an sfdrig export holds as run file ``out``, atomically."""
    path, out = Path(path), Path(out)
    where = str(path)
    if out.exists() and not overwrite:
        raise ImportDataError(f"{out}: exists already (choose another --out or overwrite)")
    if not out.parent.is_dir():
        raise ImportDataError(f"{out.parent}: output directory does not exist")
    changed = _check_conditions(meta, conditions, where)
    signals = read_export_signals(path, meta)
    cond = meta["conditions"]
    attrs = meta.get("run_attrs") or {}
    fs = float(cond["sample_rate_hz"])
    s0 = int(cond.get("first_sample", 0))
    t0 = s0 / fs
    ai = [c for c in meta["columns"] if c["group"] == "channels"]
    ao = [c for c in meta["columns"] if c["group"] == "drive"]
    chans = [{**c["attrs"], "name": c["channel"]} for c in ai]
    kind = str(attrs.get("kind", "imported"))
    lubricated = changed.get("lubricated", {}).get("now", bool(cond["lubricated"]))
    tmp = out.parent / f".{out.name}.{uuid.uuid4().hex[:12]}.tmp"
    try:
        with RunWriter.create(
            tmp, run_id or str(attrs.get("run_id", path.stem)),
            kind if kind in KINDS else "imported", chans, [c["channel"] for c in ao], fs,
            operator=str(attrs.get("operator", "")), notes=str(attrs.get("notes", "")),
            software_version=str(attrs.get("software_version", "")) or None,
            channel_map=meta.get("channel_map"), rig_config=meta.get("rig_config"),
            test_spec=meta.get("test_spec"), lubricated=lubricated,
            start_time=_shifted_time(str(attrs.get("start_time", "")), t0) or None,
            overwrite=False, swmr=False, flush_interval_s=0,
        ) as w:
            n = int(cond["n_samples"])
            block = 1 << 20
            for a in range(0, n, block):
                b = min(a + block, n)
                w.on_block(a, np.stack([signals[c["column"]][a:b] for c in ai]),
                           np.stack([signals[c["column"]][a:b] for c in ao]) if ao else None)
            for i, step in enumerate(meta.get("steps", [])):
                w.on_step(StepRecord.from_wire(_rebased_step(step, s0, t0), i))
            events = meta.get("events", [])
            for e in events:
                w.on_event(str(e["kind"]), str(e["message"]), int(e["sample"]) - s0)
        _finish_restored(tmp, attrs, events, {
            "source_file": str(path.resolve()), "source_sha256": file_sha256(path),
            "export_format": path.suffix.lower().lstrip("."), "restored_at": utc_now_iso(),
            "run_id": attrs.get("run_id"), "first_sample": s0, "n_samples": int(cond["n_samples"]),
            "conditions_changed": changed})
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out


def _finish_restored(path: Path, attrs: Mapping[str, Any], events: list[dict[str, Any]],
                     provenance: dict[str, Any]) -> None:
    """The original status, stop time and event times (the writer stamps its own), and where
    the run came from (root attribute ``imported_from``, JSON)."""
    with h5py.File(path, "r+") as f:
        status = str(attrs.get("status", "completed"))
        for key in ("stop_time", "status_reason"):
            if attrs.get(key) is not None:
                f.attrs[key] = hdf5_text(attrs[key])
        if status == "running":  # exported while written: a snapshot, not a live run
            f.attrs["status"] = "interrupted"
            f.attrs["status_reason"] = "exported while the run was still being written"
        elif status in STATUSES or status == "interrupted":
            f.attrs["status"] = status
        if isinstance(attrs.get("last_sample"), int):  # a run closed as interrupted
            f.attrs["last_sample"] = attrs["last_sample"] - int(provenance["first_sample"])
        rows = f["events"][()]
        for i, e in enumerate(events[: len(rows)]):
            rows[i]["time"] = str(e["time"]).encode()
        if len(rows):
            f["events"][...] = rows
        f.attrs["imported_from"] = json.dumps(provenance)

