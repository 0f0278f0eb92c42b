"""The fitted baseline: a linear model of the rig from the data alone, its order chosen on
held-out data.

1. Start (`data_start`): a frequency-domain fit of the dynamic stiffness per axis
   (``start.py``), or an equation-error ARX estimate where that has too few points; the
   replay's warm-up from the estimated decay time.
2. Refinement (`fit_linear`): mass, damping and stiffness per axis by output error.
3. Order (`choose_order`): one or two modes per axis, then the axes uncoupled or coupled by
   a structural cross stiffness (where both axes' responses are measured), each kept by the
   rules a finding meets (``candidates.py``), before any effect is tried.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from analysis.diagnose import residual_analysis as ra
from analysis.diagnose.candidates import (
    Candidate,
    Finding,
    Problem,
    bootstrap_gain,
    criterion,
    judge_candidate,
    not_a_finding,
)
from analysis.diagnose.data import DiagnoseError, RunRecord, Segment
from analysis.diagnose.effects import LIBRARY, Context, Variant, parameters_of
from analysis.diagnose.fitting import FitResult, arx_linear_guess, fit, fit_failure, train_sse
from analysis.diagnose.model import Evaluator, Model, Param, Residuals, residuals, rig_param
from analysis.diagnose.residual_structure import signature_sd
from analysis.diagnose.start import OneMode, one_mode_estimate
from analysis.diagnose.verdict import refinement_share, signal_fit
from rig_model.params import RigParams


@dataclass
class Baseline:
    """The baseline model, its free parameters (none for a configured baseline), and its
    residuals on the fitted training segments and on the held-out segments."""
    model: Model
    free: list[Param]
    train: Residuals
    test: Residuals
    #: the fitted baseline's order chosen on held-out data: one row per order tried
    order: list[dict[str, Any]] = field(default_factory=list)
    #: where the order chose a second mode: the one-mode baseline's held-out residuals (what
    #: the second mode is reported against, as a finding about the rig)
    one_mode_test: Residuals | None = None

    @property
    def params(self) -> dict[str, float]:
        return {p.name: p.get(self.model) for p in self.free}


def is_imported(records: list[RunRecord], rig: RigParams | None) -> bool:
    """Runs without a rig description (imported data) and none given."""
    return rig is None and all(r.rig is None for r in records)


def baseline_params(model: Model, records: list[RunRecord]) -> list[Param]:
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


def fit_subset(ev: Evaluator, train: list[Segment], budget: float) -> list[Segment]:
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


def data_start(records: list[RunRecord], train: list[Segment], base_rig: RigParams,
               notes: list[str], say: Any) -> tuple[Model, float]:
    """Start of the fitted baseline from the data alone, and the replay's warm-up [s].

    A frequency-domain fit of the dynamic stiffness per axis (``start.py``), the film's known
    added mass and centred damping taken off when the runs are lubricated; the equation-error
    ARX estimate where that has too few points. The warm-up before each replayed segment covers
    four decay times of the estimated mode, the film's damping and mass included (at least
    0.5 s, at most 30 s), so a lightly damped
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
    whole_mode = False  # the estimate holds the film's share (ARX), or not (taken off)
    if x is None and y is None:
        try:
            m_kg, c, k, _ = arx_linear_guess(records[0], train)
        except ValueError as err:
            raise DiagnoseError(f"cannot start the fitted baseline: {err}") from None
        x, whole_mode = OneMode(m_kg, c, k, 0), True
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
    # the mode decays with all its damping and mass, the film's too: the structure's share
    # alone (nothing, where warm oil leaves the film below its nominal damping) would give a
    # warm-up of 30 s, and with it a fit on 2 of 11 dwells
    whole = first if whole_mode else OneMode(first.mass_kg + d_mass,
                                             first.damping_ns_per_m + d_damp,
                                             first.stiffness_n_per_m, first.points)
    tau = whole.decay_time_s()
    warmup = float(min(30.0, max(0.5, 4 * tau)))
    say(f"start from the data: {first.natural_hz:.4g} Hz, damping ratio "
        f"{first.damping_ratio:.3g}, warm-up {warmup:.3g} s")
    notes.append(f"fitted baseline started from the data ({first.points} frequency points): "
                 f"{first.natural_hz:.4g} Hz, damping ratio {first.damping_ratio:.3g}; each "
                 f"replayed window starts {warmup:.3g} s early (four decay times) from rest")
    return model, warmup


