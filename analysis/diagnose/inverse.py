"""Judging the force from the measured motion (inverse model), for data a replay cannot follow.

A replay from force to motion needs a restoring force: a body without a spring (a drive on a
rail, EMPS) drifts in an open-loop simulation, and its data are usually closed loop. The inverse
model predicts the measured force from the measured motion instead:

``F = M a + C v + K z + offset  [+ F_c sign(v)] [+ k3 z^3] [+ k2 z^2]``

Velocity and acceleration come from the displacement by a zero-phase 4th-order Butterworth
low-pass and central differences; the force is filtered the same way, so both sides see the
same band. Every term is linear in its parameter, so each model is a least-squares fit on the
training segments, judged on the held-out ones with the same criterion, bootstrap and verdict
against the signal (here the force) as the replay. A term found once the model leaves less
than 2 % of the signal, explaining less than 0.5 % of it and less than 3/4 of what was left, is a
refinement (low confidence; `verdict.refinement_share`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import butter, sosfiltfilt

from analysis.diagnose.candidates import bootstrap_gain
from analysis.diagnose.data import DiagnoseError, RunRecord, Segment, split_segments
from analysis.diagnose.model import Residuals
from analysis.diagnose.verdict import SignalFit, Verdict, judge, refinement_share

#: library effects the inverse model can hold, with their column and parameter name
INVERSE_EFFECTS = {
    "coulomb_friction": "friction_force_N",
    "cubic_stiffness": "k3_N_per_m3",
    "quadratic_stiffness": "k2_N_per_m2",
}
BASE_TERMS = ("mass_kg", "damping_Ns_per_m", "stiffness_N_per_m", "force_offset_N")


@dataclass
class InverseFinding:
    effect: str
    parameters: dict[str, float]
    error_before: float
    error_after: float
    gain: float
    gain_interval: tuple[float, float]
    evidence: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "parameters": self.parameters,
                "error_before": self.error_before, "error_after": self.error_after,
                "gain": self.gain, "gain_interval": list(self.gain_interval),
                "evidence": self.evidence}


@dataclass
class InverseDiagnosis:
    baseline_params: dict[str, float]
    baseline_rms: float
    findings: list[InverseFinding]
    final_params: dict[str, float]
    final_rms: float
    verdict: Verdict
    rounds: list[list[dict[str, Any]]]
    cutoff_hz: float
    train: list[Segment]
    test: list[Segment]
    notes: list[str] = field(default_factory=list)

    @property
    def unexplained(self) -> bool:
        return self.verdict.unexplained

    def to_dict(self) -> dict[str, Any]:
        return {
            "judged": "force from the measured motion (inverse model)",
            "baseline": {"kind": "fitted", "rms_error": self.baseline_rms, "units": "N",
                         "parameters": self.baseline_params},
            "findings": [f.to_dict() for f in self.findings],
            "final_parameters": self.final_params,
            "final_rms_error": self.final_rms,
            "unexplained": self.unexplained,
            "verdict": self.verdict.to_dict(),
            "candidates": self.rounds,
            "filter_cutoff_hz": self.cutoff_hz,
            "segments": {"train": len(self.train), "test": len(self.test)},
            "notes": self.notes,
        }


def _kinematics(rec: RunRecord, cutoff_hz: float) -> dict[str, np.ndarray]:
    """Filtered force, displacement, velocity and acceleration of the x axis (SI)."""
    axis = 0 if np.any(rec.force_n[0]) else 1
    chans = [v for c, v in rec.responses.items() if rec.response_axis[c] == axis]
    if not chans:
        raise DiagnoseError(f"{rec.name}: no displacement on the forced axis to judge the "
                            "force from")
    fs = rec.sample_rate_hz
    if not 0 < cutoff_hz < 0.45 * fs:
        raise DiagnoseError(f"filter cut-off {cutoff_hz} Hz must be within (0, {0.45 * fs:.4g})"
                            f" Hz for {rec.name} sampled at {fs:.4g} Hz")
    sos = butter(4, cutoff_hz, fs=fs, output="sos")
    z = sosfiltfilt(sos, np.mean(chans, axis=0))
    f = sosfiltfilt(sos, rec.force_n[axis])
    v = np.gradient(z, 1 / fs)
    a = np.gradient(v, 1 / fs)
    return {"f": f, "z": z, "v": v, "a": a}


def _columns(k: dict[str, np.ndarray], terms: list[str], a: int, b: int) -> np.ndarray:
    z = k["z"][a:b]
    zc = z - np.mean(k["z"])  # about the run's mean position (a spring's rest is unknown)
    col = {"mass_kg": k["a"][a:b], "damping_Ns_per_m": k["v"][a:b], "stiffness_N_per_m": zc,
           "force_offset_N": np.ones(b - a), "friction_force_N": np.sign(k["v"][a:b]),
           "k3_N_per_m3": zc**3, "k2_N_per_m2": zc**2}
    return np.column_stack([col[t] for t in terms])


def _fit(kin: list[dict[str, np.ndarray]], segs: list[Segment], terms: list[str]) -> np.ndarray:
    rows = [_columns(kin[s.run], terms, s.start, s.stop) for s in segs]
    rhs = [kin[s.run]["f"][s.start:s.stop] for s in segs]
    a = np.vstack(rows)
    scale = np.maximum(np.sqrt(np.mean(a**2, axis=0)), 1e-300)
    sol, *_ = np.linalg.lstsq(a / scale, np.concatenate(rhs), rcond=None)
    return np.asarray(sol / scale)


def _residuals(kin: list[dict[str, np.ndarray]], segs: list[Segment], terms: list[str],
               theta: np.ndarray) -> Residuals:
    per = {s: {"force": kin[s.run]["f"][s.start:s.stop]
               - _columns(kin[s.run], terms, s.start, s.stop) @ theta} for s in segs}
    return Residuals(per, {}, {})


def diagnose_inverse(records: list[RunRecord],
                     train_spans: list[tuple[int, int]] | None = None,
                     test_spans: list[tuple[int, int]] | None = None,
                     cutoff_hz: float | None = None, seed: int = 0, max_effects: int = 3,
                     min_gain: float = 1.05, min_gain_lo: float = 0.999) -> InverseDiagnosis:
    """Judge the measured force from the measured motion; find the library terms it misses."""
    if not records:
        raise DiagnoseError("no runs to diagnose")
    fs = min(r.sample_rate_hz for r in records)
    fc = cutoff_hz if cutoff_hz is not None else min(100.0, 0.1 * fs)
    kin = [_kinematics(r, fc) for r in records]
    train, test = split_segments(records, train_spans, test_spans)
    # the "measured" signal the verdict judges is the filtered force
    frecs = [RunRecord(name=r.name, sample_rate_hz=r.sample_rate_hz, force_n=r.force_n,
                       responses={"force": k["f"]}, response_axis={"force": 0})
             for r, k in zip(records, kin, strict=True)]
    terms = list(BASE_TERMS)
    theta = _fit(kin, train, terms)
    base_test = _residuals(kin, test, terms, theta)
    base_params = dict(zip(terms, (float(v) for v in theta), strict=True))
    n_test = sum(s.n for s in test)
    cur_test, cur_terms, cur_theta = base_test, terms, theta
    cur_crit = n_test * math.log(cur_test.rms() ** 2) + len(terms) * math.log(n_test)
    findings: list[InverseFinding] = []
    rounds: list[list[dict[str, Any]]] = []
    for _ in range(max_effects):
        cands = []
        rejected = []
        for eff, name in INVERSE_EFFECTS.items():
            if name in cur_terms:
                continue
            t2 = [*cur_terms, name]
            th = _fit(kin, train, t2)
            if name == "friction_force_N" and th[-1] <= 0:
                rejected.append({"effect": eff, "not_a_finding": "friction force on its bound "
                                 "(0 or negative)", "parameters": {name: float(th[-1])}})
                continue
            res = _residuals(kin, test, t2, th)
            crit = n_test * math.log(res.rms() ** 2) + len(t2) * math.log(n_test)
            cands.append((crit, eff, name, t2, th, res))
        cands.sort(key=lambda c: c[0])
        before = cur_test.rms()
        rounds.append([{"effect": c[1], "parameters": {c[2]: float(c[4][-1])},
                        "held_out_error": c[5].rms(), "gain": before / c[5].rms(),
                        "criterion": c[0]} for c in cands] + rejected)
        if not cands:
            break
        crit, eff, name, t2, th, res = cands[0]
        gain = before / res.rms()
        lo, hi = bootstrap_gain(cur_test, res, test, seed + len(findings))
        if not (crit < cur_crit and gain >= min_gain and lo >= min_gain_lo):
            break
        params = {name: float(th[-1])}
        findings.append(InverseFinding(eff, params, before, res.rms(), gain, (lo, hi),
                                       {"criterion_before": cur_crit, "criterion_after": crit}))
        cur_test, cur_terms, cur_theta, cur_crit = res, t2, th, crit
    verdict = judge(frecs, base_test, cur_test, test, {})
    sig = verdict.final.signal_rms

    def fit_of(rms: float) -> SignalFit:  # no noise floor here: the force's own error
        return SignalFit(1.0 - (rms / sig) ** 2, sig, rms, 0.0)

    for f in findings:
        refinement, share = refinement_share(fit_of(f.error_before), fit_of(f.error_after))
        f.evidence["share_of_signal_explained"] = share
        if refinement:
            f.evidence["refinement"] = True
        weak = verdict.unexplained or not verdict.adequate or refinement
        f.evidence["confidence"] = "low" if weak else "high"
    final = dict(zip(cur_terms, (float(v) for v in cur_theta), strict=True))
    for f in findings:  # parameters as in the final joint fit
        f.parameters = {k: final[k] for k in f.parameters}
    notes = [f"force judged from the measured motion (inverse model); velocity and "
             f"acceleration by central differences after a zero-phase Butterworth low-pass at "
             f"{fc:.4g} Hz (force filtered alike)"]
    return InverseDiagnosis(base_params, base_test.rms(), findings, final, cur_test.rms(),
                            verdict, rounds, fc, train, test, notes)
