"""The fitted baseline: a linear model of the rig from the data alone, its order chosen on
held-out data.

1. Start (`data_start`): a frequency-domain fit of the dynamic stiffness per axis
   (``start.py``), or an equation-error ARX estimate where that has too few points; the
   replay's warm-up from the estimated decay time.
2. Refinement (`fit_linear`): mass, damping and stiffness per axis by output error.
3. Order (`choose_order`): one or two modes per axis, then more modes per axis where the
   dwells' modal fit (``modes.py``) finds them (linear modes at the output, ``extra_modes.py``),
   then the axes uncoupled or coupled by a structural cross stiffness (where both axes'
   responses are measured), each kept by the rules a finding meets (``candidates.py``), before
   any effect is tried.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
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
from analysis.diagnose.extra_modes import ExtraMode
from analysis.diagnose.fitting import FitResult, arx_linear_guess, fit, fit_failure, train_sse
from analysis.diagnose.model import Evaluator, Model, Param, Residuals, residuals, rig_param
from analysis.diagnose.modes import MAX_MODES, Modes
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
                 second_mode: bool = True, modes: Modes | None = None) -> Baseline:
    """The fitted baseline's order, chosen on held-out data: one or two modes per axis, then
    more modes per axis (``_more_modes``: where the dwells' modal fit ``modes`` finds modes
    the baseline lacks), then the axes uncoupled or coupled by a structural cross stiffness.

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
    start = modal_start(modes, chosen.model, band) if modes else None
    if start is not None:  # searched only where the dwells show modes the baseline lacks
        more_rows, more_base = _more_modes(pb, one, chosen, start, rules, say)
        rows.extend(more_rows)
        if more_base is not None:
            chosen, chosen_row = more_base, next(r for r in reversed(more_rows)
                                                 if "not_chosen" not in r)
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


def modes_per_axis(model: Model) -> dict[str, int]:
    """The modes the baseline ``model`` holds per axis: the kernel's (the housing, and the
    frame where ``second_mode`` is on) and the extra modes at the output."""
    kernel = 2 if model.rig.effects.second_mode.enabled else 1
    return {ax: kernel + sum(1 for m in model.extra_modes if m.axis == i)
            for i, ax in enumerate("xy")}


def _film_share(model: Model, records: list[RunRecord]) -> tuple[float, float]:
    """The film's added mass [kg] and centred damping [N.s/m] in the kernel's mode (none on
    dry runs)."""
    if not any(r.lubricated for r in records):
        return 0.0, 0.0
    film = model.rig.film
    return (film.fluid_mass_kg + film.added_mass(),
            film.eq16_damping_centred(film.viscosity_pa_s(model.rig.oil.initial_temperature_c)))


def baseline_modes(model: Model, records: list[RunRecord]) -> list[dict[str, Any]]:
    """Every mode the baseline holds, per axis: natural frequency [Hz], damping ratio and
    modal mass [kg] (the housing's from its mass, damping and stiffness, the film's added mass
    and damping included on a lubricated run; the frame's uncoupled, as the library
    parametrises it; the extra modes' as fitted), and where each comes from; on the axes some
    run measures."""
    st = model.rig.structure
    d_mass, d_damp = _film_share(model, records)
    measured = {ax for r in records for ax in r.axes}
    out = []
    for i, k in enumerate((st.stiffness_x_n_per_m, st.stiffness_y_n_per_m)):
        if i not in measured:
            continue  # an axis no run measures: its mode is no statement about the data
        mass = (st.mass_kg if i == 0 else st.mass_y()) + d_mass
        damp = (st.residual_damping_ns_per_m if i == 0 else st.residual_damping_y()) + d_damp
        out.append({"axis": "xy"[i], "natural_frequency_hz": math.sqrt(k / mass) / (2 * math.pi),
                    "damping_ratio": damp / (2 * math.sqrt(k * mass)), "modal_mass_kg": mass,
                    "source": "housing (kernel)"})
        sm = model.rig.effects.second_mode
        if sm.enabled:
            out.append({"axis": "xy"[i], "natural_frequency_hz": sm.frequency_hz,
                        "damping_ratio": sm.damping_ratio, "modal_mass_kg": sm.modal_mass_kg,
                        "source": "frame (kernel, uncoupled)"})
        for md in sorted((m for m in model.extra_modes if m.axis == i),
                         key=lambda m: m.natural_hz):
            out.append({**md.to_dict(), "source": "extra mode (linear, at the output)"})
    return out


