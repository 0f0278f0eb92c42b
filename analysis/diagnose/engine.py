"""Diagnose: baseline, candidate effects fitted on training data and judged on held-out data.

``diagnose`` runs the steps; the fitted baseline and its order are ``baseline.py``, the rules a
candidate meets ``candidates.py``, the evidence for and against a finding ``evidence.py``, the
verdict against the signal ``verdict.py``.

Procedure
---------
1. Baseline. ``config``: the rig configuration as it stands. ``fitted``: mass, damping and
   stiffness per axis fitted to the training data by output error (each response channel's
   offset in closed form), starting (imported data) from an equation-error ARX estimate.
2. Round after round (at most ``max_effects``): every applicable effect of the library not yet
   found is fitted on the training segments (its own parameters, the rest held), judged on the
   held-out segments by RMS error and by the criterion ``N ln(MSE_held_out) + k ln(N)`` (N
   held-out residual samples, k fitted parameters), lowest first; the two best are refitted
   jointly with the baseline's own parameters (fitted baseline) and the earlier findings, and
   re-ranked. (An effect that explains nothing alone may matter next to another: a quadratic
   spring beside a cubic one, so every round tries every effect.) The best is a finding only if
   it is significant, else the next in that order that is (`_significance`):
   its criterion beats the current model's, its held-out gain (RMS before / after) is at least
   ``min_gain`` or its signature on the held-out dwells stands ``Z_STRUCTURE`` noise sd above
   the noise (``residual_structure.signature_sd``: over every dwell, or among dwells of one
   frequency against the noise alone), and the lower end of the bootstrap
   interval of the gain (held-out segments resampled with replacement, seeded) is at least
   ``min_gain_lo`` (0.999: in 97.5 % of the resamples the effect does not raise the held-out
   error; resamples holding only segments the effect leaves untouched, e.g. dwells that do not
   move the faulty probe's axis, give 1; an overfitted effect makes some held-out segments
   worse).
   Samples of one segment are correlated, so the criterion alone would be lax: the bootstrap
   over whole segments is the significance check.
   Not a finding, whatever its held-out gain: a term that raises the training error, one
   whose fitted parameter sits on a bound of its fit, a mode outside the excited band.
3. Verdict against the signal (``verdict.py``): the held-out fraction of the signal above the
   noise floor that the baseline and the final model explain. Below 90 % (and not brought there
   by the first finding alone) the verdict is "baseline inadequate" (with the residual's
   spectral peaks and the channels explained worst); above it, a share of more than 2 % left is
   "unexplained", and so is any structure the final model leaves above the residual's own
   noise (``residual_structure``: against amplitude, time, frequency, oil temperature, a
   repeated dwell, harmonics, the other axis). Under either, and when a baseline parameter sits
   on a bound, every finding is low-confidence, except beside structure alone when the findings
   removed nearly all of the baseline's (``verdict.STRUCTURE_LEFT``); so is a finding whose
   runner-up (significant itself, not found itself in a later round) the held-out data do
   not tell from it (its excess squared error, the replay's resolution taken off, under 5 sd
   of the noise floor, and so among dwells of one frequency: ``distinguish``), one on dwells
   beside structure left whose own signature is under 5 sd (a stand-in for part of a misfit),
   one whose own signature does not stand above the largest structure left by its effect's
   tolerance (that misfit could have moved its size by more: ``_misfit_left_sd``),
   and a refinement: a term found once the model already left
   nothing unexplained (no structure above the noise either), explaining less than 0.5 % of the
   signal and, on dwells, a signature under 5 sd of their own noise (elsewhere less than 3/4
   of what was left; ``verdict.refinement_share``).
4. Sizes (``precision``): each finding is reported with its parameters as the final model
   holds them (every finding refitted jointly in the last round) and their standard
   deviations from the training residual's own noise (Jacobian at the final model, per sample
   and per segment, the larger). A finding whose main parameter's doubt (its sd and its move
   since the round it was found in, in quadrature) exceeds its effect's tolerance
   (``Effect.tolerance``) is low-confidence: the right cause at an unsure size is not said
   confidently.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from analysis.diagnose import residual_analysis as ra
from analysis.diagnose.amplitude import AmplitudeDependence, check_levels
from analysis.diagnose.baseline import (
    Baseline,
    baseline_modes,
    choose_order,
    data_start,
    fit_linear,
    fit_subset,
    is_imported,
    modes_per_axis,
    second_mode_finding,
)
from analysis.diagnose.candidates import (
    Candidate,
    Finding,
    Problem,
    bootstrap_gain,
    criterion,
    judge_candidate,
    not_a_finding,
    on_bound,
    total_sse,
)
from analysis.diagnose.data import (
    DiagnoseError,
    RunRecord,
    Segment,
    split_by_runs,
    split_segments,
)
from analysis.diagnose.distinguish import held_out_difference
from analysis.diagnose.effects import LIBRARY, Context, Effect, Variant, extended_rig, parameters_of
from analysis.diagnose.evidence import effect_evidence, sensor_pair_check, swap_check
from analysis.diagnose.fitting import (
    FitResult,
    Following,
    fit,
    fit_failure,
    following,
    train_sse,
)
from analysis.diagnose.hysteresis import amplitude_levels, joint_table
from analysis.diagnose.model import Evaluator, Model, Param, Residuals, residuals
from analysis.diagnose.modes import Modes, modal_dependence
from analysis.diagnose.oil import drift_course, mean_temperature
from analysis.diagnose.precision import determined, doubt, parameter_sd
from analysis.diagnose.residual_structure import (
    Z_STRUCTURE,
    excess_chi2,
    find_structure,
    signature_sd,
)
from analysis.diagnose.start import stands_above_noise
from analysis.diagnose.verdict import (
    STRUCTURE_LEFT,
    Verdict,
    excited_band,
    judge,
    refinement_share,
    signal_fit,
)
from analysis.diagnose.whole_record import account, fundamental_excess
from rig_model.params import RigParams

__all__ = ["Diagnosis", "Finding", "diagnose"]


@dataclass
class Diagnosis:
    baseline_kind: str
    units: str
    records: list[RunRecord]
    train: list[Segment]
    test: list[Segment]
    baseline_model: Model
    baseline_params: dict[str, float]
    baseline_train: Residuals
    baseline_test: Residuals
    findings: list[Finding]
    final_model: Model
    final_test: Residuals
    unexplained: bool
    rounds: list[list[dict[str, Any]]]
    skipped: dict[str, str]
    noise_floor: float | None
    extended_rig: RigParams
    elapsed_s: float
    notes: list[str] = field(default_factory=list)
    verdict: Verdict | None = None
    amplitude: AmplitudeDependence | None = None
    #: the modes in the band per level and axis (modal fit of the dwells' receptance)
    modes: Modes | None = None
    #: the fitted baseline's order chosen on held-out data: one row per order tried
    order: list[dict[str, Any]] = field(default_factory=list)

    @property
    def baseline_rms(self) -> float:
        return self.baseline_test.rms()

    def best_candidate(self) -> dict[str, Any] | None:
        """The first round's candidate of least held-out error, with its size and gain, when
        nothing was found (None otherwise, or when none could be fitted): what comes nearest,
        though not a finding (a rejected one carries why). A candidate with a parameter on a
        bound of its fit is none (the dry circular run's best was a micro-slip joint on its
        bounds, gain 1.000): its size says where the fit stopped, not what the data hold."""
        if self.findings or not self.rounds:
            return None
        fitted = [c for c in self.rounds[0] if "held_out_error" in c
                  and "on a bound" not in c.get("not_a_finding", "")]
        if not fitted:
            return None
        best = min(fitted, key=lambda c: c["held_out_error"])
        return {**best, "gain": self.baseline_rms / best["held_out_error"]}

    def residual_numbers(self) -> dict[str, Any]:
        """Held-out residuals of the baseline and the extended model: per dwell (1X amplitude
        and phase error, residual per harmonic, with frequency, amplitude and time), per
        segment (RMS against time), and their summary."""
        out: dict[str, Any] = {}
        for name, res in (("baseline", self.baseline_test), ("extended", self.final_test)):
            rows = ra.dwell_table(self.records, res, self.test)
            out[name] = {"summary": ra.summary(rows), "dwells": rows,
                         "segments": ra.segment_table(self.records, res, self.test)}
        return out

    def to_dict(self, extended_model_path: str | None = None) -> dict[str, Any]:
        return {
            "baseline": {"kind": self.baseline_kind, "rms_error": self.baseline_rms,
                         "units": self.units, "parameters": self.baseline_params,
                         "train_rms_error": self.baseline_train.rms(),
                         "modes_per_axis": max(modes_per_axis(self.baseline_model)
                                               .values()),
                         "modes": baseline_modes(self.baseline_model, self.records),
                         "coupled_axes": self.baseline_model.rig.structure
                         .stiffness_xy_n_per_m != 0.0,
                         "order_selection": self.order,
                         "modes_in_band_per_axis": self.modes.per_axis() if self.modes
                         else {}},
            "findings": [f.to_dict() for f in self.findings],
            "best_candidate": self.best_candidate(),
            "unexplained": self.unexplained,
            "extended_model": extended_model_path,
            "final_rms_error": self.final_test.rms(),
            "noise_floor": self.noise_floor,
            "segments": {"train": len(self.train), "test": len(self.test)},
            "residuals": self.residual_numbers(),
            "candidates": self.rounds,
            "not_applicable": self.skipped,
            "elapsed_s": self.elapsed_s,
            "notes": self.notes,
            "verdict": self.verdict.to_dict() if self.verdict else None,
            "amplitude_dependence": self.amplitude.to_dict() if self.amplitude else None,
            "modes": self.modes.to_dict() if self.modes else None,
            "train_runs": sorted({self.records[s.run].name for s in self.train}),
            "test_runs": sorted({self.records[s.run].name for s in self.test}),
        }


# --- main --------------------------------------------------------------------------------
# The fits' matrix products are small (a Jacobian of a few columns): on one BLAS thread they
# cost half the CPU and half the wall time that OpenBLAS's spinning threads take on 2 cores
# (25 dwells: 14.4 s CPU against 31.8 s; docs/benchmarks.md).
@threadpool_limits.wrap(limits=1, user_api="blas")
def diagnose(
    records: list[RunRecord],
    baseline: str | None = None,
    train_spans: list[tuple[int, int]] | None = None,
    test_spans: list[tuple[int, int]] | None = None,
    rig: RigParams | None = None,
    seed: int = 0,
    max_effects: int = 3,
    effects: list[str] | None = None,
    min_gain: float = 1.05,
    min_gain_lo: float = 0.999,
    fit_budget_steps: float = 4e5,
    log: Any = None,
    train_runs: list[int] | None = None,
) -> Diagnosis:
    """Diagnose the discrepancy between the rig model and measured runs.

    Parameters
    ----------
    records : list of RunRecord
        Measured runs (`analysis.diagnose.data.load_run`).
    baseline : {"config", "fitted"} or None
        None: "config" when the runs carry a rig configuration (or ``rig`` is given), else
        "fitted".
    train_spans, test_spans : list of (start, stop) or None
        Sample spans [samples] for fitting and for judging; None: whole dwells/blocks split.
    rig : RigParams or None
        Rig configuration overriding the runs' own.
    seed : int
        Seed of the bootstrap.
    effects : list of str or None
        Restrict the library to these effect ids.
    train_runs : list of int or None
        Indices of the runs to train on; the others are held out (no spans then).

    Returns
    -------
    Diagnosis
    """
    t_start = time.perf_counter()
    say = log or (lambda msg: None)
    kind, imported = _check_request(records, baseline, rig, effects)
    fitted = kind == "fitted"
    notes: list[str] = []
    base_rig, oversample = _replay_rig(records, rig, imported, notes)
    train, test = _split(records, train_spans, test_spans, train_runs)
    start_model, warmup_s = Model(rig=base_rig), 0.5
    if fitted:
        start_model, warmup_s = data_start(records, train, base_rig, notes, say)
    ev = _evaluator(records, train, warmup_s, oversample, notes)
    train, test = _settled(ev, train, notes), _settled(ev, test, notes)
    pb = _problem(ev, train, test, fit_budget_steps, notes)

    # 1. baseline, and (fitted) its order chosen on held-out data, before any effect: a
    # structure with two modes, or with its axes coupled by the rods, is no cause on top of a
    # one-mode, uncoupled baseline
    base = fit_linear(pb, start_model, records, fitted, say)
    say(f"baseline ({kind}): held-out RMS error {base.test.rms():.4g}")
    ctx = _context(pb, train, base.model, fitted)
    lo_hz, hi_hz = excited_band(records, train)
    band = (lo_hz / 1.25, hi_hz * 1.25)
    wanted = effects or list(LIBRARY)
    # the modes in the band per level, from the data alone: the starts of the modes the
    # fitted baseline's order adds beyond the kernel's
    modes = modal_dependence(records, train + test)
    say(f"modes in the band: {modes.text}")
    if fitted:
        base = choose_order(pb, ctx, base, band, seed, min_gain, min_gain_lo, say,
                            second_mode="second_mode" in wanted, modes=modes)
        ctx = replace(ctx, base=base.model)

    # 2. rounds of effects
    lib, skipped = _applicable(wanted, ctx, base.model, fitted)
    search = _search_effects(pb, ctx, lib, base, band, max_effects, seed, min_gain,
                             min_gain_lo, say)
    findings = search.findings

    # 3. verdict against the signal: what the baseline and the final model explain of it,
    # and the evidence that decides each finding's confidence
    noise = ra.noise_floor(ra.dwell_table(records, base.test, test))
    # structure left by the final model, over every dwell (training ones too: the repeated
    # dwell, the whole range of amplitude, time and temperature), against its own noise
    every = sorted(train + test, key=lambda s: (s.run, s.start))
    final_all = residuals(pb.ev, search.model, pb.fit_train, every)
    n_fitted = len(base.free) + sum(len(f.variant.params) for f in findings)
    structure = find_structure(records, final_all, every, n_fitted)
    # the baseline's structure: how much of it the findings explain
    base_structure = (find_structure(records, residuals(pb.ev, base.model, pb.fit_train, every),
                                     every, len(base.free)) if findings else structure)
    # the whole record: harmonics beyond 5X, lines between them, the 1X against the noise
    # and the replay's own error (``whole_record``)
    record = account(records, final_all, every,
                     _finer_replay(pb, search.model, every, final_all))
    _try_even_term(pb, ctx, lib, findings, search.model, every, record, say)
    verdict = judge(records, base.test, search.test, test, ra.channel_noise(records, test),
                    findings[0].test_residuals if findings else None, structure,
                    excess_chi2(base_structure), record)
    if findings and any(r["structure"] for r in record if r["test"] == "fundamental_at_noise"):
        # the 1X the findings leave against the baseline's: a finding beside a 1X pattern
        # it did not mostly remove may stand in for part of it
        base_all = residuals(pb.ev, base.model, pb.fit_train, every)
        before = account(records, base_all, every,
                         _finer_replay(pb, base.model, every, base_all))
        had = fundamental_excess(before)
        verdict.record_1x_left_share = fundamental_excess(record) / had if had > 0 else 1.0
    for row in verdict.structure + verdict.record:
        say(f"structure: {row['text']}")
    on_bound = _what_the_baseline_misses(verdict, base, findings, notes)
    for f in findings:
        if LIBRARY[f.effect].kind == "measurement":
            f.evidence.update(sensor_pair_check(pb, ctx, base.free, findings, f, search.model))
    _share_of_signal(records, test, base.test, findings)
    _sizes(pb, base, findings, search, say)
    _confidence(pb, base, findings, search, verdict, bool(on_bound))
    mode = second_mode_finding(pb, ctx, base) if fitted else None
    if mode is not None:
        mode.evidence["confidence"] = ("low" if _weak(verdict, bool(on_bound), mode)
                                       else "high")
    if not findings and verdict.unexplained:
        notes.append("the baseline misses something that no effect of the library explains")
    # amplitude dependence over the levels (runs or amplitude groups), of the data and of the
    # baseline's prediction; a finding the trend beyond the baseline argues against is low
    amplitude = check_levels(ev, base.model, pb.fit_train, train + test, base.train.offsets,
                             findings)
    say(f"amplitude dependence: {amplitude.text}")
    _more_modes_than_the_baseline(modes, base.model, notes)
    ext = extended_rig(search.model, ev.duration_s, ev.drift_anchor(search.model))
    if imported:
        ext = ext.model_copy(update={"substeps": int(min(32, max(oversample.values())))})
    return Diagnosis(
        baseline_kind=kind, units="m", records=records, train=train, test=test,
        baseline_model=base.model, baseline_params=base.params, baseline_train=base.train,
        baseline_test=base.test, findings=[mode, *findings] if mode else findings,
        final_model=search.model,
        final_test=search.test, unexplained=verdict.unexplained, rounds=search.rounds,
        skipped=skipped, noise_floor=noise, extended_rig=ext,
        elapsed_s=time.perf_counter() - t_start, notes=notes, verdict=verdict,
        amplitude=amplitude, modes=modes, order=base.order,
    )


def _try_even_term(pb: Problem, ctx: Context, lib: list[Effect], findings: list[Finding],
                   model: Model, segs: list[Segment], record: list[dict[str, Any]],
                   say: Any) -> None:
    """Where even harmonics stand out in the record (``whole_record``'s 2X, 4X, ... rows) and
    no finding is the library's even term, that term (``quadratic_stiffness``) fitted on top
    of the final model, and what it leaves of each such harmonic, entered in its row
    (``even_term_tried``; the verdict is not changed by it: a term tried after the rounds is no
    finding)."""
    even = [r for r in record if r["structure"] and r["test"] == "harmonic"
            and r["order"] % 2 == 0]
    eff = next((e for e in lib if e.id == "quadratic_stiffness"), None)
    if not even or eff is None or any(f.effect == eff.id for f in findings):
        return
    best: tuple[FitResult, Variant] | None = None
    try:
        for var in eff.variants(ctx, model):
            res = fit(pb.ev, var.starts, var.params, pb.fit_train, pb.scale_m, step=pb.step,
                      keep=var.keep)
            if best is None or res.train_sse < best[0].train_sse:
                best = (res, var)
    except Exception as err:
        if fit_failure(err) is None:
            raise
        return
    if best is None:
        return
    res, var = best
    params = parameters_of(var, res.model)
    after = account(pb.ev.records, residuals(pb.ev, res.model, pb.fit_train, segs), segs)
    for row in even:
        left = next((a for a in after if a["test"] == "harmonic" and a["channel"]
                     == row["channel"] and a["order"] == row["order"]), None)
        if left is None:
            continue
        row["even_term_tried"] = {"effect": eff.id, "parameters": params,
                                  "z_after": left["z"]}
        k2 = next(iter(v for v in params.values() if isinstance(v, float)), math.nan)
        row["text"] += (f"; the library's even term tried (quadratic_stiffness, k2 = "
                        f"{k2:.4g}): {'it takes' if left['z'] < Z_STRUCTURE else 'it leaves'} "
                        f"this harmonic ({left['z']:.1f} sd after)")
        say(f"even term tried: {row['text']}")


def _finer_replay(pb: Problem, model: Model, segs: list[Segment],
                  res: Residuals) -> Residuals | None:
    """``model``'s residuals on the dwells of ``segs`` replayed in steady state, replayed
    again at twice the rate (the force band-limited between samples: a discretisation error
    falls at least fourfold), with ``res``'s offsets: what ``whole_record`` reads the replay's
    own error from. None where no dwell is replayed in steady state (a rig's own runs: their
    replay from rest keeps `residual_structure.RESOLUTION`)."""
    ev = pb.ev
    steady = [s for s in segs if ev.periodic_chunk(s)]
    if not steady:
        return None
    fine = Evaluator(ev.records, warmup_s=ev.warmup_s, steady_state_dwells=True,
                     oversample={i: 2 * ev.oversample.get(i, 1)
                                 for i in range(len(ev.records))},
                     weights=ev.weights, drift=ev.drift)
    return residuals(fine, model, pb.fit_train, steady, offsets=res.offsets)


def _more_modes_than_the_baseline(modes: Modes, baseline: Model, notes: list[str]) -> None:
    """A note where the band holds more modes than the baseline: its residual is then, at
    least in part, the modes it lacks (no effect of the library is one); and one where the
    baseline holds modes the extended rig file cannot."""
    if baseline.extra_modes:
        notes.append(f"the baseline holds {len(baseline.extra_modes)} linear mode(s) at the "
                     "output beyond the rig kernel's (JSON baseline.modes); the extended rig "
                     "TOML holds the kernel's modes only")
    held_per_axis = modes_per_axis(baseline)
    for ax, n in modes.per_axis().items():
        held = held_per_axis[ax]
        if n > held:
            notes.append(f"the band holds {n} modes on {ax} (modal fit of the dwells); the "
                         f"baseline holds {held}: its residual is in part the modes it lacks")


# --- set-up ------------------------------------------------------------------------------
def _check_request(records: list[RunRecord], baseline: str | None, rig: RigParams | None,
                   effects: list[str] | None) -> tuple[str, bool]:
    """The baseline's kind ("config" or "fitted") and whether the runs are imported data."""
    if not records:
        raise DiagnoseError("no runs to diagnose")
    imported = is_imported(records, rig)
    kind = baseline or ("fitted" if imported else "config")
    if kind not in ("config", "fitted"):
        raise DiagnoseError(f"--baseline must be 'config' or 'fitted', got {kind!r}")
    if kind == "config" and imported:
        raise DiagnoseError(
            "--baseline config needs a rig configuration, and these runs carry none "
            "(imported data): pass --rig RIG.toml or use --baseline fitted")
    unknown = [e for e in (effects or []) if e not in LIBRARY]
    if unknown:
        raise DiagnoseError(f"unknown effect(s) {unknown}; the library has {list(LIBRARY)}")
    return kind, imported


def _replay_rig(records: list[RunRecord], rig: RigParams | None, imported: bool,
                notes: list[str]) -> tuple[RigParams, dict[int, int]]:
    """The rig the runs are replayed through, and the force oversampling per run."""
    base_rig = rig or records[0].rig or RigParams()
    # replays leave the journal contact out: a run that touched it ended in a fault, imported
    # data has no journal, and the eccentricity law's fitted clearance may sit inside the orbit
    base_rig = base_rig.model_copy(update={"contact": base_rig.contact.model_copy(
        update={"enabled": False})})
    oversample: dict[int, int] = {}
    if imported:
        # imported data without a rig description: no seal; the film as the run file says
        # (its lubricated flag), linear (its centred damping and added mass: the eccentricity
        # law is the library's amplitude_dependent_damping, for the data to show, not a
        # prior of the baseline), the oil at a constant temperature: the mean it was recorded
        # at, where it was (eq. 1 gives the film's viscosity; a drift over the data is the
        # library's viscosity_drift); force interpolated between samples (see model.py)
        oil = {"warming_c_per_hour": 0.0}
        if (t_oil := mean_temperature(records)) is not None:
            oil["initial_temperature_c"] = t_oil
        base_rig = base_rig.model_copy(update={
            "seal": base_rig.seal.model_copy(update={"enabled": False}),
            "film": base_rig.film.model_copy(update={"eccentricity_law": False}),
            "oil": base_rig.oil.model_copy(update=oil)})
        for i, r in enumerate(records):
            oversample[i] = int(min(32, max(1, math.ceil(4000.0 / r.sample_rate_hz))))
        films = sorted({"linear film on (lubricated)" if r.lubricated else "film off (dry)"
                        for r in records})
        held = (f"; the oil held at {t_oil:.4g} C, its recorded mean" if t_oil is not None
                else "")
        notes.append(f"imported data without a rig description: seal off, {', '.join(films)}"
                     f"{held}; force oversampled x{oversample[0]} for the replay")
    rates = {r.sample_rate_hz for r in records}
    if len(rates) > 1:
        notes.append(f"runs at different sample rates {sorted(rates)}")
    return base_rig, oversample


def _split(records: list[RunRecord], train_spans: list[tuple[int, int]] | None,
           test_spans: list[tuple[int, int]] | None,
           train_runs: list[int] | None) -> tuple[list[Segment], list[Segment]]:
    if train_runs is not None:
        if train_spans is not None or test_spans is not None:
            raise DiagnoseError("give either --train/--test sample spans or --train-runs/"
                                "--test-runs, not both")
        return split_by_runs(records, train_runs)
    return split_segments(records, train_spans, test_spans)


def _evaluator(records: list[RunRecord], train: list[Segment], warmup_s: float,
               oversample: dict[int, int], notes: list[str]) -> Evaluator:
    # dwells of files from elsewhere sit back to back (what precedes a dwell is not its
    # settling): each is replayed in steady state, after whole periods of its own force
    steady = any(r.kind != "sweep" for r in records)
    # sensors of different quantities (probe, accelerometer) weighed by their noise
    weights = ra.noise_weights(records, ra.channel_noise(records, train, without_dwells=True))
    ev = Evaluator(records, warmup_s=warmup_s, oversample=oversample,
                   steady_state_dwells=steady, weights=weights,
                   drift=drift_course(records, Z_STRUCTURE))
    if weights:
        notes.append("fitted to every response channel, weighted by its noise (factor to "
                     "displacement-equivalent: " + ", ".join(
                         f"{ch} {w:.3g} s^{2 if ch.startswith('a') else 1}"
                         for ch, w in sorted(weights.items())) + ")")
    elif any(r.derived_displacement for r in records):
        notes.append("displacement derived from velocity or acceleration at import: fitted to "
                     "the derived displacement only (the sources hold the same information)")
    return ev


def _settled(ev: Evaluator, segs: list[Segment], notes: list[str]) -> list[Segment]:
    """``segs`` without the samples a replay from rest cannot get right.

    A segment replayed from rest has ``warmup_s`` before it to forget that start, except
    within ``warmup_s`` of its run's first sample. A run of this rig starts at rest (the
    daemon records from the drives' first sample); in data from elsewhere the initial state
    is unknown: there a segment's first samples (up to the warm-up, at most half the segment)
    are not scored. Scored, a start transient of a few milliseconds can outweigh seconds of
    data (the first 20 ms of an imported sweep: 12x the squared error of the rest).
    """
    out: list[Segment] = []
    for seg in segs:
        rec = ev.records[seg.run]
        warm = int(ev.warmup_s * rec.sample_rate_hz)
        if rec.rig is None and seg.start < warm and not ev.periodic_chunk(seg):
            start = max(seg.start, min(warm, seg.stop - seg.n // 2))
            notes.append(f"{rec.name}: samples {seg.start}-{start} not scored "
                         "(replayed from rest at the run's start: its initial state is unknown)")
            seg = replace(seg, start=start)
        out.append(seg)
    return out


def _problem(ev: Evaluator, train: list[Segment], test: list[Segment],
             fit_budget_steps: float, notes: list[str]) -> Problem:
    records = ev.records
    fit_train = fit_subset(ev, train, fit_budget_steps)
    if len(fit_train) < len(train):
        notes.append(f"fitted on {len(fit_train)} of {len(train)} training segments "
                     "(evenly spread) to bound the fitting time")
    resp = np.concatenate([v[s.start:s.stop] - np.mean(v[s.start:s.stop])
                           for s in fit_train for v in records[s.run].responses.values()])
    scale_m = float(np.sqrt(np.mean(resp**2))) or 1.0
    # residual samples used by the fit: about 10 per period of the 5th harmonic
    f_hi = max([s.freq_hz for s in train if s.freq_hz] or [0.0])
    step = max(1, int(min(r.sample_rate_hz for r in records) / (50 * f_hi))) if f_hi else 1
    return Problem(ev, fit_train, test, scale_m, step)


def _context(pb: Problem, train: list[Segment], base: Model, fitted: bool) -> Context:
    records = pb.ev.records
    f_rms = float(np.sqrt(np.mean(np.concatenate(
        [records[s.run].force_n[:, s.start:s.stop].ravel() for s in pb.fit_train]) ** 2)))
    freqs = [s.freq_hz for s in train if s.freq_hz]
    return Context(records=records, base=base, fitted_baseline=fitted,
                   duration_s=pb.ev.duration_s, x_rms_m=pb.scale_m, f_rms_n=f_rms,
                   f_typ_hz=float(np.median(freqs)) if freqs else _dominant_freq(
                       records, pb.fit_train))


def _dominant_freq(records: list[RunRecord], segs: list[Segment]) -> float:
    s = segs[0]
    rec = records[s.run]
    x = next(iter(rec.responses.values()))[s.start:s.stop]
    spec = np.abs(np.fft.rfft(x - x.mean()))
    f = np.fft.rfftfreq(x.size, 1 / rec.sample_rate_hz)
    return float(f[1:][np.argmax(spec[1:])])


def _applicable(wanted: list[str], ctx: Context, base: Model,
                fitted: bool) -> tuple[list[Effect], dict[str, str]]:
    """The library's effects to try, and why the others are not tried."""
    lib: list[Effect] = [LIBRARY[e] for e in wanted]
    skipped = {e.id: why for e in lib if (why := e.applicable(ctx)) is not None}
    if base.rig.effects.second_mode.enabled and fitted:
        skipped["second_mode"] = "in the baseline: its order was chosen on held-out data"
    return [e for e in lib if e.id not in skipped], skipped


# --- rounds of effects -------------------------------------------------------------------
@dataclass
class _Search:
    """The outcome of the rounds: findings, the final model and its held-out residuals."""
    findings: list[Finding]
    rounds: list[list[dict[str, Any]]]
    model: Model
    test: Residuals


def _search_effects(pb: Problem, ctx: Context, lib: list[Effect], base: Baseline,
                    band: tuple[float, float], max_effects: int, seed: int, min_gain: float,
                    min_gain_lo: float, say: Any) -> _Search:
    """Round after round, the best significant effect on top of the model so far."""
    free = list(base.free)
    findings: list[Finding] = []
    rounds: list[list[dict[str, Any]]] = []
    current, cur_test = base.model, base.test
    cur_crit, _ = criterion(cur_test, pb.test, len(free))
    # a second mode the baseline's order fitted with every parameter and did not choose is
    # screened again in the first round only (where the order's fit may have stopped short);
    # on a model with a nonlinear finding each of its 30 starts is a full replay (5 s CPU a
    # round on the harmonic-balance cases), and no later round found one
    later = [e for e in lib if not (e.id == "second_mode" and _order_tried_two_modes(base))]
    for _round in range(max_effects):
        # a fitted baseline follows each screened term (its parameters to first order): it
        # absorbed part of every term when it was fitted alone (``fitting.Following``)
        follow = following(pb.ev, current, base.free, pb.fit_train, pb.scale_m, pb.step)
        cands, unfitted = _screen(pb, ctx, lib if _round == 0 else later, findings, current,
                                  len(free), follow, say)
        cur_train = train_sse(pb.ev, current, pb.fit_train)[0]
        cands, rejected = _drop_non_findings(cands, cur_train, band, "")
        rejected += unfitted
        for r in rejected:
            say(f"  {r['effect']:28s} not a finding: {r['not_a_finding']}")
        if not cands:
            rounds.append(rejected)
            break
        cands.sort(key=lambda c: c.criterion)
        refit_failed: dict[str, str] = {}
        if free:
            # the two best are refitted jointly with the baseline's and earlier findings'
            # parameters (those the training dwells fix: `_refit_params`), and re-ranked
            joint = _refit_params(free, ctx, pb.fit_train)
            for i in range(min(2, len(cands))):
                cand = cands[i]
                k_joint = len(joint) + len(cand.variant.params)
                try:
                    res = fit(pb.ev, [cand.fit.model], joint + cand.variant.params,
                              pb.fit_train, pb.scale_m, max_nfev=20 * (k_joint + 1),
                              step=pb.step)
                    if res.train_sse <= cand.fit.train_sse:
                        cands[i] = judge_candidate(pb, cand.effect, cand.variant, res,
                                                   len(free))
                except Exception as err:
                    why = fit_failure(err)
                    if why is None:
                        raise
                    # the screened fit stands; the joint refit's failure is on record
                    refit_failed[cand.effect] = f"joint refit {why}"
                    say(f"  joint refit {cand.effect:16s} {why}")
                say(f"  joint refit {cand.effect:16s} held-out {cands[i].test_rms:.4g}")
            # a joint refit may move a parameter onto its bound or raise the training error
            cands, more = _drop_non_findings(cands, cur_train, band, "joint refit: ")
            rejected += more
            if not cands:
                rounds.append(rejected)
                break
            cands.sort(key=lambda c: c.criterion)
        before = cur_test.rms()
        rounds.append([{
            "effect": c.effect, "parameters": parameters_of(c.variant, c.fit.model),
            "held_out_error": c.test_rms, "gain": before / c.test_rms, "criterion": c.criterion,
            "train_error": math.sqrt(c.fit.train_sse / c.fit.train_n), "n_params": c.k,
            **({"joint_refit": refit_failed[c.effect]} if c.effect in refit_failed else {}),
        } for c in cands] + rejected)
        # the best by the criterion, else the best after it that is significant: the
        # criterion weighs every sample, noise included, so a term at the replay's resolution
        # can rank above one whose signature stands above the noise among the dwells
        judged = partial(_significance, pb, ctx, cur_test=cur_test, cur_crit=cur_crit,
                         min_gain=min_gain, min_gain_lo=min_gain_lo, seed=seed + len(findings))
        seen: dict[int, _Significance] = {}  # a runner-up ranked first was judged here
        for i, top in enumerate(cands):
            sig = seen[id(top)] = judged(top)
            say(f"round {len(rounds)}: {'best' if i == 0 else 'next'} {top.effect} "
                f"{sig.text()}")
            if sig.significant:
                break
        if not sig.significant:
            break
        gain, (lo, hi), signature = sig.gain, sig.interval, sig.signature
        runner = next((c for c in cands if c is not top), None)
        evidence: dict[str, Any] = {
            "train_error_before": math.sqrt(total_sse(residuals(pb.ev, current, pb.fit_train))
                                            / top.fit.train_n),
            "train_error_after": math.sqrt(top.fit.train_sse / top.fit.train_n),
            "criterion_before": cur_crit, "criterion_after": top.criterion,
            "n_params": len(top.variant.params),
            "held_out_segments": len(pb.test),
            "signature_sd": signature,
        }
        if runner is not None:
            # the runner-up is told apart when its held-out squared error stands
            # ``Z_DISTINCT`` sd of the data's noise above the top's (``distinguish``)
            diff = held_out_difference(ctx.records, runner.test, top.test, pb.test)
            # a runner-up that is not significant itself explains nothing above the noise:
            # no rival cause, however close its held-out error
            rival = (seen.get(id(runner)) or judged(runner)).significant
            evidence["runner_up"] = {"effect": runner.effect,
                                     "gain": before / runner.test_rms,
                                     "parameters": parameters_of(runner.variant,
                                                                 runner.fit.model),
                                     **diff.to_dict(), "significant": rival}
            evidence["ambiguous"] = rival and not diff.distinct
        evidence.update(effect_evidence(top.effect, ctx.records, pb.test, cur_test, top.test))
        if top.effect == "joint_microslip":
            evidence["describing_function"] = _joint_describing_function(
                ctx, top.fit.model, pb.fit_train + pb.test)
        findings.append(Finding(top.effect, parameters_of(top.variant, top.fit.model), before,
                                top.test_rms, gain, (lo, hi), evidence, top.fit.model,
                                top.variant, runner, top.test))
        free = free + top.variant.params
        current, cur_test, cur_crit = top.fit.model, top.test, top.criterion
    return _Search(findings, rounds, current, cur_test)


def _order_tried_two_modes(base: Baseline) -> bool:
    """Whether the fitted baseline's order fitted two modes per axis (its row in the order
    table, chosen or not)."""
    return any(r.get("modes_per_axis") == 2 and not r.get("coupled_axes")
               and "extra_mode" not in r for r in base.order)


@dataclass(frozen=True)
class _Significance:
    """A candidate's held-out gain (with its bootstrap interval), its signature in noise sd
    and whether that makes it a finding."""

    gain: float
    interval: tuple[float, float]
    signature: float
    significant: bool

    def text(self) -> str:
        lo, hi = self.interval
        return (f"gain {self.gain:.3g} [{lo:.3g}, {hi:.3g}], signature {self.signature:.3g} sd"
                f"{'' if self.significant else ' (not significant)'}")


def _significance(pb: Problem, ctx: Context, cand: Candidate, *, cur_test: Residuals,
                  cur_crit: float, min_gain: float, min_gain_lo: float,
                  seed: int) -> _Significance:
    """Whether ``cand`` is significant on top of the model whose held-out residuals are
    ``cur_test``: a better criterion, a held-out gain of ``min_gain`` or a signature
    ``Z_STRUCTURE`` sd above the noise, and a bootstrap interval above ``min_gain_lo``."""
    gain = cur_test.rms() / cand.test_rms
    lo, hi = bootstrap_gain(cur_test, cand.test, pb.test, seed)
    # the term's signature on the held-out dwells in noise sd: a small effect on a low-noise
    # record gains little RMS yet stands far above the noise
    signature = signature_sd(ctx.records, cur_test, cand.test, pb.test, cand.k)
    strong = gain >= min_gain or signature >= Z_STRUCTURE
    return _Significance(gain, (lo, hi), signature,
                         cand.criterion < cur_crit and strong and lo >= min_gain_lo)


def _refit_params(free: list[Param], ctx: Context, segs: list[Segment]) -> list[Param]:
    """The parameters a candidate's joint refit moves with its own: ``free`` without the
    spring of a still axis (`_still_axes`, on the dwells ``segs``).

    An axis no run drives and no dwell moves above its noise fixes its spring only through
    couplings at the noise's level (dry friction's direction along the velocity vector), so
    free, the fit's steps along it (scaled by its near-zero sensitivity) are large and
    nonlinear, and the refit spends its evaluations there while the driven axis's mass,
    damping and stiffness stay where the baseline absorbed the effect (15 N of seal friction
    on x dwells only: 115 of 120 evaluations used and 17.1 N; with y's spring held, 15.0 N in
    66). It keeps the baseline's value. An axis that responds (the film's cross terms moving
    y hundreds of sd above its noise) keeps its spring free: the response fixes it."""
    held = {f"stiffness_{'xy'[ax]}_N_per_m" for ax in _still_axes(ctx, segs)}
    return [p for p in free if p.name not in held]


def _still_axes(ctx: Context, segs: list[Segment]) -> set[int]:
    """The axes (where some axis is driven) that no run drives and whose every response
    channel's 1X stays within ``Z_STRUCTURE`` sd of its noise on every dwell of ``segs``
    (`start.stands_above_noise`). None without dwells: nothing shows an axis still."""
    driven = ctx.driven_axes()
    if not driven or not any(s.freq_hz for s in segs):
        return set()
    still = {0, 1} - driven
    for seg in segs:
        if not seg.freq_hz:
            continue
        rec = ctx.records[seg.run]
        fs = rec.sample_rate_hz
        for ch, (ax, _) in rec.objective_channels().items():
            if ax not in still:
                continue
            z, _, rest = ra.harmonics(rec.signal(ch)[seg.start:seg.stop], seg.start, fs,
                                      seg.freq_hz, 1)
            if stands_above_noise(abs(complex(z[0])), rest, seg.n):
                still.discard(ax)
    return still


def _joint_describing_function(ctx: Context, model: Model,
                               segs: list[Segment]) -> list[dict[str, Any]]:
    """The fitted joint's equivalent stiffness and loss stiffness at each amplitude level of
    the dwells (the 1X of the x displacement), at the data's typical frequency."""
    j = model.rig.effects.joint_microslip
    amps = []
    for seg in segs:
        rec = ctx.records[seg.run]
        chans = [c for c, a in rec.response_axis.items() if a == 0]
        if not seg.freq_hz or not chans:
            continue
        z, _, _ = ra.harmonics(rec.responses[chans[0]][seg.start:seg.stop], seg.start,
                               rec.sample_rate_hz, seg.freq_hz, 1)
        amps.append(abs(complex(z[0])))
    return joint_table(j.stiffness_n_per_m, j.slip_force_n, amplitude_levels(amps),
                       ctx.f_typ_hz, j.shape)


def _screen(pb: Problem, ctx: Context, lib: list[Effect], findings: list[Finding],
            current: Model, n_free: int, follow: Following | None,
            say: Any) -> tuple[list[Candidate], list[dict[str, Any]]]:
    """Every effect not yet found, its own parameters fitted (the rest held, or following to
    first order: ``follow``), judged; and a row for each that could not be fitted (why)."""
    cands: list[Candidate] = []
    unfitted: list[dict[str, Any]] = []
    for eff in lib:
        if any(f.effect == eff.id for f in findings):
            continue
        t0 = time.process_time()
        best: tuple[FitResult, Variant] | None = None
        try:
            for var in eff.variants(ctx, current):
                res = fit(pb.ev, var.starts, var.params, pb.fit_train, pb.scale_m,
                          step=pb.step, keep=var.keep, follow=follow if var.follow else None)
                if best is None or res.train_sse < best[0].train_sse:
                    best = (res, var)
            if best is None:
                continue
            res, var = best
            cand = judge_candidate(pb, eff.id, var, res, n_free)
        except Exception as err:
            why = fit_failure(err)
            if why is None:
                raise
            unfitted.append({"effect": eff.id, "not_a_finding": why})
            say(f"  {eff.id:28s} {why}")
            continue
        cands.append(cand)
        say(f"  {eff.id:28s} held-out {cands[-1].test_rms:.4g}  "
            f"({time.process_time() - t0:.1f} s CPU, {res.nfev} evaluations)")
    return cands, unfitted


def _drop_non_findings(cands: list[Candidate], cur_train: float, band: tuple[float, float],
                       prefix: str) -> tuple[list[Candidate], list[dict[str, Any]]]:
    """The candidates that can be findings, and a row for each that cannot."""
    kept: list[Candidate] = []
    rejected: list[dict[str, Any]] = []
    for cand in cands:
        why = not_a_finding(cand, cur_train, band)
        if why is None:
            kept.append(cand)
        else:
            rejected.append({"effect": cand.effect, "not_a_finding": prefix + why,
                             "parameters": parameters_of(cand.variant, cand.fit.model),
                             "held_out_error": cand.test_rms})
    return kept, rejected


# --- judgement of the findings -----------------------------------------------------------
def _what_the_baseline_misses(verdict: Verdict, base: Baseline, findings: list[Finding],
                              notes: list[str]) -> list[str]:
    """A second mode found on an inadequate baseline, and the baseline's parameters on a
    bound (returned), entered in the verdict's list of what is missing."""
    for f in findings:
        if f.effect == "second_mode" and not verdict.adequate:
            # a second mass-spring term helps: the baseline lacks a degree of freedom
            verdict.missing.setdefault("modes", []).append(
                {"term": "second_mode", **f.parameters})
    on_bound_ = [p.name for p in base.free if on_bound(p, base.model)]
    if on_bound_:
        verdict.missing["baseline_parameters_on_bound"] = on_bound_
        notes.append(f"baseline parameter(s) {on_bound_} on a bound of the fit: the baseline "
                     "does not describe the data")
    return on_bound_


def _share_of_signal(records: list[RunRecord], test: list[Segment], base_test: Residuals,
                     findings: list[Finding]) -> None:
    """Each finding's share of the held-out signal, and whether it is only a refinement."""
    noise_of = ra.channel_noise(records, test)
    before_res = base_test
    # dwells give each term's signature against their own noise; other data only the share
    dwells = any(s.freq_hz for s in test)
    for f in findings:
        assert f.test_residuals is not None
        refinement, share = refinement_share(
            signal_fit(records, before_res, test, noise_of),
            signal_fit(records, f.test_residuals, test, noise_of),
            float(f.evidence["signature_sd"]) if dwells and "signature_sd" in f.evidence
            else None)
        f.evidence["share_of_signal_explained"] = share
        # a model that left structure above the noise (held-out dwells) did not leave
        # "nothing unexplained": a term removing it is a cause, not a refinement
        if refinement and not any(r["structure"] for r in find_structure(
                records, before_res, test, 0)):
            f.evidence["refinement"] = True
        before_res = f.test_residuals


def _sizes(pb: Problem, base: Baseline, findings: list[Finding], search: _Search,
           say: Any) -> None:
    """Each finding's size as the final model holds it (the baseline and every finding
    refitted jointly in the last round: the model the extended rig is written from), with its
    standard deviation from the data's noise (``precision``), how far it moved since the round
    it was found in, and whether that pins it down to its effect's tolerance
    (``evidence["size"]``)."""
    params = list(base.free) + [p for f in findings for p in f.variant.params]
    prec = parameter_sd(pb.ev, search.model, params, pb.fit_train, pb.scale_m, pb.step)
    sds = dict(zip(map(id, params), zip(prec.sd, prec.per_sample, prec.per_segment,
                                        prec.per_spectrum, strict=True), strict=True))
    for f in findings:
        eff = LIBRARY[f.effect]
        found = dict(f.parameters)
        f.parameters = parameters_of(f.variant, search.model)
        # the effect's main parameter, else the variant's first (cross_coupling fits only the
        # terms from the driven axis: c_yx where c_xy is the library's main)
        main = next((p for p in f.variant.params if p.name == eff.main), f.variant.params[0])
        value = f.parameters[main.name]
        shift = {p.name: f.parameters[p.name] - float(found[p.name]) for p in f.variant.params}
        sd, per_sample, per_segment, per_spectrum = sds[id(main)]
        ok = determined(value, sd, shift[main.name], eff.tolerance)
        f.evidence["size"] = {
            "main": main.name, "sd": {p.name: sds[id(p)][0] for p in f.variant.params},
            "sd_per_sample": per_sample, "sd_per_segment": per_segment,
            "sd_per_spectrum": per_spectrum,
            "when_found": {p.name: found[p.name] for p in f.variant.params},
            "shift_on_joint_refit": shift,
            "relative_doubt": doubt(sd, shift[main.name]) / max(abs(value), 1e-300),
            "tolerance": eff.tolerance, "determined": ok}
        say(f"size of {f.effect}: {main.name} {value:.5g} +- {sd:.3g} (found at "
            f"{float(found[main.name]):.5g}): "
            f"{'determined' if ok else 'not determined'} to {eff.tolerance:.0%}")


def _confidence(pb: Problem, base: Baseline, findings: list[Finding], search: _Search,
                verdict: Verdict, base_on_bound: bool) -> None:
    """High confidence only on an adequate baseline, a final model that leaves nothing of the
    signal unexplained and no structure beyond a small remainder of the baseline's, for a
    finding that is no refinement, whose cause is not ambiguous, whose size the data pin
    down to its effect's tolerance (``_sizes``) and which, on dwells beside structure left,
    removed structure itself (its signature)."""
    dwells = any(s.freq_hz for s in pb.test)
    for f in findings:
        # a runner-up the held-out data do not tell from the finding leaves the cause
        # ambiguous, unless it was found too, or, swapped in for the finding next to the other
        # findings, its held-out error stands above the final model's beyond the noise
        found = {g.effect for g in findings}
        if f.evidence.get("ambiguous") and f.runner_up is not None:
            if f.runner_up.effect in found:
                f.evidence["ambiguous"] = False
            else:
                swapped = swap_check(pb, base.model, base.free, findings, f, search.model)
                if swapped is None:
                    f.evidence["runner_up"]["held_out_error_swapped"] = math.nan
                else:
                    diff = held_out_difference(pb.ev.records, swapped, search.test, pb.test)
                    f.evidence["runner_up"]["held_out_error_swapped"] = swapped.rms()
                    f.evidence["runner_up"]["swapped"] = diff.to_dict()
                    if diff.distinct:
                        f.evidence["ambiguous"] = False
        weak = _weak(verdict, base_on_bound, f)
        # a size the data do not pin down to the effect's tolerance is no confident finding
        vague = not f.evidence.get("size", {}).get("determined", True)
        # on dwells, a term that removes under Z_STRUCTURE sd of structure is significant by
        # its RMS gain alone: beside structure the final model leaves, it stands in for part
        # of a misfit rather than naming a cause (the independent rig's friction at seed 5: a
        # 0.3 % probe gain, 0.17 sd, beside 95 sd left within frequencies)
        stand_in = (dwells and bool(verdict.structure)
                    and float(f.evidence.get("signature_sd", math.inf)) < Z_STRUCTURE)
        # beside structure left, the misfit's size in noise sd over the finding's own
        # signature bounds how far the misfit can have moved the finding's size (relative;
        # all of the misfit along the finding's direction): more than the effect's tolerance
        # and the size is not pinned down by the data. The harmonic-balance generator's
        # friction and cubic spring (dev seeds 6201-6202): k3 removed 21.7 and 16.5 sd beside
        # 23 and 17.7 sd left (the record's 3X-9X and the 1X within frequencies, what its
        # 21-harmonic seal does that exact Coulomb friction does not), and came out -18.7 %
        # and -3.1 % with per-sample sds of 1.1 % and 0.8 %; the friction (810 and 528 sd)
        # within 0.2 %
        left = _misfit_left_sd(verdict) if dwells else 0.0
        signature = float(f.evidence.get("signature_sd", math.inf))
        misfit = left > 0.0 and left > LIBRARY[f.effect].tolerance * signature
        f.evidence["misfit_left_sd"] = left
        f.evidence["confidence"] = ("low" if (weak or vague or stand_in or misfit
                                              or f.evidence.get("ambiguous")) else "high")


def _misfit_left_sd(verdict: Verdict) -> float:
    """The largest structure the final model leaves, in noise sd (0: none): the residual's
    structure tests and the whole record's rows."""
    rows = [r for r in verdict.structure + verdict.record if r.get("structure", True)]
    return max((float(r["z"]) for r in rows), default=0.0)


def _weak(verdict: Verdict, base_on_bound: bool, f: Finding) -> bool:
    """Whether the final model leaves too much for ``f`` to be named with confidence: the
    signal not explained, an inadequate baseline or one on a bound, a refinement, or structure
    left in the residual (or a 1X pattern in the whole record, ``whole_record``'s
    ``fundamental_at_noise``) unless the findings explain nearly all of the baseline's
    (``verdict.STRUCTURE_LEFT``)."""
    return (verdict.signal_unexplained or not verdict.adequate or base_on_bound
            or f.evidence.get("refinement", False)
            or (bool(verdict.structure) and not verdict.structure_mostly_explained)
            or verdict.record_1x_left_share > STRUCTURE_LEFT)