def fit_linear(pb: Problem, start: Model, records: list[RunRecord], fitted: bool,
               say: Any) -> Baseline:
    """The baseline: ``start`` as it is (configured), or its mass, damping and stiffness per
    axis refined by output error (fitted)."""
    model = start
    free: list[Param] = []
    if fitted:
        free = baseline_params(model, records)
        say(f"fitting the linear baseline ({', '.join(p.name for p in free)})")
        model = fit(pb.ev, [model], free, pb.fit_train, pb.scale_m, max_nfev=60,
                    step=pb.step).model
    return _with_residuals(pb, model, free, [])


def _with_residuals(pb: Problem, model: Model, free: list[Param],
                    order: list[dict[str, Any]]) -> Baseline:
    train = residuals(pb.ev, model, pb.fit_train)
    test = residuals(pb.ev, model, pb.fit_train, pb.test, train.offsets)
    return Baseline(model, free, train, test, order)


def choose_order(pb: Problem, ctx: Context, one: Baseline, band: tuple[float, float],
                 seed: int, min_gain: float, min_gain_lo: float, say: Any,
                 second_mode: bool = True) -> Baseline:
    """The fitted baseline's order, chosen on held-out data: one or two modes per axis, then
    the axes uncoupled or coupled by a structural cross stiffness.

    The second mode (``second_mode``: the frame as a second mass-spring under the housing) is
    fitted with the one-mode baseline's parameters, from the same starts as the library term.
    The coupling (``_coupled_axes``) is fitted on the order chosen so far, with its parameters.
    Each is kept by the same rules as a finding: a lower held-out criterion, a held-out gain of
    at least ``min_gain`` whose bootstrap interval stays above ``min_gain_lo``, no parameter on
    a bound, no higher training error, a mode inside the excited band. Returns the baseline of
    the order chosen, with the table of every order tried (and the coupling's reason when it
    was not tried).
    """
    rules = _Rules(band, seed, min_gain, min_gain_lo)
    rows = [_order_row(pb, one, modes_per_axis=1)]
    chosen, chosen_row = one, rows[0]
    if second_mode:
        two, two_row = _two_modes(pb, ctx, one, rules, say)
        if two_row is not None:
            rows.append(two_row)
            if two is not None:
                chosen, chosen_row = two, two_row
    coupled, coupled_row = _coupled_axes(pb, ctx, chosen, rules, say)
    rows.append(coupled_row)
    if coupled is not None:
        chosen, chosen_row = coupled, coupled_row
    for r in rows:
        r["chosen"] = r is chosen_row
    chosen.order = rows
    if chosen.model.rig.effects.second_mode.enabled:
        chosen.one_mode_test = one.test
    return chosen


@dataclass(frozen=True)
class _Rules:
    """What an order must meet to be chosen: the excited band, the bootstrap's seed, the least
    held-out gain and the least lower end of its interval."""
    band: tuple[float, float]
    seed: int
    min_gain: float
    min_gain_lo: float


def _order_row(pb: Problem, base: Baseline, modes_per_axis: int) -> dict[str, Any]:
    crit, _ = criterion(base.test, pb.test, len(base.free))
    return {"modes_per_axis": modes_per_axis, "coupled_axes": False,
            "held_out_error": base.test.rms(), "criterion": crit, "n_params": len(base.free)}


def _judged(pb: Problem, base: Baseline, cand: Candidate,
            rules: _Rules) -> tuple[dict[str, Any], str | None]:
    """The order table's row of candidate ``cand`` on top of ``base``, and why it is not
    chosen (None: chosen), by the rules a finding meets."""
    base_train = train_sse(pb.ev, base.model, pb.fit_train)[0]
    base_crit, _ = criterion(base.test, pb.test, len(base.free))
    gain = base.test.rms() / cand.test_rms
    lo, hi = bootstrap_gain(base.test, cand.test, pb.test, rules.seed)
    why = not_a_finding(cand, base_train, rules.band)
    if why is None and not (cand.criterion < base_crit and gain >= rules.min_gain
                            and lo >= rules.min_gain_lo):
        why = f"held-out gain {gain:.3g} [{lo:.3g}, {hi:.3g}] not significant"
    row = {"held_out_error": cand.test_rms, "criterion": cand.criterion, "n_params": cand.k,
           "parameters": parameters_of(cand.variant, cand.fit.model), "gain": gain,
           "gain_interval": [lo, hi], **({"not_chosen": why} if why else {})}
    return row, why