@dataclass(frozen=True)
class ModalStart:
    """Where the search for more modes starts: per axis, the mode of the dwells' modal fit
    the kernel's housing takes, and the others (the extra modes' starts), most visible
    first."""
    kernel: dict[int, ExtraMode]
    extra: dict[int, list[ExtraMode]]
    driven: frozenset[int]  # the axes the modal fit has points on


def modal_start(modes: Modes, model: Model, band: tuple[float, float]) -> ModalStart | None:
    """The start of the search for more modes (None: no axis has a mode the baseline lacks).

    Per driven axis, the modes of the dwells' modal fit at its reference level (the most
    modes; the lowest level among equals) in the excited ``band``. Where they are more than
    the modes ``model`` holds on that axis, the kernel's housing takes the one that forgets
    its start fastest (largest zeta w_n: the kernel replays each dwell from rest a warm-up
    sized at the start, while the extra modes start in their exact steady state; on the rig
    that is the film's well-damped mode), and the others are the extra modes' starts, up to
    ``MAX_MODES`` per axis in all, most visible first (largest resonant receptance
    |A| / (2 zeta w_n^2)); modal masses from the residues (|A| = 1 / m).
    """
    held = modes_per_axis(model)
    kernel: dict[int, ExtraMode] = {}
    extra: dict[int, list[ExtraMode]] = {}
    driven = frozenset(i for i, ax in enumerate("xy") if any(lv.axis == ax
                                                             for lv in modes.levels))
    for axis, ax in enumerate("xy"):
        fits = [lv for lv in modes.levels if lv.axis == ax]
        if not fits:
            continue
        ref = max(fits, key=lambda lv: len(lv.modes))
        found = [ExtraMode(axis, m.natural_hz, m.damping_ratio, 1.0 / abs(m.residue))
                 for m in ref.modes if band[0] <= m.natural_hz <= band[1] and abs(m.residue) > 0]
        if len(found) <= held[ax]:
            continue
        own = max(found, key=lambda m: m.damping_ratio * m.natural_hz)
        rest = sorted((m for m in found if m is not own),
                      key=lambda m: -1.0 / (m.modal_mass_kg * 2 * m.damping_ratio
                                            * (2 * math.pi * m.natural_hz) ** 2))
        kernel[axis], extra[axis] = own, rest[:MAX_MODES - 1]
    return ModalStart(kernel, extra, driven) if extra else None


def _kernel_at(model: Model, records: list[RunRecord], start: ModalStart) -> Model:
    """``model`` with one kernel mode per axis (no frame), placed on ``start.kernel``'s modes:
    each axis' mass, damping and stiffness from its own mode (the film's share taken off, kept
    positive; y's mass and damping apart from x's)."""
    d_mass, d_damp = _film_share(model, records)
    st = model.rig.structure
    update: dict[str, Any] = {}
    if 0 in start.kernel and 1 in start.driven and 1 not in start.kernel:
        # a driven y keeps its mode while x's moves
        update.update(mass_y_kg=st.mass_y(), residual_damping_y_ns_per_m=st.residual_damping_y())
    for axis, md in start.kernel.items():
        mass = max(md.modal_mass_kg - d_mass, 0.1 * md.modal_mass_kg)
        w = 2 * math.pi * md.natural_hz
        damp = max(2 * md.damping_ratio * (mass + d_mass) * w - d_damp,
                   0.1 * md.damping_ratio * (mass + d_mass) * w)
        stiff = (mass + d_mass) * w**2
        names = (("mass_kg", "residual_damping_ns_per_m", "stiffness_x_n_per_m") if axis == 0
                 else ("mass_y_kg", "residual_damping_y_ns_per_m", "stiffness_y_n_per_m"))
        update.update(zip(names, (mass, damp, stiff), strict=True))
        if axis == 1 and 0 not in start.driven:  # y alone: x's numbers as y's
            update.update(mass_kg=mass, residual_damping_ns_per_m=damp)
    eff = model.rig.effects
    rig = model.rig.model_copy(update={
        "structure": st.model_copy(update=update),
        "effects": eff.model_copy(update={
            "second_mode": eff.second_mode.model_copy(update={"enabled": False})})})
    return replace(model, rig=rig, extra_modes=())


