"""One dwell of a sweep: approach, converge, settle, record (its states: `dwell_states`).

    approach  drive and frequency move to the predicted drive (ramped, phase-continuous)
    converge  wait ``wait_cycles``, lock-in over ``window_cycles``, correct (Newton-Broyden),
              until the controlled amplitudes are inside the tolerance band
    settle    ``settle_cycles`` after the last change, and successive windows agree
    record    ``record_cycles`` whole cycles; the step result is their lock-in

A correction is an *update*; a step that needs more than ``max_updates`` fails with a reason.
The ramp (and every raise) is `control.run.sweep.approach`; the result is
`control.run.sweep.step_result`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from control.run.errors import OpenLoopError
from control.run.safety import AxisSignals, SafetyLimits
from control.run.stream import DriveStream
from control.run.sweep.approach import (
    GUARD_FRACTION,
    LOAD_GUARD_FRACTION,
    LOAD_MARGIN,
    RAISE_STOP,
    Approach,
)
from control.run.sweep.dwell_states import DwellMachine, DwellState
from control.run.sweep.step_result import StepResult
from control.signal.controller import (
    AmplitudeController,
    Assessment,
    DrivePredictor,
    orbit_peak_radius,
)
from control.signal.lockin import LockIn, LockInAccumulator, cycles_to_samples
from control.wire.step_plan import StepPlan
from control.wire.sweep_spec import SweepSpec

__all__ = ["StepResult", "StepRunner"]

log = logging.getLogger(__name__)


class StepRunner(Approach):
    """Runs dwells on a `DriveStream`; keeps what it learns between them (`DrivePredictor`).

    The approach to each drive (start, watched raises, break-away) is `Approach`'s.

    Parameters
    ----------
    stream : DriveStream
    spec : SweepSpec
    limits : SafetyLimits
    emit : callable(kind, message, sample)
        Event sink (warnings, info).
    """

    def __init__(
        self,
        stream: DriveStream,
        spec: SweepSpec,
        limits: SafetyLimits,
        emit: Callable[[str, str, int], None],
    ) -> None:
        self.stream = stream
        self.spec = spec
        self.limits = limits
        self.emit = emit
        self.cm = stream.cm
        self.fs = self.cm.sample_rate_hz
        self.lockin = LockIn(self.fs)
        self.signals = AxisSignals.from_channel_map(self.cm)
        self.predictor = DrivePredictor(orbit=spec.target_kind == "displacement")
        self.cfg = spec.control
        # drive row of each axis, and the nominal shaker gains [N/V]
        self.ao_row = [self.cm.ao_for_axis("x"), self.cm.ao_for_axis("y")]
        self.gain_n_per_v = np.array(
            [self.cm.ao[r].nominal_force_n_per_v for r in self.ao_row]
        )
        self.open_loop_checked = np.zeros(2, dtype=bool)
        self.limited_by = ""  # what held the drive back in the present step
        self.ceiling_v = np.inf
        self._guard_reason = ""  # the soft limit's event in the present step, if any
        self.on_update: Callable[[int], None] | None = None
        #: the present dwell's state (approach, converge, settle, record, done)
        self.dwell = DwellMachine()
        self._last_drive: np.ndarray | None = None  # (X, Y) drive of the last converged step
        self._last_jacobian: np.ndarray | None = None
        self._compliance: dict[float, float] = {}  # largest orbit per newton at a frequency
        self._left_hz = 0.0  # the frequency the last frequency change left [Hz]
        self._radii: list[float] = []  # recent block maxima of the orbit (`_outside_growth`)
        self._drives: list[np.ndarray] = []  # the drive (phasors, frequency) at those blocks
        stream.guard = self._guard

    def _guard(self, eng: np.ndarray) -> str:
        """The soft limit on one block: why it is over `GUARD_FRACTION` of a trip level, or ""."""
        lim = self.limits
        disp = self.signals.displacement(eng)
        radius = float(np.max(np.hypot(disp[0], disp[1])))
        if radius > GUARD_FRACTION * lim.displacement_limit_m:
            return (f"the orbit reached {radius * 1e6:.1f} um, over {100 * GUARD_FRACTION:.0f} % "
                    f"of the {lim.displacement_limit_m * 1e6:.4g} um limit")
        growing = self._outside_growth(radius)
        if growing:
            return growing
        load = float(np.max(np.abs(self.signals.load(eng))))
        if load > LOAD_GUARD_FRACTION * lim.max_load_n:
            return (f"the load reached {load:.1f} N, over {100 * LOAD_GUARD_FRACTION:.0f} % of "
                    f"the {lim.max_load_n:g} N limit")
        return ""

    def _outside_growth(self, radius: float) -> str:
        """An orbit growing while the drive is held (an outside change: amplifier gain, plant)
        so fast that it would pass the limit before the drive already written has played: why,
        or "". Growth: the largest block radius of the last cycle against the cycle before."""
        stream, synth, lim = self.stream, self.stream.synth, self.limits
        n = max(1, int(np.ceil(self.fs / max(synth.freq_hz, 1e-9) / stream.block)))
        held = stream.ahead_blocks + 1 + n  # blocks over which our own changes still show
        state = np.concatenate([synth.phasors, [synth.freq_hz]])
        self._radii.append(radius)
        self._drives.append(state)
        del self._radii[:-2 * n]
        del self._drives[:-held]
        if len(self._radii) < 2 * n or len(self._drives) < held:
            return ""
        if stream.other_drive_end > stream.sample - (2 * n + held) * stream.block:
            # a late host's ring played an earlier, smaller drive (friction may have stuck the
            # housing): the orbit regrowing at the drive it had is not an outside change
            # (issue 21: that regrowth halved the drive and the step did not converge)
            return ""
        # a held drive is the same array of values, bit for bit (np.allclose cost 0.5 ms a
        # block here)
        if any(not np.array_equal(d, state) for d in self._drives):
            return ""  # the controller moved the drive: its own raises are watched elsewhere
        last, prev = max(self._radii[n:]), max(self._radii[:n])
        growth = (last - prev) / n  # per block
        if (last > 0.5 * lim.displacement_limit_m
                and last + growth * (stream.ahead_blocks + 1) > lim.displacement_limit_m):
            return (f"the orbit grows {growth * 1e6:.1f} um per block at a held drive "
                    f"({last * 1e6:.1f} um): it would pass the {lim.displacement_limit_m * 1e6:.4g}"
                    " um limit before the drive already written has played")
        return ""

    def _measure(self, plan: StepPlan, first: int, last: int) -> tuple[np.ndarray, ...]:
        """Lock-in of [first, last): controlled (2,), other (2,), drive (2,) in the run's frame,
        and the standard errors of controlled and other (2,) each."""
        self.stream.advance_to(last, held=True)
        ai, ao = self.stream.window(first, last)
        f = plan.freq_hz
        other_kind = "load" if plan.target_kind == "displacement" else "displacement"
        both = np.concatenate([self.signals.controlled(ai, plan.target_kind),
                               self.signals.controlled(ai, other_kind)])
        z, sigma = self.lockin.fundamental_with_error(both, first, f)
        drive = self._axis_drive(self.lockin.fundamental(ao, first, f))
        return z[:2], z[2:], drive, sigma[:2], sigma[2:]

    def _check_open_loop(self, plan: StepPlan, drive: np.ndarray, sample: int,
                         first: int, last: int) -> None:
        """Drive without load on a driven axis -> `OpenLoopError`."""
        ai, _ = self.stream.window(first, last)
        load = self.lockin.fundamental(self.signals.load(ai), first, plan.freq_hz)
        expected = np.abs(drive) * self.gain_n_per_v
        lim = self.limits
        for axis in range(2):
            if self.open_loop_checked[axis] or expected[axis] < lim.open_loop_min_load_n:
                continue
            if abs(load[axis]) < lim.open_loop_min_ratio * expected[axis]:
                ao_name = self.cm.ao[self.ao_row[axis]].name
                raise OpenLoopError(
                    f"open loop: check the stinger and the amplifier ({ao_name} drives "
                    f"{abs(drive[axis]):.3f} V, nominally {expected[axis]:.1f} N, but load cell "
                    f"{self.signals.load_names[axis]} reads {abs(load[axis]):.2f} N)",
                    sample, "open_loop",
                )
            self.open_loop_checked[axis] = True

    @staticmethod
    def _drift(plan: StepPlan, now: tuple[np.ndarray, ...], before: tuple[np.ndarray, ...]
               ) -> float:
        """Change between two windows at the same drive, relative, beyond their noise.

        ``now``/``before``: (controlled, other, s_controlled, s_other). A change within three
        standard errors of the two estimates is noise, not drift.
        """
        ctrl, other, s_ctrl, s_other = now
        p_ctrl, p_other, ps_ctrl, ps_other = before
        act = np.abs(plan.shape) > 0
        scale_c = np.abs(plan.shape)[act]
        scale_o = np.maximum(np.abs(other), np.abs(p_other))[act] + 1e-12
        dc = np.maximum(np.abs(ctrl - p_ctrl)[act] - 3 * np.hypot(s_ctrl, ps_ctrl)[act], 0.0)
        do = np.maximum(np.abs(other - p_other)[act] - 3 * np.hypot(s_other, ps_other)[act], 0.0)
        return max(float(np.max(dc / scale_c)), float(np.max(do / scale_o)))

    # --- the dwell --------------------------------------------------------------------------
    def run(self, plan: StepPlan) -> StepResult:
        """Run one dwell; returns its result (converged or with the reason it did not)."""
        spec, cfg, stream, synth = self.spec, self.cfg, self.stream, self.stream.synth
        f = plan.freq_hz
        start_sample = stream.sample

        def cyc(c: float) -> int:
            return cycles_to_samples(f, self.fs, c)

        stream.guard_event = None
        self._guard_reason = ""
        dwell = self.dwell
        dwell.begin(plan.describe(), start_sample)
        ctl, change_end = self._start(plan)
        dwell.to(DwellState.CONVERGE, change_end)
        self.limited_by = ""

        updates = 0
        guarded = 0  # soft-limit events in this step
        breakaways = 0  # raises of a housing that did not move
        w = cyc(cfg.window_cycles)
        settle_tol = cfg.settle_tolerance_pct / 100.0
        prev_ok: tuple[np.ndarray, ...] | None = None  # the last in-tolerance window
        prev_win: tuple[int, np.ndarray] | None = None  # (change_end, response) of the last
        next_free = change_end + cyc(cfg.wait_cycles)
        while True:
            settle_end = change_end + cyc(spec.settle_cycles)
            # after an in-tolerance window, jump to the one that ends with the settling time
            w0 = next_free if prev_ok is None else max(next_free, settle_end - w)
            ctrl, other, drive, s_ctrl, s_other = self._measure(plan, w0, w0 + w)
            disp_w, load_w = (other, ctrl) if plan.target_kind == "load" else (ctrl, other)
            self._note_compliance(f, orbit_peak_radius(disp_w), float(np.max(np.abs(load_w))))
            if log.isEnabledFor(logging.DEBUG):
                log.debug("%s window %d-%d drive %s response %s", plan.describe(), w0, w0 + w,
                          np.round(drive, 4), np.round(ctrl, 9))
            next_free = w0 + w
            if stream.guard_event is not None:
                # the soft limit halved the drive: never again this close in this step
                _, why = stream.guard_event
                stream.guard_event = None
                guarded += 1
                self.emit("warning", f"{plan.describe()}: drive halved, {why}", next_free)
                ctl.max_drive_v = min(ctl.max_drive_v, float(np.max(np.abs(drive))))
                self._guard_reason = f"the soft limit ({why})"
                ctl.forget()
                if guarded >= 2 or updates >= spec.max_updates:
                    ctl.saturated = True
                    self.limited_by = f"the soft limit ({why})"
                    dwell.to(DwellState.DONE, next_free)
                    return self._failed(plan, w0, w0 + w, updates, start_sample,
                                        f"stopped below the limits: {why}",
                                        ctl.assess(ctrl))
                change_end, next_free = synth.sample, synth.sample + cyc(cfg.wait_cycles)
                updates += 1
                prev_ok = prev_win = None
                dwell.to(DwellState.CONVERGE, change_end)
                continue
            if not self.open_loop_checked[np.abs(plan.shape) > 0].all():
                self._check_open_loop(plan, drive, w0 + w, w0, w0 + w)
            assess = ctl.assess(ctrl, cfg.aim_fraction if prev_ok is None else 1.0)
            # a load reached with the orbit past the displacement margin is not a result: the
            # correction below brings the orbit back to the margin and the step fails with it
            orbit_over = (plan.target_kind == "load" and cfg.algorithm != "proportional"
                          and orbit_peak_radius(other) > self._response_cap("displacement"))
            if assess.within and not orbit_over:
                dwell.to(DwellState.SETTLE, next_free)
                if prev_ok is not None and next_free >= settle_end:
                    change = self._drift(plan, (ctrl, other, s_ctrl, s_other), prev_ok)
                    waited = next_free - change_end
                    if change <= settle_tol or waited >= cyc(cfg.max_settle_cycles):
                        if change > settle_tol:
                            self.emit("warning", f"{plan.describe()}: response not settled "
                                      f"after {cfg.max_settle_cycles} cycles (successive "
                                      f"windows differ by {100 * change:.2f} %); recording",
                                      next_free)
                        dwell.to(DwellState.RECORD, next_free)
                        result = self._record(plan, ctl, next_free, updates, start_sample)
                        if result.converged or updates >= spec.max_updates:
                            if result.converged:
                                self._remember(plan, result, ctl)
                            dwell.to(DwellState.DONE, result.last_sample)
                            return result
                        # drifted out during the recording: correct and go round again
                        rec_ctrl = result.controlled
                        assert rec_ctrl is not None
                        rec_load = (rec_ctrl if plan.target_kind == "load"
                                    else result.harmonics[self.signals.load_rows, 0])
                        dwell.to(DwellState.CONVERGE, result.last_sample)
                        change_end, next_free = self._correct(
                            plan, ctl, self._axis_drive(synth.to_absolute(synth.phasors)), rec_ctrl,
                            rec_load)
                        updates += 1
                        prev_ok = None
                        continue
                prev_ok = (ctrl, other, s_ctrl, s_other)
                continue
            prev_ok = None
            dwell.to(DwellState.CONVERGE, next_free)
            # a lightly damped housing is still ringing after a change: correct only once two
            # successive windows agree to within a quarter of the remaining error (Newton on
            # a transient misleads J), or once the settling time has passed
            last_win, prev_win = prev_win, (change_end, ctrl)
            if cfg.algorithm != "proportional" and next_free < settle_end and not orbit_over:
                err = float(np.linalg.norm((ctl.target_for(ctrl) - ctrl)[np.abs(plan.shape) > 0]))
                if last_win is None or last_win[0] != change_end:
                    if err < 0.2 * float(np.linalg.norm(plan.shape)):
                        continue
                elif float(np.linalg.norm(ctrl - last_win[1])) > 0.25 * err:
                    continue
            if (plan.target_kind == "displacement" and cfg.algorithm != "proportional"
                    and ctl.is_stuck(ctrl) and breakaways < spec.max_updates):
                # the search for break-away is not a correction: it has its own budget
                change_end, next_free = self._break_away(plan, ctl, drive, ctrl)
                breakaways += 1
                continue
            if updates >= spec.max_updates:
                why = f"did not converge in {spec.max_updates} updates ({assess.describe()})"
                if ctl.saturated or self.limited_by:
                    why += f"; the drive is held by {self.limited_by or 'the drive limit'}"
                dwell.to(DwellState.DONE, next_free)
                return self._failed(plan, w0, w0 + w, updates, start_sample, why, assess)
            if plan.target_kind == "load":
                change_end, next_free = self._correct(plan, ctl, drive, ctrl, ctrl, other)
                if orbit_over:
                    # friction makes the orbit grow faster than the load (stick, then slip):
                    # the drive that passed the margin is never approached again in this step
                    ctl.max_drive_v = min(ctl.max_drive_v,
                                          float(np.max(np.abs(synth.target_phasors))))
                    self._guard_reason = self._guard_reason or (
                        f"the displacement limit ({self.limits.displacement_limit_m * 1e6:.4g} "
                        f"um; the orbit reached {orbit_peak_radius(other) * 1e6:.1f} um at "
                        f"{abs(ctrl).max():.1f} N)")
            else:
                change_end, next_free = self._correct(plan, ctl, drive, ctrl, other)
            updates += 1
            if self.on_update is not None:
                self.on_update(updates)

    def _correct(self, plan: StepPlan, ctl: AmplitudeController, drive: np.ndarray,
                 response: np.ndarray,
                 load: np.ndarray, displacement: np.ndarray | None = None) -> tuple[int, int]:
        """One controller update; returns (end of the ramp, first sample worth measuring).

        The controller bounds its own response (`AmplitudeController.response_limit`); the
        quantity it does not control is bounded here, scaled from its measured value at
        ``drive``: the load (2,) within `LOAD_MARGIN` of the load limit and, for a load target,
        the ``displacement`` (2,) within `DISPLACEMENT_MARGIN` of the displacement limit. A
        target the rig cannot reach safely ends as a step that did not converge, not as a trip.
        """
        synth = self.stream.synth
        new = ctl.update(drive, response)
        ratio = float(np.linalg.norm(new)) / max(float(np.linalg.norm(drive)), 1e-12)
        cap = LOAD_MARGIN * self.limits.max_load_n
        with np.errstate(divide="ignore", invalid="ignore"):
            predicted = np.abs(load) * np.abs(new) / np.abs(drive)
        over = np.isfinite(predicted) & (predicted > cap)
        held = ""
        if over.any():
            new = new * float(np.min(cap / predicted[over]))
            held = f"the load limit ({self.limits.max_load_n:g} N)"
        if displacement is not None and float(np.linalg.norm(drive)) > 0:
            cap_d = self._response_cap("displacement")
            pred_d = orbit_peak_radius(displacement) * ratio
            if pred_d > cap_d:
                new = new * (cap_d / pred_d)
                held = (f"the displacement limit ({self.limits.displacement_limit_m * 1e6:.4g} "
                        "um)")
        if held:
            ctl.saturated = True
            self.limited_by = held
        elif ctl.limited_by == "response":
            self.limited_by = (
                f"the displacement limit ({self.limits.displacement_limit_m * 1e6:.4g} um)"
                if ctl.limit_on_orbit else f"the load limit ({self.limits.max_load_n:g} N)")
        elif ctl.saturated:
            self.limited_by = (self._guard_reason
                               or f"the drive limit ({self.limits.max_drive_v:g} V)")
        rows = synth.from_absolute(self._rows_drive(new))
        if (displacement is None and self.cfg.algorithm != "proportional"
                and float(np.linalg.norm(rows))
                > (1.0 + self.cfg.start_growth) * float(np.linalg.norm(synth.phasors))):
            # a raise larger than one latency's worth is watched block by block: where the
            # plant is steeper than its estimate (near break-away, near a resonance) it stops
            # before the orbit runs away
            held_before = self.limited_by
            self._watched_raise(plan, rows, RAISE_STOP, self.cfg.start_growth)
            ctl.max_drive_v = min(ctl.max_drive_v, self.ceiling_v)
            if self.limited_by:
                ctl.saturated = True
            else:
                self.limited_by = held_before
            end = synth.sample
        else:
            end = self._ramp(rows, None)
        return end, end + cycles_to_samples(synth.freq_hz, self.fs, self.cfg.wait_cycles)

    def _record(self, plan: StepPlan, ctl: AmplitudeController, first: int, updates: int,
                start_sample: int) -> StepResult:
        """Record ``record_cycles`` whole cycles from ``first``, demodulated as they arrive."""
        f = plan.freq_hz
        last = first + cycles_to_samples(f, self.fs, self.spec.record_cycles)
        n_ai = len(self.cm.ai)
        acc = LockInAccumulator(self.fs, f, first, last, n_ai + 4 + len(self.cm.ao))
        sig = self.signals

        def feed(b0: int, ai: np.ndarray, ao: np.ndarray) -> None:
            acc.add(b0, np.vstack([ai, sig.displacement(ai), sig.load(ai), ao]))

        if self.stream.sample > first:  # the start of the window is already in
            ai, ao = self.stream.window(first, min(self.stream.sample, last))
            feed(first, ai, ao)
        self.stream.taps.append(feed)
        try:
            self.stream.advance_to(last, held=True)
        finally:
            self.stream.taps.remove(feed)
        harm, _, sigma = acc.result()
        disp, load = harm[n_ai:n_ai + 2, 0], harm[n_ai + 2:n_ai + 4, 0]
        ctrl, other = (disp, load) if plan.target_kind == "displacement" else (load, disp)
        s_other = (sigma[n_ai:n_ai + 2] if plan.target_kind == "load"
                   else sigma[n_ai + 2:n_ai + 4])
        assess = ctl.assess(ctrl)
        reason = "" if assess.within else (
            f"recorded response outside the tolerance ({assess.describe()})")
        act = np.abs(plan.shape) > 0
        rel = s_other[act] / np.maximum(np.abs(other[act]), 1e-300)
        if np.max(rel) > 0.02:
            other_kind = "load" if plan.target_kind == "displacement" else "displacement"
            self.emit("warning", f"{plan.describe()}: the {other_kind} is not periodic (its 1X "
                      f"is uncertain by {100 * np.max(rel):.1f} % over the recording: stick-slip "
                      "or a transient)", last)
        return StepResult(
            plan, first, last, updates, assess.within, reason, harm[:n_ai], harm[n_ai + 4:, 0],
            self.cm.ai_names, self.cm.ao_names, start_sample, assess, ctrl,
        )

    def _failed(self, plan: StepPlan, first: int, last: int, updates: int, start_sample: int,
                reason: str, assess: Assessment) -> StepResult:
        ai, ao = self.stream.window(first, last)
        harm, _ = self.lockin.demodulate(ai, first, plan.freq_hz)
        drive_rows = self.lockin.fundamental(ao, first, plan.freq_hz)
        return StepResult(plan, first, last, updates, False, reason, harm, drive_rows,
                          self.cm.ai_names, self.cm.ao_names, start_sample, assess)

    def _remember(self, plan: StepPlan, result: StepResult, ctl: AmplitudeController) -> None:
        assert result.controlled is not None
        drive = self._axis_drive(result.drive_v)
        self.predictor.remember(plan.freq_hz, plan.shape, result.controlled, drive, ctl.jacobian)
        self._last_drive, self._last_jacobian = drive, ctl.jacobian.copy()