def _two_modes(pb: Problem, ctx: Context, one: Baseline, rules: _Rules,
               say: Any) -> tuple[Baseline | None, dict[str, Any] | None]:
    """The two-mode baseline if chosen (None: one mode), and its row (None: not fitted)."""
    best: tuple[FitResult, Variant] | None = None
    try:
        for var in LIBRARY["second_mode"].variants(ctx, one.model):
            # the best starts (the second mode added to the one-mode fit) refined with every
            # parameter: the first mode moves once the second takes its share of the response
            k = len(one.free) + len(var.params)
            res = fit(pb.ev, var.starts, one.free + var.params, pb.fit_train, pb.scale_m,
                      step=pb.step, keep=var.keep, max_nfev=30 * (k + 1))
            if best is None or res.train_sse < best[0].train_sse:
                best = (res, var)
        if best is None:
            return None, None
        res, var = best
        two = judge_candidate(pb, "second_mode", var, res, len(one.free))
    except Exception as err:
        failed = fit_failure(err)
        if failed is None:
            raise
        say(f"baseline order: one mode per axis (two modes {failed})")
        return None, {"modes_per_axis": 2, "coupled_axes": False, "not_chosen": failed}
    row, why = _judged(pb, one, two, rules)
    say(f"baseline order: {'two modes' if why is None else 'one mode'} per axis (two modes: "
        f"held-out {two.test_rms:.4g}, gain {row['gain']:.3g} [{row['gain_interval'][0]:.3g}, "
        f"{row['gain_interval'][1]:.3g}]{'' if why is None else '; ' + why})")
    row = {"modes_per_axis": 2, "coupled_axes": False, **row}
    if why is not None:
        return None, row
    return _with_residuals(pb, two.fit.model, one.free + var.params, []), row


def _coupled_axes(pb: Problem, ctx: Context, base: Baseline, rules: _Rules,
                  say: Any) -> tuple[Baseline | None, dict[str, Any]]:
    """The baseline ``base`` with its axes coupled by a structural cross stiffness if chosen
    (None: uncoupled), and its row in the order table.

    k_xy is in phase with the displacement (the rods' principal axes turned away from x and
    y), unlike the film's cross-coupled damping and mass (the library's ``cross_coupling``),
    which is why it belongs to the baseline and is judged here, before any effect. It is
    fitted with every parameter of ``base``, from 0 and from +-5 % of the mean axis stiffness,
    within the bound no rod set reaches, |k_xy| < sqrt(K_x K_y). Any coupling beats none
    where the other axis answers, so on a film the rods' k_xy is chosen only where it explains
    the held-out data better than the film's cross terms would (``_film_couples_better``).
    """
    modes = 2 if base.model.rig.effects.second_mode.enabled else 1
    row: dict[str, Any] = {"modes_per_axis": modes, "coupled_axes": True}
    why_not = _why_not_coupled(pb.ev.records)
    if why_not is not None:
        say(f"baseline order: axes uncoupled (coupling not tried: {why_not})")
        return None, {**row, "not_tried": why_not}
    st = base.model.rig.structure
    k_mean = 0.5 * (st.stiffness_x_n_per_m + st.stiffness_y_n_per_m)
    bound = math.sqrt(st.stiffness_x_n_per_m * st.stiffness_y_n_per_m)
    k_xy = rig_param("stiffness_xy_N_per_m", "structure.stiffness_xy_n_per_m", 0.02 * k_mean,
                     -bound, bound)
    var = Variant({}, [k_xy], [k_xy.set(base.model, r * k_mean) for r in (0.0, 0.05, -0.05)])
    k = len(base.free) + 1
    t0 = time.process_time()
    try:
        res = fit(pb.ev, var.starts, base.free + var.params, pb.fit_train, pb.scale_m,
                  step=pb.step, max_nfev=20 * (k + 1))
        cand = judge_candidate(pb, "coupled_axes", var, res, len(base.free))
    except Exception as err:
        failed = fit_failure(err)
        if failed is None:
            raise
        say(f"baseline order: axes uncoupled (coupled {failed})")
        return None, {**row, "not_chosen": failed}
    judged, why = _judged(pb, base, cand, rules)
    if why is None:
        why = _film_couples_better(pb, ctx, base, cand.test_rms)
    lo, hi = judged["gain_interval"]
    say(f"baseline order: axes {'coupled' if why is None else 'uncoupled'} (coupled: k_xy "
        f"{k_xy.get(res.model):.4g} N/m, held-out {cand.test_rms:.4g}, gain "
        f"{judged['gain']:.3g} [{lo:.3g}, {hi:.3g}]{'' if why is None else '; ' + why}; "
        f"{time.process_time() - t0:.1f} s CPU, {res.nfev} evaluations)")
    row.update(judged)
    if why is not None:
        row["not_chosen"] = why
        return None, row
    return _with_residuals(pb, res.model, base.free + var.params, []), row


