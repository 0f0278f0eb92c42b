"""Diagnose: baseline, candidate effects fitted on training data and judged on held-out data.

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
   it is significant:
   its criterion beats the current model's, its held-out gain (RMS before / after) is at least
   ``min_gain``, and the lower end of the bootstrap interval of the gain (held-out segments
   resampled with replacement, seeded) is at least ``min_gain_lo`` (0.999: in 97.5 % of the
   resamples the effect does not raise the held-out error; resamples holding only segments the
   effect leaves untouched, e.g. dwells that do not move the faulty probe's axis, give 1; an
   overfitted effect makes some held-out segments worse).
   Samples of one segment are correlated, so the criterion alone would be lax: the bootstrap
   over whole segments is the significance check.
   Not a finding, whatever its held-out gain: a term that raises the training error, one
   whose fitted parameter sits on a bound of its fit, a mode outside the excited band.
3. Verdict against the signal (``verdict.py``): the held-out fraction of the signal above the
   noise floor that the baseline and the final model explain. Below 90 % (and not brought there
   by the first finding alone) the verdict is "baseline inadequate" (with the residual's
   spectral peaks and the channels explained worst); above it, a share of more than 2 % left is
   "unexplained". Under either, and when a baseline parameter sits on a bound, every finding is
   low-confidence; so is a finding whose runner-up (not found itself in a later round) explains
   the held-out data nearly as well (held-out MSE within 25 %), and a refinement: a term found
   once the model already left nothing unexplained, explaining less than 0.5 % of the signal and
   less than 3/4 of what was left (``verdict.refinement_share``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from analysis.diagnose import residual_analysis as ra
from analysis.diagnose.amplitude import AmplitudeDependence, check_levels
from analysis.diagnose.data import (
    DiagnoseError,
    RunRecord,
    Segment,
    split_by_runs,
    split_segments,
)
from analysis.diagnose.effects import (
    LIBRARY,
    Context,
    Effect,
    Variant,
    extended_rig,
    parameters_of,
)
from analysis.diagnose.fitting import FitResult, arx_linear_guess, fit, train_sse
from analysis.diagnose.model import Evaluator, Model, Param, Residuals, residuals, rig_param
from analysis.diagnose.start import OneMode, one_mode_estimate
from analysis.diagnose.verdict import Verdict, excited_band, judge, refinement_share, signal_fit
from simulated_hw.params import RigParams


@dataclass
class Candidate:
    effect: str
    variant: Variant
    fit: FitResult
    test: Residuals
    test_rms: float
    criterion: float
    k: int


@dataclass
class Finding:
    effect: str
    parameters: dict[str, Any]
    error_before: float
    error_after: float
    gain: float
    gain_interval: tuple[float, float]
    evidence: dict[str, Any]
    model: Model
    variant: Variant
    runner_up: Candidate | None = None
    test_residuals: Residuals | None = None  # held-out residuals of the model with it

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "parameters": self.parameters,
                "error_before": self.error_before, "error_after": self.error_after,
                "gain": self.gain, "gain_interval": list(self.gain_interval),
                "evidence": self.evidence}


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
    #: the fitted baseline's order chosen on held-out data: one row per order tried
    order: list[dict[str, Any]] = field(default_factory=list)

    @property
    def baseline_rms(self) -> float:
        return self.baseline_test.rms()

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
                         "modes_per_axis": 2 if self.baseline_model.rig.effects.second_mode
                         .enabled else 1,
                         "order_selection": self.order},
            "findings": [f.to_dict() for f in self.findings],
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
            "train_runs": sorted({self.records[s.run].name for s in self.train}),
            "test_runs": sorted({self.records[s.run].name for s in self.test}),
        }


# --- baseline ----------------------------------------------------------------------------
def _imported(records: list[RunRecord], rig: RigParams | None) -> bool:
    return rig is None and all(r.rig is None for r in records)


def baseline_params(model: Model, records: list[RunRecord], imported: bool) -> list[Param]:
    st = model.rig.structure
    c_crit = 2 * math.sqrt(st.stiffness_x_n_per_m * st.mass_kg)
    ps = [
        rig_param("mass_kg", "structure.mass_kg", 0.05 * st.mass_kg, 1e-3 * st.mass_kg),
        rig_param("damping_Ns_per_m", "structure.residual_damping_ns_per_m",
                  0.1 * max(st.residual_damping_ns_per_m, 0.02 * c_crit), 0.0),
        rig_param("stiffness_x_N_per_m", "structure.stiffness_x_n_per_m",
                  0.02 * st.stiffness_x_n_per_m, 1e-3 * st.stiffness_x_n_per_m),
    ]
    if any(1 in r.axes for r in records):
        ps.append(rig_param("stiffness_y_N_per_m", "structure.stiffness_y_n_per_m",
                            0.02 * st.stiffness_y_n_per_m, 1e-3 * st.stiffness_y_n_per_m))
    # Offsets: each response channel's offset is fitted in closed form (model.residuals); a
    # force offset would be redundant with it for a linear structure (and ill-conditioned).
    return ps


def _fit_subset(ev: Evaluator, train: list[Segment], budget: float) -> list[Segment]:
    """Evenly spread training segments whose simulation work stays within ``budget`` steps."""
    def work(s: Segment) -> float:
        rec = ev.records[s.run]
        sub = ev.oversample.get(s.run, 1)
        return (s.n + ev.warmup_s * rec.sample_rate_hz) * sub
    total = sum(work(s) for s in train)
    if total <= budget:
        return train
    k = max(2, int(len(train) * budget / total))
    idx = np.unique(np.linspace(0, len(train) - 1, k).round().astype(int))
    return [train[i] for i in idx]


def _data_start(records: list[RunRecord], train: list[Segment], base_rig: RigParams,
                notes: list[str], say: Any) -> tuple[Model, float]:
    """Start of the fitted baseline from the data alone, and the replay's warm-up [s].

    A frequency-domain fit of the dynamic stiffness per axis (``start.py``), the film's known
    added mass and centred damping taken off when the runs are lubricated; the equation-error
    ARX estimate where that has too few points. The warm-up before each replayed segment covers
    four decay times of the estimated mode (at least 0.5 s, at most 30 s), so a lightly damped
    structure has forgotten its start from rest before it is scored.
    """
    film = base_rig.film
    lub = any(r.lubricated for r in records)
    d_mass = film.fluid_mass_kg + film.added_mass() if lub else 0.0
    d_damp = (film.eq16_damping_centred(film.viscosity_pa_s(base_rig.oil.initial_temperature_c))
              if lub else 0.0)
    est = {ax: one_mode_estimate(records, train, ax, d_mass, d_damp) for ax in (0, 1)}
    st = base_rig.structure
    x, y = est[0], est[1]
    if x is None and y is None:
        try:
            m_kg, c, k, _ = arx_linear_guess(records[0], train)
        except ValueError as err:
            raise DiagnoseError(f"cannot start the fitted baseline: {err}") from None
        x = OneMode(m_kg, c, k, 0)
        notes.append("fitted baseline started from an equation-error (ARX) estimate")
    first = x if x is not None else y
    assert first is not None
    update = {"mass_kg": first.mass_kg, "residual_damping_ns_per_m": first.damping_ns_per_m,
              "stiffness_x_n_per_m": (x or first).stiffness_n_per_m,
              "stiffness_y_n_per_m": (y or first).stiffness_n_per_m}
    if first.damping_ns_per_m <= 0.0:
        update["residual_damping_ns_per_m"] = 0.02 * 2 * math.sqrt(
            first.stiffness_n_per_m * first.mass_kg)
    model = Model(rig=base_rig.model_copy(update={"structure": st.model_copy(update=update)}))
    tau = first.decay_time_s()
    warmup = float(min(30.0, max(0.5, 4 * tau)))
    say(f"start from the data: {first.natural_hz:.4g} Hz, damping ratio "
        f"{first.damping_ratio:.3g}, warm-up {warmup:.3g} s")
    notes.append(f"fitted baseline started from the data ({first.points} frequency points): "
                 f"{first.natural_hz:.4g} Hz, damping ratio {first.damping_ratio:.3g}; each "
                 f"replayed window starts {warmup:.3g} s early (four decay times) from rest")
    return model, warmup


# --- significance ------------------------------------------------------------------------
def bootstrap_gain(before: Residuals, after: Residuals, segs: list[Segment], seed: int,
                   n_boot: int = 2000) -> tuple[float, float]:
    """95 % percentile interval of RMS-before / RMS-after over resampled held-out segments."""
    sb = np.array([before.sse(s)[0] for s in segs])
    sa = np.array([after.sse(s)[0] for s in segs])
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(segs), size=(n_boot, len(segs)))
    ratio = np.sqrt(sb[idx].sum(axis=1) / np.maximum(sa[idx].sum(axis=1), 1e-300))
    lo, hi = np.percentile(ratio, [2.5, 97.5])
    return float(lo), float(hi)


def _criterion(res: Residuals, segs: list[Segment], k: int) -> tuple[float, int]:
    s, n = 0.0, 0
    for seg in segs:
        a, b = res.sse(seg)
        s += a
        n += b
    return n * math.log(max(s / n, 1e-300)) + k * math.log(n), n


# --- main --------------------------------------------------------------------------------
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
    if not records:
        raise DiagnoseError("no runs to diagnose")
    imported = _imported(records, rig)
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
    rates = {r.sample_rate_hz for r in records}
    notes: list[str] = []

    base_rig = rig or records[0].rig or RigParams()
    # replays leave the journal contact out: a run that touched it ended in a fault, imported
    # data has no journal, and the eccentricity law's fitted clearance may sit inside the orbit
    base_rig = base_rig.model_copy(update={"contact": base_rig.contact.model_copy(
        update={"enabled": False})})
    oversample: dict[int, int] = {}
    if imported:
        # imported data without a rig description: no seal; the film as the run file says
        # (its lubricated flag); force interpolated between samples (see model.py)
        base_rig = base_rig.model_copy(update={"seal": base_rig.seal.model_copy(
            update={"enabled": False})})
        for i, r in enumerate(records):
            oversample[i] = int(min(32, max(1, math.ceil(4000.0 / r.sample_rate_hz))))
        films = sorted({"film on (lubricated)" if r.lubricated else "film off (dry)"
                        for r in records})
        notes.append(f"imported data without a rig description: seal off, {', '.join(films)}; "
                     f"force oversampled x{oversample[0]} for the replay")
    if len(rates) > 1:
        notes.append(f"runs at different sample rates {sorted(rates)}")
    if train_runs is not None:
        if train_spans is not None or test_spans is not None:
            raise DiagnoseError("give either --train/--test sample spans or --train-runs/"
                                "--test-runs, not both")
        train, test = split_by_runs(records, train_runs)
    else:
        train, test = split_segments(records, train_spans, test_spans)
    start_model = Model(rig=base_rig)
    warmup_s = 0.5
    if kind == "fitted":
        start_model, warmup_s = _data_start(records, train, base_rig, notes, say)
    # dwells of files from elsewhere sit back to back (what precedes a dwell is not its
    # settling): each is replayed in steady state, after whole periods of its own force
    steady = any(r.kind != "sweep" for r in records)
    # sensors of different quantities (probe, accelerometer) weighed by their noise
    weights = ra.noise_weights(records, ra.channel_noise(records, train, without_dwells=True))
    ev = Evaluator(records, warmup_s=warmup_s, oversample=oversample,
                   steady_state_dwells=steady, weights=weights)
    if weights:
        notes.append("fitted to every response channel, weighted by its noise (factor to "
                     "displacement-equivalent: " + ", ".join(
                         f"{ch} {w:.3g} s^{2 if ch.startswith('a') else 1}"
                         for ch, w in sorted(weights.items())) + ")")
    elif any(r.derived_displacement for r in records):
        notes.append("displacement derived from velocity or acceleration at import: fitted to "
                     "the derived displacement only (the sources hold the same information)")
    fit_train = _fit_subset(ev, train, fit_budget_steps)
    if len(fit_train) < len(train):
        notes.append(f"fitted on {len(fit_train)} of {len(train)} training segments "
                     "(evenly spread) to bound the fitting time")
    resp = np.concatenate([v[s.start:s.stop] - np.mean(v[s.start:s.stop])
                           for s in fit_train for v in records[s.run].responses.values()])
    scale_m = float(np.sqrt(np.mean(resp**2))) or 1.0
    # residual samples used by the fit: about 10 per period of the 5th harmonic
    f_hi = max([s.freq_hz for s in train if s.freq_hz] or [0.0])
    step = max(1, int(min(r.sample_rate_hz for r in records) / (50 * f_hi))) if f_hi else 1
    model = start_model
    free: list[Param] = []
    free_base: list[Param] = []
    bparams: dict[str, float] = {}
    if kind == "fitted":
        free = baseline_params(model, records, imported)
        say(f"fitting the linear baseline ({', '.join(p.name for p in free)})")
        model = fit(ev, [model], free, fit_train, scale_m, max_nfev=60, step=step).model
        bparams = {p.name: p.get(model) for p in free}
    base_model = model
    base_train = residuals(ev, model, fit_train)
    base_test = residuals(ev, model, fit_train, test, base_train.offsets)
    say(f"baseline ({kind}): held-out RMS error {base_test.rms():.4g}")

    f_rms = float(np.sqrt(np.mean(np.concatenate(
        [records[s.run].force_n[:, s.start:s.stop].ravel() for s in fit_train]) ** 2)))
    freqs = [s.freq_hz for s in train if s.freq_hz]
    ctx = Context(records=records, base=base_model, fitted_baseline=(kind == "fitted"),
                  duration_s=ev.duration_s, x_rms_m=scale_m, f_rms_n=f_rms,
                  f_typ_hz=float(np.median(freqs)) if freqs else _dominant_freq(records,
                                                                                 fit_train))
    lo_hz, hi_hz = excited_band(records, train)
    band = (lo_hz / 1.25, hi_hz * 1.25)
    order: list[dict[str, Any]] = []
    wanted = effects or list(LIBRARY)
    if kind == "fitted" and "second_mode" in wanted:
        # the fitted baseline's order (modes per axis) is chosen on held-out data, before any
        # effect: a structure with two modes is no cause on top of a one-mode baseline
        two, order = _choose_order(ev, ctx, model, free, fit_train, test, scale_m, step, band,
                                   seed, min_gain, min_gain_lo, say)
        if two is not None:
            model = base_model = two.fit.model
            free = free + two.variant.params
            bparams = {p.name: p.get(model) for p in free}
            base_train = residuals(ev, model, fit_train)
            base_test = residuals(ev, model, fit_train, test, base_train.offsets)
            ctx = replace(ctx, base=base_model)
    free_base = list(free)
    lib: list[Effect] = [LIBRARY[e] for e in wanted]
    skipped = {e.id: why for e in lib if (why := e.applicable(ctx)) is not None}
    if base_model.rig.effects.second_mode.enabled and kind == "fitted":
        skipped["second_mode"] = "in the baseline: its order was chosen on held-out data"
    lib = [e for e in lib if e.id not in skipped]
    findings: list[Finding] = []
    rounds: list[list[dict[str, Any]]] = []
    current, cur_test = model, base_test
    cur_crit, _ = _criterion(cur_test, test, len(free))
    for _round in range(max_effects):
        cands: list[Candidate] = []
        for eff in lib:
            if any(f.effect == eff.id for f in findings):
                continue
            t0 = time.process_time()
            best: tuple[FitResult, Variant] | None = None
            for var in eff.variants(ctx, current):
                # screening: the new effect's parameters only (the rest held)
                res = fit(ev, var.starts, var.params, fit_train, scale_m, step=step,
                          keep=var.keep)
                if best is None or res.train_sse < best[0].train_sse:
                    best = (res, var)
            if best is None:
                continue
            res, var = best
            cands.append(_judge(ev, eff.id, var, res, fit_train, test, len(free)))
            say(f"  {eff.id:28s} held-out {cands[-1].test_rms:.4g}  "
                f"({time.process_time() - t0:.1f} s CPU, {res.nfev} evaluations)")
        cur_train = train_sse(ev, current, fit_train)[0]
        rejected: list[dict[str, Any]] = []
        kept: list[Candidate] = []
        for cand in cands:
            why = _not_a_finding(cand, cur_train, band)
            if why is None:
                kept.append(cand)
            else:
                rejected.append({"effect": cand.effect, "not_a_finding": why,
                                 "parameters": parameters_of(cand.variant, cand.fit.model),
                                 "held_out_error": cand.test_rms})
                say(f"  {cand.effect:28s} not a finding: {why}")
        cands = kept
        if not cands:
            rounds.append(rejected)
            break
        cands.sort(key=lambda c: c.criterion)
        if free:
            # the two best are refitted jointly with the baseline's and earlier findings'
            # parameters, and re-ranked
            for i in range(min(2, len(cands))):
                cand = cands[i]
                k_joint = len(free) + len(cand.variant.params)
                res = fit(ev, [cand.fit.model], free + cand.variant.params, fit_train, scale_m,
                          max_nfev=20 * (k_joint + 1), step=step)
                if res.train_sse <= cand.fit.train_sse:
                    cands[i] = _judge(ev, cand.effect, cand.variant, res, fit_train, test,
                                      len(free))
                say(f"  joint refit {cand.effect:16s} held-out {cands[i].test_rms:.4g}")
            # a joint refit may move a parameter onto its bound or raise the training error
            for cj in list(cands):
                why = _not_a_finding(cj, cur_train, band)
                if why is not None:
                    cands.remove(cj)
                    rejected.append({"effect": cj.effect, "not_a_finding": f"joint refit: {why}",
                                     "parameters": parameters_of(cj.variant, cj.fit.model),
                                     "held_out_error": cj.test_rms})
            if not cands:
                rounds.append(rejected)
                break
            cands.sort(key=lambda c: c.criterion)
        before = cur_test.rms()
        rounds.append([{
            "effect": c.effect, "parameters": parameters_of(c.variant, c.fit.model),
            "held_out_error": c.test_rms, "gain": before / c.test_rms, "criterion": c.criterion,
            "train_error": math.sqrt(c.fit.train_sse / c.fit.train_n), "n_params": c.k,
        } for c in cands] + rejected)
        top = cands[0]
        gain = before / top.test_rms
        lo, hi = bootstrap_gain(cur_test, top.test, test, seed + len(findings))
        significant = top.criterion < cur_crit and gain >= min_gain and lo >= min_gain_lo
        say(f"round {len(rounds)}: best {top.effect} gain {gain:.3g} [{lo:.3g}, {hi:.3g}]"
            f"{'' if significant else ' (not significant)'}")
        if not significant:
            break
        runner = cands[1] if len(cands) > 1 else None
        evidence: dict[str, Any] = {
            "train_error_before": math.sqrt(_sse(residuals(ev, current, fit_train))
                                            / top.fit.train_n),
            "train_error_after": math.sqrt(top.fit.train_sse / top.fit.train_n),
            "criterion_before": cur_crit, "criterion_after": top.criterion,
            "n_params": len(top.variant.params),
            "held_out_segments": len(test),
        }
        if runner is not None:
            evidence["runner_up"] = {"effect": runner.effect,
                                     "gain": before / runner.test_rms,
                                     "parameters": parameters_of(runner.variant,
                                                                 runner.fit.model)}
            evidence["ambiguous"] = bool(top.test_rms**2 > runner.test_rms**2 / 1.25)
        evidence.update(_effect_evidence(top.effect, records, test, cur_test, top.test,
                                         top.fit.model, ev.duration_s))
        findings.append(Finding(top.effect, parameters_of(top.variant, top.fit.model), before,
                                top.test_rms, gain, (lo, hi), evidence, top.fit.model,
                                top.variant, runner, top.test))
        free = free + top.variant.params
        current, cur_test, cur_crit = top.fit.model, top.test, top.criterion

    # verdict against the signal: what the baseline and the final model explain of it
    rows_base = ra.dwell_table(records, base_test, test)
    noise = ra.noise_floor(rows_base)
    verdict = judge(records, base_test, cur_test, test, ra.channel_noise(records, test),
                    findings[0].test_residuals if findings else None)
    unexplained = verdict.unexplained
    for f in findings:
        if f.effect == "second_mode" and not verdict.adequate:
            # a second mass-spring term helps: the baseline lacks a degree of freedom
            verdict.missing.setdefault("modes", []).append(
                {"term": "second_mode", **f.parameters})
    on_bound = [p.name for p in free_base if _on_bound(p, base_model)]
    if on_bound:
        verdict.missing["baseline_parameters_on_bound"] = on_bound
        notes.append(f"baseline parameter(s) {on_bound} on a bound of the fit: the baseline "
                     "does not describe the data")
    for f in findings:
        if LIBRARY[f.effect].kind == "measurement":
            f.evidence.update(_sensor_pair_check(ev, ctx, base_model, free_base, findings, f,
                                                 current, fit_train, test, scale_m, step))
    noise_of = ra.channel_noise(records, test)
    before_res = base_test
    for f in findings:
        assert f.test_residuals is not None
        refinement, share = refinement_share(signal_fit(records, before_res, test, noise_of),
                                             signal_fit(records, f.test_residuals, test,
                                                        noise_of))
        f.evidence["share_of_signal_explained"] = share
        if refinement:
            f.evidence["refinement"] = True
        before_res = f.test_residuals
    for f in findings:
        # a runner-up as good as the finding leaves the cause ambiguous, unless it was found
        # too, or, swapped in for the finding next to the other findings, it explains the
        # held-out data clearly worse than the final model
        found = {g.effect for g in findings}
        if f.evidence.get("ambiguous") and f.runner_up is not None:
            if f.runner_up.effect in found:
                f.evidence["ambiguous"] = False
            else:
                swap_rms = _swap_check(ev, base_model, kind == "fitted", free_base, findings, f,
                                       current, fit_train, test, scale_m, step)
                f.evidence["runner_up"]["held_out_error_swapped"] = swap_rms
                if swap_rms**2 > 1.25 * cur_test.rms() ** 2:
                    f.evidence["ambiguous"] = False
        weak = (unexplained or not verdict.adequate or bool(on_bound)
                or f.evidence.get("refinement", False))
        f.evidence["confidence"] = "low" if (weak or f.evidence.get("ambiguous")) else "high"
    if not findings and unexplained:
        notes.append("the baseline misses something that no effect of the library explains")
    # amplitude dependence over the levels (runs or amplitude groups), of the data and of the
    # baseline's prediction; a finding the trend beyond the baseline argues against is low
    amplitude = check_levels(ev, base_model, fit_train, train + test, base_train.offsets,
                             findings)
    say(f"amplitude dependence: {amplitude.text}")
    ext = extended_rig(current, ev.duration_s)
    if imported:
        ext = ext.model_copy(update={"substeps": int(min(32, max(oversample.values())))})
    return Diagnosis(
        baseline_kind=kind, units="m", records=records, train=train, test=test,
        baseline_model=base_model, baseline_params=bparams, baseline_train=base_train,
        baseline_test=base_test, findings=findings, final_model=current, final_test=cur_test,
        unexplained=unexplained, rounds=rounds, skipped=skipped, noise_floor=noise,
        extended_rig=ext, elapsed_s=time.perf_counter() - t_start, notes=notes,
        verdict=verdict, amplitude=amplitude, order=order,
    )


def _sensor_pair_check(ev: Evaluator, ctx: Context, base: Model, free_base: list[Param],
                       findings: list[Finding], f: Finding, final: Model,
                       fit_train: list[Segment], test: list[Segment], scale_m: float,
                       step: int) -> dict[str, Any]:
    """Which sensor of a disagreeing pair is wrong, and whether the data can tell.

    The same measurement effect is refitted on each other sensor of the finding's axis instead
    (with the baseline's own parameters and the other findings free): a gain error of the probe
    and the inverse gain error of the accelerometer, the structure scaled with it, fit alike on
    a fitted baseline; a configured baseline, or a delay (never negative), tells them apart. A
    partner within 25 % of the final model's held-out mean square cannot be told from the
    finding's channel.
    """
    ch = f.parameters.get("channel")
    axis_of: dict[str, int] = {}
    for rec in ev.records:
        axis_of.update({c: a for c, (a, _) in rec.objective_channels().items()})
    if ch not in axis_of:
        return {}
    partners = [c for c, a in axis_of.items() if a == axis_of[ch] and c != ch]
    own = f.variant.params[0]
    cleared = own.set(final, 0.0 if own.name == "delay_s" else 1.0)
    others = [p for g in findings if g is not f for p in g.variant.params]
    final_ms = residuals(ev, final, fit_train, test).rms() ** 2
    out: dict[str, Any] = {"pair_check": {}}
    alike: list[str] = []
    for var in LIBRARY[f.effect].variants(ctx, cleared):
        partner = var.labels.get("channel")
        if partner not in partners:
            continue
        res = fit(ev, var.starts, free_base + others + var.params, fit_train, scale_m,
                  max_nfev=20 * (len(free_base) + len(others) + 2), step=step)
        ms = residuals(ev, res.model, fit_train, test).rms() ** 2
        out["pair_check"][partner] = {
            **parameters_of(var, res.model),
            "held_out_error": math.sqrt(ms)}
        if ms <= 1.25 * final_ms:
            alike.append(partner)
    out["cannot_tell_from"] = alike
    if alike:
        out["which_sensor"] = (f"{ch} or {', '.join(alike)}: the pair disagree, and the data "
                               "cannot tell which of them is wrong")
    else:
        out["which_sensor"] = f"{ch} (its partners on the axis explain the data clearly worse)"
    return out


def _swap_check(ev: Evaluator, base: Model, fitted: bool, free_base: list[Param],
                findings: list[Finding], f: Finding, final: Model, fit_train: list[Segment],
                test: list[Segment], scale_m: float, step: int) -> float:
    """Held-out RMS of the final model with finding ``f`` replaced by its runner-up."""
    assert f.runner_up is not None
    m = base
    params = list(free_base)
    for p in free_base:
        m = p.set(m, p.get(final))
    for g in findings:
        if g is f:
            continue
        for p in g.variant.params:
            m = p.set(m, p.get(final))
        params += g.variant.params
    runner = f.runner_up
    for p in runner.variant.params:
        m = p.set(m, p.get(runner.fit.model))
    params += runner.variant.params
    res = fit(ev, [m], params, fit_train, scale_m, max_nfev=20 * (len(params) + 1), step=step)
    return residuals(ev, res.model, fit_train, test).rms()


def _choose_order(ev: Evaluator, ctx: Context, one: Model, free: list[Param],
                  fit_train: list[Segment], test: list[Segment], scale_m: float, step: int,
                  band: tuple[float, float], seed: int, min_gain: float, min_gain_lo: float,
                  say: Any) -> tuple[Candidate | None, list[dict[str, Any]]]:
    """One or two modes per axis for the fitted baseline, chosen on held-out data.

    The second mode (``second_mode``: the frame as a second mass-spring under the housing) is
    fitted with the one-mode baseline's parameters, from the same starts as the library term,
    and kept by the same rules as a finding: a lower held-out criterion, a held-out gain of at
    least ``min_gain`` whose bootstrap interval stays above ``min_gain_lo``, no parameter on a
    bound, no higher training error, the mode inside the excited band. Returns the two-mode
    candidate (None: one mode) and the table of both orders.
    """
    one_train = train_sse(ev, one, fit_train)[0]
    one_test = residuals(ev, one, fit_train, test)
    one_crit, _ = _criterion(one_test, test, len(free))
    rows: list[dict[str, Any]] = [{"modes_per_axis": 1, "held_out_error": one_test.rms(),
                                   "criterion": one_crit, "n_params": len(free)}]
    best: tuple[FitResult, Variant] | None = None
    for var in LIBRARY["second_mode"].variants(ctx, one):
        # the best starts (the second mode added to the one-mode fit) refined with every
        # parameter: the first mode moves once the second takes its share of the response
        k = len(free) + len(var.params)
        res = fit(ev, var.starts, free + var.params, fit_train, scale_m, step=step,
                  keep=var.keep, max_nfev=30 * (k + 1))
        if best is None or res.train_sse < best[0].train_sse:
            best = (res, var)
    if best is None:
        return None, rows
    res, var = best
    two = _judge(ev, "second_mode", var, res, fit_train, test, len(free))
    gain = one_test.rms() / two.test_rms
    lo, hi = bootstrap_gain(one_test, two.test, test, seed)
    why = _not_a_finding(two, one_train, band)
    if why is None and not (two.criterion < one_crit and gain >= min_gain
                            and lo >= min_gain_lo):
        why = f"held-out gain {gain:.3g} [{lo:.3g}, {hi:.3g}] not significant"
    rows.append({"modes_per_axis": 2, "held_out_error": two.test_rms,
                 "criterion": two.criterion, "n_params": two.k,
                 "parameters": parameters_of(var, two.fit.model), "gain": gain,
                 "gain_interval": [lo, hi], "chosen": why is None,
                 **({"not_chosen": why} if why else {})})
    rows[0]["chosen"] = why is not None
    say(f"baseline order: {'two modes' if why is None else 'one mode'} per axis (two modes: "
        f"held-out {two.test_rms:.4g}, gain {gain:.3g} [{lo:.3g}, {hi:.3g}]"
        f"{'' if why is None else '; ' + why})")
    return (two if why is None else None), rows


def _judge(ev: Evaluator, effect: str, var: Variant, res: FitResult, fit_train: list[Segment],
           test: list[Segment], n_free: int) -> Candidate:
    test_res = residuals(ev, res.model, fit_train, test)
    k = n_free + len(var.params)
    crit, _ = _criterion(test_res, test, k)
    return Candidate(effect, var, res, test_res, test_res.rms(), crit, k)


def _on_bound(p: Param, model: Model) -> bool:
    v = p.get(model)
    tol = 1e-3 * p.scale
    return bool((math.isfinite(p.lo) and v - p.lo <= tol)
                or (math.isfinite(p.hi) and p.hi - v <= tol))


def _not_a_finding(c: Candidate, cur_train_sse: float,
                   band: tuple[float, float]) -> str | None:
    """Why candidate ``c`` cannot be a finding (None: it can).

    A term that raises the training error, a parameter held on a bound of its fit, or a mode
    outside the excited band (the data say nothing about it) explains nothing.
    """
    if c.fit.train_sse > cur_train_sse * (1 + 1e-9):
        return "raises the training error"
    bound = [p.name for p in c.variant.params if _on_bound(p, c.fit.model)]
    if bound:
        return f"parameter(s) {bound} on a bound of the fit"
    if c.effect == "second_mode":
        f = c.fit.model.rig.effects.second_mode.frequency_hz
        if not band[0] <= f <= band[1]:
            return (f"mode at {f:.4g} Hz outside the excited band "
                    f"{band[0]:.4g}..{band[1]:.4g} Hz")
    return None


def _sse(res: Residuals) -> float:
    return sum(res.sse(s)[0] for s in res.per_segment)


def _dominant_freq(records: list[RunRecord], segs: list[Segment]) -> float:
    s = segs[0]
    rec = records[s.run]
    x = next(iter(rec.responses.values()))[s.start:s.stop]
    spec = np.abs(np.fft.rfft(x - x.mean()))
    f = np.fft.rfftfreq(x.size, 1 / rec.sample_rate_hz)
    return float(f[1:][np.argmax(spec[1:])])


def _effect_evidence(effect: str, records: list[RunRecord], test: list[Segment],
                     before: Residuals, after: Residuals, model: Model,
                     duration_s: float) -> dict[str, Any]:
    """Effect-specific corroboration: dwell errors before/after, redundant sensors, oil temp."""
    out: dict[str, Any] = {}
    rb = ra.summary(ra.dwell_table(records, before, test))
    rf = ra.summary(ra.dwell_table(records, after, test))
    if rb:
        out["dwell_errors_before"] = rb
        out["dwell_errors_after"] = rf
    if effect == "sensor_gain":
        out["accelerometer_check"] = _accel_check(records, test)
    if effect == "viscosity_drift":
        temps = [r.t_oil_c for r in records if r.t_oil_c is not None]
        if temps:
            t = temps[0]
            rise = float(np.mean(t[-100:]) - np.mean(t[:100]))
            out["oil_temperature_rise_c"] = rise
            out["eq1_relative_change_from_temperature"] = math.expm1(-0.01665 * rise)
    return out


def _accel_check(records: list[RunRecord], segs: list[Segment]) -> dict[str, float]:
    """Per probe: median of |displacement from the accelerometer| / |probe| at 1X over dwells.

    The accelerometer is an independent sensor: -A / w^2 is the displacement it measures.
    A probe whose ratio departs from 1 while its twin stays at 1 has the wrong gain.
    """
    ratios: dict[str, list[float]] = {}
    for seg in segs:
        if not seg.freq_hz:
            continue
        rec = records[seg.run]
        w = 2 * math.pi * seg.freq_hz
        for ch, axis in rec.response_axis.items():
            acc_name = "ax" if axis == 0 else "ay"
            if acc_name not in rec.accel:
                continue
            za, _, _ = ra.harmonics(rec.accel[acc_name][seg.start:seg.stop], seg.start,
                                    rec.sample_rate_hz, seg.freq_hz, 1)
            zx, _, _ = ra.harmonics(rec.responses[ch][seg.start:seg.stop], seg.start,
                                    rec.sample_rate_hz, seg.freq_hz, 1)
            if abs(zx[0]) > 0:
                ratios.setdefault(ch, []).append(abs(zx[0]) / (abs(za[0]) / w**2))
    return {ch: float(np.median(v)) for ch, v in ratios.items()}
