"""Calibration results back into the channel map (`sfdrig channels calibrate`).

- A **probe calibration** run (`analysis.structure.identify_probe_calibration`, Table A1): each
  probe's identified gain becomes its ``gain_v_per_unit`` where it differs from the map's by more
  than the calibration's uncertainty (and 0.1 %) and the fit is good (R^2 >= 0.99). Before
  fitting, every dial-gauge entry is held against what the probes read at that point (with the
  gain in use): an entry whose sign, or whose size beyond a factor of 2, disagrees
  (`0.0010 in` typed while the probes read -76 um) is questioned and left out of the fit
  unless kept (``keep_steps``: step numbers counted from 1, as the messages show them).
- A **static** run loaded by the shakers: the load cell's force against the drive's volts, per
  axis, is the amplifier and shaker's gain, the drive's ``nominal_force_n_per_v``. Loaded by
  hand, each force-gauge entry is held against the probes' displacement times the rods'
  nominal stiffness (a factor of 2 either way, and the sign); the stiffness itself is no field
  of the map (`sfdrig identify` reports it).
"""

from __future__ import annotations

import math
import re
from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np

from analysis.dwells import run_label
from analysis.errors import Skipped
from analysis.structure import MIL_M, identify_probe_calibration
from analysis.uncertainty import line_fit
from daq.channels import ChannelMap
from daq.map_edits import Correction
from storage import RunData

AGREE = (0.5, 2.0)  # an entry against what the probes say
MIN_SIZE_M = 5e-6  # points nearer zero than this on both sides are not judged
MIN_SIZE_N = 5.0
MIN_R2 = 0.99
MIN_CHANGE = 1e-3  # gains closer than this (relative) are left as they are
K_NOMINAL_N_PER_M = {"x": 788e3, "y": 823e3}  # the rods (report, Table 2)
_UNITS_M = {"in": 0.0254, "mil": MIL_M, "mils": MIL_M, "um": 1e-6, "mm": 1e-3, "m": 1.0}


@dataclass
class FlowBack:
    """What one run gives the channel map: corrections, the entries questioned (one line
    each), and notes on what was found and not proposed."""

    corrections: list[Correction] = field(default_factory=list)
    questions: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def calibration_flow_back(run: RunData, cm: ChannelMap,
                          keep_steps: Collection[int] = ()) -> FlowBack:
    """The corrections of ``cm`` that ``run`` supports; raises ValueError for a run that holds
    no calibration, or for a kept step (counted from 1) the run does not have."""
    bad = sorted(n for n in keep_steps if not 1 <= n <= len(run.steps))
    if bad and run.kind == "probe_calibration":
        raise ValueError(f"{run.path}: --keep-step {bad[0]}: no such step (the run has "
                         f"{len(run.steps)}, counted from 1)")
    if run.kind == "probe_calibration":
        return _probes(run, cm, keep_steps)
    if run.kind == "static":
        return _static(run, cm)
    raise ValueError(f"{run.path}: a {run.kind!r} run holds no calibration for the channel map "
                     "(give a probe_calibration or a static run)")