def _kernel_params(model: Model, axis: int) -> list[Param]:
    """The kernel mode's mass, damping and stiffness on ``axis`` (y's apart from x's)."""
    st = model.rig.structure
    m, c, k = ((st.mass_kg, st.residual_damping_ns_per_m, st.stiffness_x_n_per_m) if axis == 0
               else (st.mass_y(), st.residual_damping_y(), st.stiffness_y_n_per_m))
    ax, y = "xy"[axis], "_y" if axis else ""
    return [rig_param(f"mass{y}_kg", f"structure.mass{y}_kg", 0.05 * m, 1e-3 * m),
            rig_param(f"damping{y}_Ns_per_m", f"structure.residual_damping{y}_ns_per_m",
                      0.1 * max(c, 1e-6 * m), 0.0),
            rig_param(f"stiffness_{ax}_N_per_m", f"structure.stiffness_{ax}_n_per_m", 0.02 * k,
                      1e-3 * k)]


def extra_mode_params(model: Model, index: int) -> list[Param]:
    """The fitted numbers of ``model.extra_modes[index]``: natural frequency (within 1.5x of
    its start: further, it is no longer the mode the dwells show), damping ratio and modal
    mass."""
    md = model.extra_modes[index]
    ax = "xy"[md.axis]
    k = 1 + sum(1 for m in model.extra_modes[:index + 1] if m.axis == md.axis)

    def param(field_name: str, label: str, scale: float, lo: float, hi: float) -> Param:
        def get(m: Model) -> float:
            return float(getattr(m.extra_modes[index], field_name))

        def put(m: Model, v: float) -> Model:
            em = list(m.extra_modes)
            em[index] = ExtraMode(**{**asdict(em[index]), field_name: float(v)})
            return replace(m, extra_modes=tuple(em))
        return Param(f"{ax}_mode{k}_{label}", get, put, scale, lo, hi)

    return [param("natural_hz", "frequency_hz", 0.01 * md.natural_hz, md.natural_hz / 1.5,
                  md.natural_hz * 1.5),
            param("damping_ratio", "damping_ratio", 0.2 * md.damping_ratio, 1e-4, 0.5),
            param("modal_mass_kg", "modal_mass_kg", 0.1 * md.modal_mass_kg,
                  1e-3 * md.modal_mass_kg, 1e3 * md.modal_mass_kg)]