def _film_couples_better(pb: Problem, ctx: Context, base: Baseline,
                         coupled_rms: float) -> str | None:
    """Why the rods' coupling is not chosen (None: it is): the film's cross terms (the
    library's ``cross_coupling``, fitted as the coupling is, with every parameter of
    ``base``) explain the held-out data at least as well as k_xy (held-out RMS
    ``coupled_rms``). Not tried where the library's term cannot be fitted (no film)."""
    eff = LIBRARY["cross_coupling"]
    if eff.applicable(ctx) is not None:
        return None
    best: Candidate | None = None
    for var in eff.variants(ctx, base.model):
        k = len(base.free) + len(var.params)
        try:
            res = fit(pb.ev, var.starts, base.free + var.params, pb.fit_train, pb.scale_m,
                      step=pb.step, max_nfev=20 * (k + 1))
            cand = judge_candidate(pb, eff.id, var, res, len(base.free))
        except Exception as err:
            if fit_failure(err) is None:
                raise
            continue
        if best is None or cand.test_rms < best.test_rms:
            best = cand
    if best is None or best.test_rms > coupled_rms:
        return None
    sizes = ", ".join(f"{k} {v:.4g}" for k, v in parameters_of(best.variant, best.fit.model)
                      .items())
    return (f"the film's cross terms ({sizes}) explain the held-out data as well or better "
            f"(held-out {best.test_rms:.4g} against {coupled_rms:.4g}): a cause for the "
            "library, not the rods")


def _why_not_coupled(records: list[RunRecord]) -> str | None:
    """Why the axes' coupling cannot be fitted on these runs (None: it can): a coupling shows
    only in the response of the axis it couples to, so both axes' responses must be measured
    in one run (a probe, velocity sensor or accelerometer on each)."""
    for r in records:
        if {ax for ax, _ in r.objective_channels().values()} >= {0, 1}:
            return None
    return "no run measures the responses of both axes (a sensor on x and one on y)"


def second_mode_finding(pb: Problem, ctx: Context, base: Baseline) -> Finding | None:
    """The second mode the fitted baseline's order chose, as a finding about the rig (None:
    the order kept one mode per axis).

    The rig's model holds one mode per axis (the housing on its rods): a second mode in the
    band (the frame, section IV.3) is something the data show that the model lacks, and the
    operator is told so with its frequency, modal mass and damping. It was fitted in the
    baseline, with every baseline parameter, because a missing mode would otherwise be
    absorbed by the effects tried on top; it is judged here against the one-mode baseline on
    the same held-out dwells: the gain, its bootstrap interval, its signature in the dwells'
    noise and whether it is only a refinement. Its confidence is set by the caller's rules
    (`engine._weak`)."""
    if base.one_mode_test is None or not base.model.rig.effects.second_mode.enabled:
        return None
    row = next(r for r in base.order if r["modes_per_axis"] == 2 and not r["coupled_axes"])
    var = LIBRARY["second_mode"].variants(ctx, base.model)[0]
    two_test = base.test
    records = pb.ev.records
    noise_of = ra.channel_noise(records, pb.test)
    dwells = any(s.freq_hz for s in pb.test)
    signature = (signature_sd(records, base.one_mode_test, two_test, pb.test, len(var.params))
                 if dwells else None)
    refinement, share = refinement_share(signal_fit(records, base.one_mode_test, pb.test,
                                                    noise_of),
                                         signal_fit(records, two_test, pb.test, noise_of),
                                         signature)
    evidence: dict[str, Any] = {
        "in_baseline": "chosen by the fitted baseline's order on held-out data",
        "n_params": len(var.params), "held_out_segments": len(pb.test),
        "share_of_signal_explained": share,
        **({"signature_sd": signature} if signature is not None else {}),
        **({"refinement": True} if refinement else {}),
    }
    return Finding("second_mode", parameters_of(var, base.model), base.one_mode_test.rms(),
                   float(row["held_out_error"]), float(row["gain"]),
                   (float(row["gain_interval"][0]), float(row["gain_interval"][1])), evidence,
                   base.model, var, None, two_test)