def _probes(run: RunData, cm: ChannelMap, keep: Collection[int]) -> FlowBack:
    fb = FlowBack()
    label = run_label(run)
    questioned: set[int] = set()
    for st in run.steps:
        axis, idx = str(st.get("motion", "")), int(st["index"])
        ref = float(st.get("reference_m", st.get("target_value", float("nan"))))
        probes = [c for c in run.channel_names if re.fullmatch(rf"{axis}\d+", c)]
        if not probes or not math.isfinite(ref):
            continue
        first, last = int(st["first_sample"]), int(st["last_sample"])
        reads = {p: float(np.mean(run.channel(p, first, last))) for p in probes}
        z = float(np.mean(list(reads.values())))
        if max(abs(z), abs(ref)) < MIN_SIZE_M or \
                (z != 0 and AGREE[0] <= ref / z <= AGREE[1]):
            continue
        text = str(st.get("gauge_text", "")) or f"{ref * 1e6:+.1f} um"
        unit = (re.findall(r"([A-Za-z]+)\s*$", text) or ["um"])[0]
        scale = _UNITS_M.get(unit, 1e-6)
        shown = ", ".join(f"{p} {v * 1e6:+.1f}" for p, v in reads.items())
        what = "the sign and the size" if ref * z < 0 else "the size"
        n = idx + 1  # steps are counted from 1, as everywhere the operator reads them
        kept = n in keep
        fb.questions.append(
            f"{label} step {n} ({axis}): the gauge entry {text!r} ({ref * 1e6:+.1f} um) while "
            f"the probes read {z * 1e6:+.1f} um ({shown} um): {what} disagree ("
            f"{z / scale:+.4g} {unit if unit in _UNITS_M else 'um'} would match); "
            + ("kept in the fit (--keep-step)" if kept else
               f"left out of the fit (--keep-step {n} keeps it)"))
        if not kept:
            questioned.add(idx)
    skipped: list[Skipped] = []
    for cal in identify_probe_calibration(run, skipped, skip_steps=questioned):
        if cal.channel not in cm.ai_names:
            fb.notes.append(f"{cal.channel}: calibrated in {label} but not in the map")
            continue
        ch = cm.ai_channel(cal.channel)
        old_mil = ch.gain_v_per_unit * MIL_M * 1e3
        found = (f"{cal.gain_mv_per_mil:.1f} mV/mil ({cal.gain_v_per_m:.6g} V/m), R^2 "
                 f"{cal.r2:.4f}, +/-{cal.u_gain_rel * 100:.1f} %, {cal.n_points} points")
        if cal.r2 < MIN_R2:
            fb.notes.append(f"{ch.name}: {found}: R^2 under {MIN_R2}, not proposed (look at "
                            "the points, repeat the calibration)")
        elif abs(cal.gain_v_per_m / ch.gain_v_per_unit - 1) <= max(MIN_CHANGE, cal.u_gain_rel):
            fb.notes.append(f"{ch.name}: {found}: the map's {old_mil:.1f} mV/mil is within "
                            "its uncertainty, left as it is")
        else:
            fb.corrections.append(Correction(
                "ai", ch.name, "gain_v_per_unit", float(f"{cal.gain_v_per_m:.6g}"),
                f"probe calibration {label}: {found}; the map had {old_mil:.1f} mV/mil"))
        in_use = cal.gain_in_use_v_per_m
        if math.isfinite(in_use) and abs(in_use / ch.gain_v_per_unit - 1) > MIN_CHANGE:
            fb.notes.append(f"{ch.name}: the run was recorded with {in_use:.6g} V/m, the map "
                            f"now has {ch.gain_v_per_unit:.6g}: the volts were rebuilt with "
                            "the run's")
    fb.notes += [f"{s.channel or '-'}: {s.reason}" for s in skipped if s.channel]
    return fb


def _static(run: RunData, cm: ChannelMap) -> FlowBack:
    fb = FlowBack()
    label = run_label(run)
    pts: dict[str, list[tuple[float, float]]] = {}
    for st in run.steps:
        axis, idx = str(st.get("motion", "")), int(st["index"])
        if axis not in ("x", "y"):
            continue
        first, last = int(st["first_sample"]), int(st["last_sample"])
        if "gauge_force_n" in st:  # by hand: the entry against the probes and the rods
            f = float(st["gauge_force_n"])
            probes = [c for c in run.channel_names if re.fullmatch(rf"{axis}\d+", c)]
            if not probes:
                continue
            z = float(np.mean([np.mean(run.channel(p, first, last)) for p in probes]))
            f_rods = z * K_NOMINAL_N_PER_M[axis]
            if max(abs(f), abs(f_rods)) >= MIN_SIZE_N and \
                    not (f_rods != 0 and AGREE[0] <= f / f_rods <= AGREE[1]):
                fb.questions.append(
                    f"{label} step {idx} ({axis}): the force gauge entry "
                    f"{st.get('gauge_text', f'{f:g} N')!r} ({f:+.1f} N) while the probes read "
                    f"{z * 1e6:+.1f} um, {f_rods:+.1f} N on the rods' "
                    f"{K_NOMINAL_N_PER_M[axis] / 1e3:.0f} kN/m: check the entry")
            continue
        try:
            ao = cm.ao[cm.ao_for_axis(axis)]
        except KeyError:
            continue
        if ao.name not in run.drive_names or f"f{axis}" not in run.channel_names:
            continue
        volts = float(np.mean(run.channel(ao.name, first, last)))
        force = float(np.mean(run.channel(f"f{axis}", first, last)))
        pts.setdefault(axis, []).append((volts, force))
    for axis, p in sorted(pts.items()):
        ao = cm.ao[cm.ao_for_axis(axis)]
        v = np.array([a for a, _ in p])
        if len(p) < 3 or np.ptp(v) <= 0:
            fb.notes.append(f"{ao.name}: {len(p)} shaker-held point(s) in {label}: 3 at "
                            "different drives needed for its gain")
            continue
        fit = line_fit(v, np.array([b for _, b in p]))
        found = f"{fit.slope:.4g} N/V from {len(p)} static points, R^2 {fit.r2:.4f}"
        if fit.r2 < MIN_R2 or fit.slope <= 0:
            fb.notes.append(f"{ao.name}: {found}: not proposed")
        elif abs(fit.slope / ao.nominal_force_n_per_v - 1) < 0.02:
            fb.notes.append(f"{ao.name}: {found}: agrees with the map's "
                            f"{ao.nominal_force_n_per_v:g} N/V")
        else:
            fb.corrections.append(Correction(
                "ao", ao.name, "nominal_force_n_per_v", float(f"{fit.slope:.4g}"),
                f"static test {label}: {found}; the map had {ao.nominal_force_n_per_v:g}"))
    return fb