def _more_modes(pb: Problem, one: Baseline, chosen: Baseline, start: ModalStart,
                rules: _Rules, say: Any) -> tuple[list[dict[str, Any]], Baseline | None]:
    """More modes per axis: the order 0, 1, 2, ... extra modes chosen on held-out data.

    Order 0 is the one-mode baseline ``one`` refitted from its kernel mode placed on the
    dwells' modal fit (`_kernel_at`); each next order adds one extra mode (``start.extra``,
    axis by axis, most visible first) to the order before it and is fitted with its axis'
    numbers (the kernel mode's and every extra mode's on that axis: a mode starts from the
    modal fit, and the others move once it takes its share). An order is kept where it meets
    the rules a finding meets against the last order kept; one that does not is still grown
    on, unless its mode raised the training error (a mode may matter only once the others are
    in: the residual of the modes still missing hides it); an axis' last orders not kept are
    dropped before the next axis. The last order kept, refitted
    (`_refined`), is then judged by the same rules against ``chosen`` (the order chosen before:
    one or two kernel modes). Returns a row per order tried and the baseline chosen (None:
    ``chosen`` stays)."""
    t0 = time.process_time()
    rows: list[dict[str, Any]] = []
    placed = _kernel_at(one.model, pb.ev.records, start)
    kernel = {axis: _kernel_params(placed, axis) for axis in sorted(start.kernel)}
    base_free = _unique([*one.free, *(p for ps in kernel.values() for p in ps)])
    try:
        res0 = fit(pb.ev, [placed], [p for ps in kernel.values() for p in ps], pb.fit_train,
                   pb.scale_m, step=pb.step, max_nfev=60)
    except Exception as err:
        failed = fit_failure(err)
        if failed is None:
            raise
        say(f"baseline order: no more modes ({failed})")
        return [{"modes_per_axis": 2, "coupled_axes": False, "extra_mode": None,
                 "not_chosen": failed}], None
    cur = _with_residuals(pb, res0.model, base_free, [])
    grown = res0.model
    axis_before = None
    for md in (md for axis in sorted(start.extra) for md in start.extra[axis]):
        if axis_before is not None and md.axis != axis_before:
            grown = cur.model  # an axis' last orders not kept end with it
        axis_before = md.axis
        model = replace(grown, extra_modes=(*grown.extra_modes, md))
        extra = [p for i in range(len(model.extra_modes)) for p in extra_mode_params(model, i)]
        var = Variant({"axis": "xy"[md.axis]}, extra[-3:], [model], follow=False)
        n_modes = modes_per_axis(model)
        row: dict[str, Any] = {"modes_per_axis": max(n_modes.values()), "modes": n_modes,
                               "coupled_axes": False, "extra_mode": md.to_dict()}
        # the axis' own numbers: the other axis' replay does not change (its runs, if
        # separate, are replayed from the kernel's cache)
        mine = [*kernel.get(md.axis, []),
                *(p for i, e in enumerate(model.extra_modes) if e.axis == md.axis
                  for p in extra_mode_params(model, i))]
        # judged where the mode acts: the held-out segments of runs measuring its axis (the
        # other axis' residual, its modes not yet added, would hide any gain)
        on_axis = replace(pb, test=[sg for sg in pb.test
                                    if md.axis in pb.ev.records[sg.run].axes])
        try:
            res = fit(pb.ev, [model], mine, pb.fit_train, pb.scale_m, step=pb.step,
                      max_nfev=20 * (len(mine) + 1))
            cand = judge_candidate(on_axis, "extra_mode", var, res,
                                   len(base_free) + len(extra) - 3)
        except Exception as err:
            failed = fit_failure(err)
            if failed is None:
                raise
            rows.append({**row, "not_chosen": failed})
            continue
        judged, why = _judged(on_axis, cur, cand, rules)
        if why != "raises the training error":
            grown = res.model  # a mode that lowers nothing is not grown on
        f_fit = res.model.extra_modes[-1].natural_hz
        if why is None and not rules.band[0] <= f_fit <= rules.band[1]:
            why = (f"mode at {f_fit:.4g} Hz outside the excited band "
                   f"{rules.band[0]:.4g}..{rules.band[1]:.4g} Hz")
        lo, hi = judged["gain_interval"]
        say(f"baseline order: {n_modes['xy'[md.axis]]} modes on {'xy'[md.axis]} "
            f"{'kept' if why is None else 'not kept'} (mode at {f_fit:.4g} Hz, held-out "
            f"{cand.test_rms:.4g}, gain {judged['gain']:.3g} [{lo:.3g}, {hi:.3g}]"
            f"{'' if why is None else '; ' + why})")
        rows.append({**row, **judged, "held_out_segments": len(on_axis.test),
                     "extra_mode": res.model.extra_modes[-1].to_dict(),
                     **({"not_chosen": why} if why else {})})
        if why is None:
            cur = _with_residuals(pb, res.model, base_free + extra, [])
    kept = [r for r in rows if "not_chosen" not in r]
    if not kept:
        return rows, None
    cur = _refined(pb, cur, kernel)
    # the highest order kept against the order chosen before it, by the same rules
    params = cur.free[len(base_free):]
    var = Variant({}, params, [cur.model], follow=False)
    fit_res = FitResult(cur.model, train_sse(pb.ev, cur.model, pb.fit_train)[0],
                        sum(s.n for s in pb.fit_train), 0)
    cand = judge_candidate(pb, "extra_mode", var, fit_res, len(cur.free) - len(params))
    judged, why = _judged(pb, chosen, cand, rules)
    lo, hi = judged["gain_interval"]
    say(f"baseline order: {'more modes' if why is None else 'no more modes'} "
        f"({', '.join(f'{ax} {n}' for ax, n in modes_per_axis(cur.model).items())} against the "
        f"order before: gain {judged['gain']:.3g} [{lo:.3g}, {hi:.3g}]"
        f"{'' if why is None else '; ' + why}; {time.process_time() - t0:.1f} s CPU)")
    kept[-1]["against_order_before"] = {"gain": judged["gain"], "gain_interval": [lo, hi],
                                        **({"not_chosen": why} if why else {})}
    if why is not None:
        kept[-1]["not_chosen"] = f"against the order before: {why}"
        return rows, None
    return rows, cur


