"""One dwell of a sweep: ramp, converge, settle, record.

    ramp      drive and frequency move to the predicted drive (ramped, phase-continuous)
    converge  wait ``wait_cycles``, lock-in over ``window_cycles``, correct (Newton-Broyden),
              until the controlled amplitudes are inside the tolerance band
    settle    ``settle_cycles`` after the last change, and successive windows agree
    record    ``record_cycles`` whole cycles; the step result is their lock-in

A correction is an *update*; a step that needs more than ``max_updates`` fails with a reason.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from control.controller import (
    AmplitudeController,
    Assessment,
    DrivePredictor,
    ProportionalController,
    orbit_peak_radius,
)
from control.errors import OpenLoopError
from control.lockin import LockIn, LockInAccumulator, cycles_to_samples
from control.plan import StepPlan
from control.safety import AxisSignals, SafetyLimits
from control.spec import SweepSpec
from control.stream import DriveStream

log = logging.getLogger(__name__)

#: A correction never asks for more than this fraction of the load limit (predicted from the
#: measured load): the margin covers harmonics, noise and the prediction's error.
LOAD_MARGIN = 0.9
#: ... nor for an orbit radius above this fraction of the displacement limit (predicted from the
#: plant estimate J and from the measured secant): the margin covers the higher harmonics of a
#: stick-slip orbit, noise and the prediction's error.
DISPLACEMENT_MARGIN = 0.8
#: At a new frequency the drive starts from this fraction of the predicted one (`_start`).
START_FRACTION = 0.8
#: ... or of the drive predicted from a converged step at this very frequency (its tangent).
START_FRACTION_KNOWN = 0.9
#: The soft limit: an orbit radius or a load over this fraction of its trip level halves the
#: drive at once (`DriveStream.guard`); the step then goes on below it, or fails after twice.
#: Between the correction margins above and the trip.
GUARD_FRACTION = 0.9
LOAD_GUARD_FRACTION = 0.95
#: A correction that raises the drive stops where the orbit passes this fraction of the target.
RAISE_STOP = 1.2


@dataclass
class StepResult:
    """What a dwell achieved (contract A's step dict, via `to_dict`).

    Attributes
    ----------
    plan : StepPlan
    first_sample, last_sample : int
        Half-open span of the recorded whole cycles (run sample indices).
    updates : int
        Controller corrections made in this step.
    converged : bool
    reason : str
        Why not converged ("" when converged).
    harmonics : complex array (n_ai, 5)
        1X..5X of every AI channel over the span, engineering units.
    drive_v : complex array (n_ao,)
        1X of every drive over the span [V].
    ai_names, ao_names : list of str
    start_sample : int
        Run sample at which the step began (its ramp).
    """

    plan: StepPlan
    first_sample: int
    last_sample: int
    updates: int
    converged: bool
    reason: str
    harmonics: np.ndarray
    drive_v: np.ndarray
    ai_names: list[str]
    ao_names: list[str]
    start_sample: int = 0
    assessment: Assessment | None = field(default=None, repr=False)
    controlled: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict in the layout of contract A."""
        p = self.plan
        return {
            "index": int(p.index),
            "freq_hz": float(p.freq_hz),
            "target_kind": p.target_kind,
            "target_value": float(p.target_value),
            "motion": p.motion,
            "first_sample": int(self.first_sample),
            "last_sample": int(self.last_sample),
            "updates": int(self.updates),
            "converged": bool(self.converged),
            "reason": self.reason,
            "harmonics": {
                name: [[float(z.real), float(z.imag)] for z in self.harmonics[i]]
                for i, name in enumerate(self.ai_names)
            },
            "drive_v": {
                name: [float(self.drive_v[i].real), float(self.drive_v[i].imag)]
                for i, name in enumerate(self.ao_names)
            },
        }


class StepRunner:
    """Runs dwells on a `DriveStream`; keeps what it learns between them (`DrivePredictor`).

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
        self.predictor = DrivePredictor()
        self.cfg = spec.control
        # drive row of each axis, and the nominal shaker gains [N/V]
        self.ao_row = [self.cm.ao_for_axis("x"), self.cm.ao_for_axis("y")]
        self.gain_n_per_v = np.array(
            [self.cm.ao[r].nominal_force_n_per_v for r in self.ao_row]
        )
        self.open_loop_checked = np.zeros(2, dtype=bool)
        self.limited_by = ""  # what held the drive back in the present step
        self._guard_reason = ""  # the soft limit's event in the present step, if any
        self.on_update: Callable[[int], None] | None = None
        self._last_drive: np.ndarray | None = None  # (X, Y) drive of the last converged step
        self._last_jacobian: np.ndarray | None = None
        stream.guard = self._guard

    def _guard(self, eng: np.ndarray) -> str:
        """The soft limit on one block: why it is over `GUARD_FRACTION` of a trip level, or ""."""
        lim = self.limits
        disp = self.signals.displacement(eng)
        radius = float(np.max(np.hypot(disp[0], disp[1])))
        if radius > GUARD_FRACTION * lim.displacement_limit_m:
            return (f"the orbit reached {radius * 1e6:.1f} um, over {100 * GUARD_FRACTION:.0f} % "
                    f"of the {lim.displacement_limit_m * 1e6:.4g} um limit")
        load = float(np.max(np.abs(self.signals.load(eng))))
        if load > LOAD_GUARD_FRACTION * lim.max_load_n:
            return (f"the load reached {load:.1f} N, over {100 * LOAD_GUARD_FRACTION:.0f} % of "
                    f"the {lim.max_load_n:g} N limit")
        return ""

    # --- helpers ----------------------------------------------------------------------------
    def _prior_jacobian(self, plan: StepPlan) -> np.ndarray:
        g = self.gain_n_per_v
        if plan.target_kind == "load":
            return np.diag(g).astype(np.complex128)
        return np.diag(g / self.cfg.initial_stiffness_n_per_m).astype(np.complex128)

    def _axis_drive(self, phasors_rows: np.ndarray) -> np.ndarray:
        """AO-row phasors -> (X, Y) drive."""
        return np.asarray(phasors_rows, dtype=np.complex128)[self.ao_row]

    def _rows_drive(self, drive_xy: np.ndarray) -> np.ndarray:
        """(X, Y) drive -> AO-row phasors."""
        out = np.zeros(len(self.cm.ao), dtype=np.complex128)
        out[self.ao_row] = drive_xy
        return out

    def _ramp(self, target_rows: np.ndarray, freq_hz: float | None) -> int:
        """Ramp to new phasors (synth frame) within the envelope-rate limit; the end sample."""
        synth = self.stream.synth
        delta = float(np.max(np.abs(target_rows - synth.phasors)))
        ramp_s = max(self.cfg.min_ramp_s, delta / self.limits.max_drive_rate_v_per_s)
        n = synth.ramp_to(target_rows, freq_hz, ramp_s)
        return synth.sample + n

    def _measure(self, plan: StepPlan, first: int, last: int) -> tuple[np.ndarray, ...]:
        """Lock-in of [first, last): controlled (2,), other (2,), drive (2,) in the run's frame,
        and the standard errors of controlled and other (2,) each."""
        self.stream.advance_to(last)
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

    def _start(self, plan: StepPlan) -> tuple[AmplitudeController, int]:
        """Predict the step's drive and J, make its controller, ramp there; (controller, end of
        the ramp)."""
        cfg, synth = self.cfg, self.stream.synth
        pred = self.predictor.predict(plan.freq_hz, plan.shape) if cfg.predict else None
        if (pred is None and not cfg.predict and self._last_drive is not None
                and self._last_jacobian is not None):
            pred = self._last_drive, self._last_jacobian
        if pred is not None:
            guess, jac = pred
        else:
            jac = self._prior_jacobian(plan)
            a = np.abs(plan.shape) > 0
            guess = np.zeros(2, dtype=np.complex128)
            guess[a] = np.linalg.solve(jac[np.ix_(a, a)], plan.shape[a])
        ctl: AmplitudeController
        if cfg.algorithm == "proportional":
            ctl = ProportionalController(
                plan.shape, jac, self.spec.tolerance, max_drive_v=self.limits.max_drive_v,
                max_growth=cfg.max_growth, gain=cfg.proportional_gain,
            )
        else:
            displacement = plan.target_kind == "displacement"
            ctl = AmplitudeController(
                plan.shape, jac, self.spec.tolerance, max_drive_v=self.limits.max_drive_v,
                max_growth=cfg.max_growth, prior_only=pred is None and displacement,
                rescale_first=pred is not None and not self.predictor.knows(plan.freq_hz),
                response_limit=self._response_cap(plan.target_kind),
                limit_on_orbit=displacement, breakaway_growth=cfg.breakaway_growth,
            )
        # the common phase is free: turn the guess towards the present drive
        rows_guess = self._rows_drive(guess)
        inner = np.vdot(rows_guess, synth.target_phasors)
        if abs(inner) > 0:
            rows_guess = rows_guess * (inner / abs(inner))
        # no load measured at this frequency yet: hold the guess to the nominal shaker gain's
        # share of the load limit, and to the drive limit
        nominal = np.abs(self._axis_drive(rows_guess)) * self.gain_n_per_v
        cap = LOAD_MARGIN * self.limits.max_load_n
        if nominal.max() > cap:
            rows_guess *= cap / float(nominal.max())
        # nor above what J predicts (the plant without friction, from zero drive) for the
        # displacement: a housing that slips more freely than at the last step stays in bounds.
        # Where a step at this frequency converged, the guess is its tangent, which predicts
        # the target itself (J from zero would overstate a friction-held orbit by the offset)
        known = pred is not None and self.predictor.knows(plan.freq_hz)
        if (plan.target_kind == "displacement" and cfg.algorithm != "proportional"
                and not (known and orbit_peak_radius(plan.shape)
                         <= self._response_cap("displacement"))):
            a = np.abs(plan.shape) > 0
            lin = np.zeros(2, dtype=np.complex128)
            lin[a] = jac[np.ix_(a, a)] @ self._axis_drive(rows_guess)[a]
            cap_d = self._response_cap("displacement")
            if orbit_peak_radius(lin) > cap_d:
                rows_guess *= cap_d / orbit_peak_radius(lin)
        peak = float(np.max(np.abs(rows_guess)))
        if peak > self.limits.max_drive_v:
            rows_guess *= self.limits.max_drive_v / peak
        same_freq = abs(plan.freq_hz - synth.freq_hz) <= 1e-9 * plan.freq_hz
        lowering = float(np.linalg.norm(rows_guess)) <= float(np.linalg.norm(synth.phasors))
        if (cfg.algorithm == "proportional" or (same_freq and plan.target_kind == "displacement")
                or (same_freq and lowering)):
            return ctl, self._ramp(rows_guess, plan.freq_hz)
        # a new frequency: the drive predicted from other frequencies is a guess, and the path
        # there may cross a resonance. Move the frequency at no more than `START_FRACTION` of
        # the guess, then raise the drive watching every block; stop near the target. A load
        # target is raised the same way: nothing predicts its orbit before it is measured, and
        # the raise stops at the displacement margin (the step then fails with that reason).
        low = ((START_FRACTION_KNOWN if known else START_FRACTION)
               * float(np.max(np.abs(rows_guess))))
        if plan.freq_hz < synth.freq_hz and not known:
            # downwards, towards the stiffness line: a drive predicted from above (where mass
            # dominates) can be many times too much; start from the nominal stiffness instead
            # (not needed where a step at this very frequency converged: it predicts from here)
            a = np.abs(plan.shape) > 0
            prior = np.zeros(2, dtype=np.complex128)
            prior[a] = np.linalg.solve(self._prior_jacobian(plan)[np.ix_(a, a)], plan.shape[a])
            low = min(low, START_FRACTION * float(np.max(np.abs(prior))))
        now = float(np.max(np.abs(synth.phasors)))
        if now > low:
            self.stream.advance_to(self._ramp(synth.phasors * (low / now), None))
        # the frequency moves at the lower of the present and the start drive (upwards from a
        # low frequency the path may pass the resonance), along the guess's direction
        level = min(now, low) if now > 0 else low
        start = rows_guess * (level / max(float(np.max(np.abs(rows_guess))), 1e-12))
        self.stream.advance_to(self._ramp(start, plan.freq_hz))
        self._watched_raise(plan, rows_guess, 0.9, cfg.start_growth)
        if self.limited_by:
            ctl.saturated = True
        return ctl, synth.sample

    def _response_cap(self, kind: str) -> float:
        """The largest response a correction may aim at: a margin under the trip level."""
        if kind == "displacement":
            return DISPLACEMENT_MARGIN * self.limits.displacement_limit_m
        return LOAD_MARGIN * self.limits.max_load_n

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
        ctl, change_end = self._start(plan)
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
                    return self._failed(plan, w0, w0 + w, updates, start_sample,
                                        f"stopped below the limits: {why}",
                                        ctl.assess(ctrl))
                change_end, next_free = synth.sample, synth.sample + cyc(cfg.wait_cycles)
                updates += 1
                prev_ok = prev_win = None
                continue
            if not self.open_loop_checked[np.abs(plan.shape) > 0].all():
                self._check_open_loop(plan, drive, w0 + w, w0, w0 + w)
            assess = ctl.assess(ctrl, cfg.aim_fraction if prev_ok is None else 1.0)
            # a load reached with the orbit past the displacement margin is not a result: the
            # correction below brings the orbit back to the margin and the step fails with it
            orbit_over = (plan.target_kind == "load" and cfg.algorithm != "proportional"
                          and orbit_peak_radius(other) > self._response_cap("displacement"))
            if assess.within and not orbit_over:
                if prev_ok is not None and next_free >= settle_end:
                    change = self._drift(plan, (ctrl, other, s_ctrl, s_other), prev_ok)
                    waited = next_free - change_end
                    if change <= settle_tol or waited >= cyc(cfg.max_settle_cycles):
                        if change > settle_tol:
                            self.emit("warning", f"{plan.describe()}: response not settled "
                                      f"after {cfg.max_settle_cycles} cycles (successive "
                                      f"windows differ by {100 * change:.2f} %); recording",
                                      next_free)
                        result = self._record(plan, ctl, next_free, updates, start_sample)
                        if result.converged or updates >= spec.max_updates:
                            if result.converged:
                                self._remember(plan, result, ctl)
                            return result
                        # drifted out during the recording: correct and go round again
                        rec_ctrl = result.controlled
                        assert rec_ctrl is not None
                        rec_load = (rec_ctrl if plan.target_kind == "load"
                                    else result.harmonics[self.signals.load_rows, 0])
                        change_end, next_free = self._correct(
                            plan, ctl, self._axis_drive(synth.to_absolute(synth.phasors)), rec_ctrl,
                            rec_load)
                        updates += 1
                        prev_ok = None
                        continue
                prev_ok = (ctrl, other, s_ctrl, s_other)
                continue
            prev_ok = None
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

    def _break_away(self, plan: StepPlan, ctl: AmplitudeController, drive: np.ndarray,
                    response: np.ndarray) -> tuple[int, int]:
        """Raise the drive of a housing that does not move until it moves (`_watched_raise`
        towards the drive limit, stopping at ``stuck_fraction`` of the target); returns (end of
        the raise, first sample worth measuring).

        Near break-away a friction-held housing answers a small raise with a large jump (the
        Den Hartog law, ``X ~ sqrt(F^2 - F_0^2) / k``; at resonance ``(F - F_0) / (c w)``), and
        a raise is only seen a latency later. Raising by at most ``breakaway_growth`` (10 %) per
        latency, the jump is what one latency's raise can cause: within ~0.46 F_0 / k
        quasi-statically, 0.1 F_0 / (c w) at resonance.
        """
        ctl.note_stuck(drive, response)
        top = self.stream.synth.phasors * (self.limits.max_drive_v
                                           / float(np.max(np.abs(self.stream.synth.phasors))))
        self._watched_raise(plan, top, ctl.stuck_fraction, self.cfg.breakaway_growth)
        if self.limited_by:
            ctl.saturated = True
        end = self.stream.synth.sample
        return end, end + cycles_to_samples(self.stream.synth.freq_hz, self.fs,
                                            self.cfg.wait_cycles)

    def _watched_raise(self, plan: StepPlan, top_rows: np.ndarray, stop_fraction: float,
                       growth: float) -> None:
        """Move the drive block by block towards ``top_rows`` (synthesiser frame), the drive
        vector growing by at most ``growth`` (relative) per latency, watching every block read;
        stop once the orbit (peak radius over the last cycle, about its mean) reaches
        ``stop_fraction`` of the target's, or when the drive limit, the load margin, the
        displacement margin or the soft limit is reached (then `limited_by` says which).

        The latency is the AO written ahead plus one block and one cycle: a raise is seen that
        much later, so what happens in one latency bounds the overshoot.
        """
        stream, synth, fs = self.stream, self.stream.synth, self.fs
        cyc = cycles_to_samples(synth.freq_hz, fs, 1.0)
        latency = (stream.ahead_blocks + 1) * stream.block + cyc
        if plan.target_kind == "load":
            # a load target may start from a stuck housing: raise it as a break-away is raised
            growth = min(growth, self.cfg.breakaway_growth)
        per_block = (1.0 + growth) ** (stream.block / latency)
        stop_at = (stop_fraction * orbit_peak_radius(plan.shape)
                   if plan.target_kind == "displacement" else np.inf)
        cap_d = self._response_cap("displacement")
        cap_f = LOAD_MARGIN * self.limits.max_load_n
        top = np.asarray(top_rows, dtype=np.complex128)
        self.limited_by = ""
        radius = 0.0
        watch_end = -1  # a load target's final raise is watched for one latency
        while True:
            # towards top (magnitude and phase), the drive vector growing by per_block at most;
            # for a load target (no orbit to stop at) slower as the orbit nears the displacement
            # margin: near break-away a small raise makes a large jump, seen a latency later
            now = synth.phasors
            slow = max(0.1, 1.0 - radius / cap_d) if plan.target_kind == "load" else 1.0
            room = (per_block ** slow - 1.0) * float(np.linalg.norm(now))
            dist = float(np.linalg.norm(top - now))
            final = (dist <= room or room == 0.0
                     or float(np.linalg.norm(top)) <= float(np.linalg.norm(now)))
            rows = top if final else now + (top - now) * (room / dist)
            nominal = float(np.max(np.abs(self._axis_drive(rows)) * self.gain_n_per_v))
            if float(np.max(np.abs(rows))) > self.limits.max_drive_v + 1e-12:
                self.limited_by = f"the drive limit ({self.limits.max_drive_v:g} V)"
            elif nominal > cap_f:
                self.limited_by = f"the load limit ({self.limits.max_load_n:g} N)"
            else:
                synth.ramp_to(rows, None, stream.block / fs)
            stream.cycle()
            if stream.guard_event is not None:
                self.limited_by = f"the soft limit ({stream.guard_event[1]})"
                return
            ai, _ = stream.window(max(stream.sample - cyc, 0), stream.sample)
            disp = self.signals.displacement(ai)
            disp = disp - disp.mean(axis=1, keepdims=True)
            radius = float(np.max(np.hypot(disp[0], disp[1])))
            if radius > cap_d:
                self.limited_by = (f"the displacement limit "
                                   f"({self.limits.displacement_limit_m * 1e6:.4g} um)")
            elif float(np.max(np.abs(self.signals.load(ai)))) > cap_f:
                self.limited_by = f"the load limit ({self.limits.max_load_n:g} N)"
            if radius >= stop_at or self.limited_by:
                return
            if final:
                if plan.target_kind != "load":
                    return
                if watch_end < 0:
                    watch_end = stream.sample + latency
                elif stream.sample >= watch_end:
                    return

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
            self.stream.advance_to(last)
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