def _refined(pb: Problem, base: Baseline, kernel: dict[int, list[Param]]) -> Baseline:
    """``base`` refitted axis by axis (the kernel mode's and the extra modes' numbers of each),
    from where the order search left it: each order's fit stops at a budget sized for one new
    mode, and the last one's modes have not all settled."""
    model = base.model
    for axis in sorted({m.axis for m in model.extra_modes}):
        mine = [*kernel.get(axis, []),
                *(p for i, e in enumerate(model.extra_modes) if e.axis == axis
                  for p in extra_mode_params(model, i))]
        model = fit(pb.ev, [model], mine, pb.fit_train, pb.scale_m, step=pb.step,
                    max_nfev=40 * (len(mine) + 1)).model
    return _with_residuals(pb, model, base.free, [])


def _unique(params: list[Param]) -> list[Param]:
    """``params`` without the repeats of a name (the first kept)."""
    seen: dict[str, Param] = {}
    for p in params:
        seen.setdefault(p.name, p)
    return list(seen.values())


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
    # ``base.test`` may hold more segments than ``pb.test`` (an axis' own, `_more_modes`)
    gain = (base.test.rms() if len(base.test.per_segment) == len(pb.test)
            else base.test.rms(pb.test)) / cand.test_rms
    lo, hi = bootstrap_gain(base.test, cand.test, pb.test, rules.seed)
    why = not_a_finding(cand, base_train, rules.band)
    if why is None and not (cand.criterion < base_crit and gain >= rules.min_gain
                            and lo >= rules.min_gain_lo):
        why = f"held-out gain {gain:.3g} [{lo:.3g}, {hi:.3g}] not significant"
    row = {"held_out_error": cand.test_rms, "criterion": cand.criterion, "n_params": cand.k,
           "parameters": parameters_of(cand.variant, cand.fit.model), "gain": gain,
           "gain_interval": [lo, hi], **({"not_chosen": why} if why else {})}
    return row, why


#: the starts of the two-mode order refined with every parameter, of the second mode's starts
#: ranked by their training error
TWO_MODE_KEEP = 3


def _two_modes(pb: Problem, ctx: Context, one: Baseline, rules: _Rules,
               say: Any) -> tuple[Baseline | None, dict[str, Any] | None]:
    """The two-mode baseline if chosen (None: one mode), and its row (None: not fitted)."""
    best: tuple[FitResult, Variant] | None = None
    t0 = time.process_time()
    try:
        for var in LIBRARY["second_mode"].variants(ctx, one.model):
            # the best starts (the second mode added to the one-mode fit) refined with every
            # parameter: the first mode moves once the second takes its share of the response
            k = len(one.free) + len(var.params)
            res = fit(pb.ev, var.starts, one.free + var.params, pb.fit_train, pb.scale_m,
                      step=pb.step, keep=TWO_MODE_KEEP, max_nfev=30 * (k + 1))
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
        f"{row['gain_interval'][1]:.3g}]{'' if why is None else '; ' + why}; "
        f"{time.process_time() - t0:.1f} s CPU, {res.nfev} evaluations)")
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
    modes = modes_per_axis(base.model)
    row: dict[str, Any] = {"modes_per_axis": max(modes.values()), "coupled_axes": True,
                           **({"modes": modes} if base.model.extra_modes else {})}
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
    row = next(r for r in base.order if r["modes_per_axis"] == 2 and not r["coupled_axes"]
               and "extra_mode" not in r)
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
