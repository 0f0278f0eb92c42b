"""How a dwell approaches its drive without learning by tripping (issue 11's anticipation).

The margins every drive update keeps from the trip levels, and the moves that get there: the
start of a step (a guess predicted from the steps already run, held inside the margins; a new
frequency is set at zero drive, never glided to under one, and the first drive there is what a
plant estimate at that frequency allows, raised from there), the watched raise
(block by block, at most a given growth per latency, stopped by the orbit, the margins or the soft
limit) and the break-away of a stuck housing. `Approach` is the base of
`control.run.sweep.dwell.StepRunner`,
which provides the attributes declared below and runs the converge-settle-record loop.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from control.run.safety import AxisSignals, SafetyLimits
from control.run.stream import DriveStream
from control.signal.controller import (
    AmplitudeController,
    DrivePredictor,
    ProportionalController,
    orbit_peak_radius,
)
from control.signal.lockin import cycles_to_samples
from control.wire.step_plan import StepPlan
from control.wire.sweep_spec import ControlSettings, SweepSpec
from daq.channels import ChannelMap

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
#: The first drive at a new frequency aims at no more than this fraction of the displacement
#: margin by the plant estimate there (`Approach._plant_compliance`); watched raises go on.
START_MARGIN = 0.5
#: Before a new frequency the drive goes to zero and waits (at most `QUIET_MAX_S`) until the
#: orbit has rung down under this fraction of the displacement limit.
QUIET_FRACTION = 0.05
QUIET_MAX_S = 0.5
#: A watched raise commands the drive for this many blocks at a time (a straight ramp, no
#: faster in any block than the raise allows), not every block: each command rewrites the AO
#: ring's prediction.
RAISE_COMMAND_BLOCKS = 4
#: A watched raise whose orbit passes the displacement margin backs the drive off to this
#: fraction of the margin, scaled from the orbit measured.
BACK_OFF = 0.9


def target_ceiling(kind: str, limits: SafetyLimits, algorithm: str) -> tuple[float, str]:
    """(the largest response the controller brings a step to, why) for a target of ``kind``:
    its orbit radius [m] for "displacement" (within `DISPLACEMENT_MARGIN` of the limit; the
    proportional loop, which predicts nothing, until the soft limit at `GUARD_FRACTION`), its
    load on an axis [N] for "load" (within `LOAD_MARGIN` of the load limit, every algorithm)."""
    margin = "the most the controller aims at, a margin for harmonics, noise and prediction error"
    if kind == "load":
        return LOAD_MARGIN * limits.max_load_n, (
            f"{100 * LOAD_MARGIN:.0f} % of the {limits.max_load_n:g} N load limit, {margin}")
    lim_um = limits.displacement_limit_m * 1e6
    if algorithm == "proportional":
        return GUARD_FRACTION * limits.displacement_limit_m, (
            f"{100 * GUARD_FRACTION:.0f} % of the {lim_um:.4g} um displacement limit, where the "
            "soft limit halves the drive")
    return DISPLACEMENT_MARGIN * limits.displacement_limit_m, (
        f"{100 * DISPLACEMENT_MARGIN:.0f} % of the {lim_um:.4g} um displacement limit, {margin}")


def unreachable_targets(steps: Sequence[StepPlan], limits: SafetyLimits,
                        algorithm: str) -> list[str]:
    """One line per target value the controller would never reach (`target_ceiling`): the
    field, the value, what it asks for, the largest value accepted and why. Its steps would
    spend their updates held at the margin and fail; refused before the run instead."""
    problems = []
    for value in dict.fromkeys(st.target_value for st in steps):
        mine = [st for st in steps if st.target_value == value]
        st = mine[0]
        ceiling, why = target_ceiling(st.target_kind, limits, algorithm)
        if st.target_kind == "load":
            field, asks = "load_n", float(np.max(np.abs(st.shape)))
            what, limit = f"a load of {asks:.4g} N", f"{ceiling:.4g} N"
        else:
            field, asks = "amplitude_m", orbit_peak_radius(st.shape)
            what, limit = f"an orbit radius of {asks * 1e6:.4g} um", f"{ceiling * 1e6:.4g} um"
        if not asks > ceiling * (1 + 1e-12):
            continue
        largest = ceiling * value / asks  # the response scales with the target
        shown = [f"{v:.4g}" if field == "load_n" else f"{v:.4g} ({v * 1e6:.4g} um)"
                 for v in (value, largest)]
        problems.append(
            f"{field} = {shown[0]} ({st.motion}, {len(mine)} step{'s' * (len(mine) > 1)} "
            f"from step {st.number}): asks for {what}, over {limit} ({why}); the largest "
            f"{field} accepted is {shown[1]}")
    return problems


class Approach:
    """The approach half of `StepRunner` (see the module docstring)."""

    stream: DriveStream
    cm: ChannelMap
    spec: SweepSpec
    limits: SafetyLimits
    cfg: ControlSettings
    fs: float
    signals: AxisSignals
    predictor: DrivePredictor
    ao_row: list[int]
    gain_n_per_v: np.ndarray
    limited_by: str
    #: the drive a watched raise backed off to when it passed the displacement margin [V]
    ceiling_v: float
    _last_drive: np.ndarray | None
    _last_jacobian: np.ndarray | None
    _compliance: dict[float, float]
    _guard_reason: str
    _left_hz: float

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

    def _response_cap(self, kind: str) -> float:
        """The largest response a correction may aim at: a margin under the trip level."""
        if kind == "displacement":
            return DISPLACEMENT_MARGIN * self.limits.displacement_limit_m
        return LOAD_MARGIN * self.limits.max_load_n

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
                elasticity=self.predictor.elasticity(plan.freq_hz, plan.shape),
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
        if not same_freq:
            # issue 21: the frequency never glides under a drive (from 0 Hz at the start of a
            # run, or from the last step's frequency): a glide through the ~45 Hz resonance at a
            # growing amplitude tripped 400 N at 150 Hz at 87-126 um. The drive goes to zero,
            # the orbit rings down, the frequency is set, and the step is approached at it.
            self._new_frequency(plan.freq_hz)
        # a drive on at this very frequency (not after a new one, nor after a pause): its orbit
        # is measured, so the step may go on from it
        here = same_freq and float(np.max(np.abs(synth.phasors))) > 0
        lowering = float(np.linalg.norm(rows_guess)) <= float(np.linalg.norm(synth.phasors))
        if (cfg.algorithm == "proportional" or (here and plan.target_kind == "displacement")
                or (here and lowering)):
            return ctl, self._ramp(rows_guess, None)
        # the drive predicted from other frequencies is a guess: start at `START_FRACTION` of
        # it, then raise the drive watching every block; stop near the target. A load target
        # is raised the same way (the raise stops at the displacement margin and the step then
        # fails with that reason).
        low = ((START_FRACTION_KNOWN if known else START_FRACTION)
               * float(np.max(np.abs(rows_guess))))
        if not same_freq and plan.freq_hz < self._left_hz and not known:
            # downwards, towards the stiffness line: a drive predicted from above (where mass
            # dominates) can be many times too much; start from the nominal stiffness instead
            # (not needed where a step at this very frequency converged: it predicts from here)
            a = np.abs(plan.shape) > 0
            prior = np.zeros(2, dtype=np.complex128)
            prior[a] = np.linalg.solve(self._prior_jacobian(plan)[np.ix_(a, a)], plan.shape[a])
            low = min(low, START_FRACTION * float(np.max(np.abs(prior))))
        if not here:
            # and at no more than the load that the plant estimate at this very frequency
            # (1-DOF, lightest damping, widened resonance; or the compliance measured here, if
            # larger) says gives `START_MARGIN` of the displacement margin: what a drive does
            # here is known only once it is measured here (with a drive on here it is: the
            # raise goes on from it)
            start_n = (START_MARGIN * self._response_cap("displacement")
                       / self._plant_compliance(plan.freq_hz,
                                                measured_only=known and self.spec.lubricated))
            low = min(low, start_n / float(np.max(self.gain_n_per_v)))
        now = float(np.max(np.abs(synth.phasors)))
        if now > low:
            self.stream.advance_to(self._ramp(synth.phasors * (low / now), None))
        level = min(now, low) if now > 0 else low
        start = rows_guess * (level / max(float(np.max(np.abs(rows_guess))), 1e-12))
        self.stream.advance_to(self._ramp(start, None))
        # stop near the target; where this frequency's tangent predicts it, at the target itself
        self._watched_raise(plan, rows_guess, 1.0 if known else 0.9, cfg.start_growth)
        if self.limited_by:
            ctl.saturated = True
        ctl.max_drive_v = min(ctl.max_drive_v, self.ceiling_v)
        return ctl, synth.sample

    def _new_frequency(self, freq_hz: float) -> None:
        """Drive to zero, wait for the orbit to ring down, then set ``freq_hz`` (at zero drive
        a frequency change is a step of nothing; the phase stays continuous)."""
        stream, synth = self.stream, self.stream.synth
        self._left_hz = synth.freq_hz
        zero = np.zeros(len(self.cm.ao), dtype=np.complex128)
        if np.any(synth.phasors != 0) or np.any(synth.target_phasors != 0):
            stream.advance_to(self._ramp(zero, None))
        if synth.freq_hz > 0:
            # the free ring of the last orbit (dry: 7 % damping, ~50 ms decay, friction stops
            # it sooner) must not add to the first orbit measured at the new frequency
            cyc = cycles_to_samples(synth.freq_hz, self.fs, 1.0)
            quiet = QUIET_FRACTION * self.limits.displacement_limit_m
            deadline = stream.sample + int(QUIET_MAX_S * self.fs)
            while stream.sample < deadline:
                stream.cycle()
                ai, _ = stream.window(max(stream.sample - cyc, 0), stream.sample)
                disp = self.signals.displacement(ai)
                disp = disp - disp.mean(axis=1, keepdims=True)
                if float(np.max(np.hypot(disp[0], disp[1]))) < quiet:
                    break
        synth.ramp_to(None, freq_hz, 0.0)

    def _plant_compliance(self, freq_hz: float, measured_only: bool = False) -> float:
        """The largest orbit per newton of load [m/N] the rig may have at ``freq_hz``: a 1-DOF
        mass-spring-damper from the nominal parameters (`ControlSettings`), its stiffness and
        mass each anywhere within ``plant_uncertainty`` (the film's added mass too when
        lubricated), with the lightest damping (dry; lubricated, half the film's at the centre
        added); or the compliance measured within 10 % of this
        frequency in this run, if that is larger. ``measured_only`` (a lubricated step at
        this very frequency converged): the largest measured here, the model's worst case
        aside (it started every step of the report's lubricated X programme at a tenth of its
        target: 0.4-0.9 s of raise a step). Lubricated only: the film's damping keeps the orbit
        near proportional to the load, where dry friction makes a larger orbit grow faster
        than its load (a compliance measured at 10 um understates the one at 40 um: a dry
        circular 40 um step started from it tripped at 64.1 um)."""
        measured_here = self._compliance.get(freq_hz, 0.0)
        if measured_only and measured_here > 0:
            return max(c for f, c in self._compliance.items() if abs(f - freq_hz) <= 0.1 * freq_hz)
        cfg = self.cfg
        u = cfg.plant_uncertainty
        w2 = (2 * np.pi * freq_hz) ** 2
        m = cfg.nominal_mass_kg
        m_hi = (m + (cfg.lubricated_added_mass_kg if self.spec.lubricated else 0.0)) * (1 + u)
        k = cfg.initial_stiffness_n_per_m
        lo, hi = k * (1 - u) - m_hi * w2, k * (1 + u) - m * (1 - u) * w2
        dyn = 0.0 if lo <= 0.0 <= hi else min(abs(lo), abs(hi))
        c = cfg.nominal_damping_ns_per_m + (cfg.lubricated_damping_ns_per_m
                                            if self.spec.lubricated else 0.0)
        model = 1.0 / float(np.hypot(dyn, c * np.sqrt(w2)))
        measured = [c for f, c in self._compliance.items() if abs(f - freq_hz) <= 0.1 * freq_hz]
        return max([model, *measured])

    def _note_compliance(self, freq_hz: float, orbit_m: float, load_n: float) -> None:
        """Keep the largest orbit per newton measured at ``freq_hz`` (`_plant_compliance`)."""
        if load_n > self.limits.open_loop_min_load_n:
            self._compliance[freq_hz] = max(self._compliance.get(freq_hz, 0.0), orbit_m / load_n)

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
        self.ceiling_v = np.inf
        radius = 0.0
        watch_end = -1  # a load target's final raise is watched for one latency
        final = False
        commanded_lag = -1  # the read lag the present ramp's rate was set for
        while True:
            if not synth.is_ramping or stream.read_lag > commanded_lag:
                final = self._raise_command(plan, top, latency, per_block, radius, cap_d,
                                            cap_f)
                commanded_lag = stream.read_lag
            raising = synth.revision  # the raise's own command (not the soft limit's, ...)
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
                # past the margin while raising (a break-away jump, or an orbit still building
                # up at the last drive: dry, 30 Hz with the frame mode it grew 52 -> 57 um at
                # a held drive): back off at once, and no higher again in this step
                synth.ramp_to(synth.phasors * (BACK_OFF * cap_d / radius), None,
                              stream.block / fs)
                self.ceiling_v = float(np.max(np.abs(synth.target_phasors)))
                self._guard_reason = self._guard_reason or (
                    f"the displacement limit ({self.limits.displacement_limit_m * 1e6:.4g} um; "
                    f"the orbit reached {radius * 1e6:.1f} um as the drive was raised)")
            elif float(np.max(np.abs(self.signals.load(ai)))) > cap_f:
                self.limited_by = f"the load limit ({self.limits.max_load_n:g} N)"
            if radius >= stop_at or self.limited_by:
                if synth.revision == raising:
                    self._hold_drive()  # a back-off or the soft limit is a command of its own
                return
            if final and not synth.is_ramping:
                if plan.target_kind != "load":
                    return
                if watch_end < 0:
                    watch_end = stream.sample + latency + stream.read_lag
                elif stream.sample >= watch_end:
                    return

    def _raise_command(self, plan: StepPlan, top: np.ndarray, latency: int, per_block: float,
                       radius: float, cap_d: float, cap_f: float) -> bool:
        """The next command of a watched raise: towards ``top`` (magnitude and phase) over up
        to `RAISE_COMMAND_BLOCKS` blocks, the drive vector growing by at most one block's
        ``per_block`` (less for a late host) in every block, a straight ramp (whose relative
        growth per block only falls as it goes); where that ramp's end is over the drive or
        load limit, one block's raise as before, which may be stopped there (`limited_by`).
        Whether the command reaches ``top``. One command for several blocks, not one a block:
        each command rewrites the AO ring's prediction, through gRPC two round trips."""
        stream, synth = self.stream, self.stream.synth
        now = synth.phasors
        # a late host reads blocks older than the lead: a raise is seen that much later, so
        # the raise per block slows in proportion (at the full rate, a 20 um step at 25 Hz
        # reached 58 um on a loaded PC: the break-away jump of raises it had not seen)
        slow = latency / (latency + stream.read_lag)
        if plan.target_kind == "load":
            # for a load target (no orbit to stop at) slower as the orbit nears the
            # displacement margin: near break-away a small raise makes a large jump, seen a
            # latency later
            slow *= max(0.1, 1.0 - radius / cap_d)
        step = (per_block ** slow - 1.0) * float(np.linalg.norm(now))  # one block's raise
        dist = float(np.linalg.norm(top - now))
        lowering = float(np.linalg.norm(top)) <= float(np.linalg.norm(now))
        for blocks in (RAISE_COMMAND_BLOCKS, 1):
            room = step * blocks
            final = dist <= room or room == 0.0 or lowering
            rows = top if final else now + (top - now) * (room / dist)
            n = 1 if lowering or room == 0.0 else max(1, min(blocks, int(np.ceil(dist / step))))
            nominal = float(np.max(np.abs(self._axis_drive(rows)) * self.gain_n_per_v))
            if float(np.max(np.abs(rows))) > self.limits.max_drive_v + 1e-12:
                why = f"the drive limit ({self.limits.max_drive_v:g} V)"
            elif nominal > cap_f:
                why = f"the load limit ({self.limits.max_load_n:g} N)"
            else:
                synth.ramp_to(rows, None, n * stream.block / self.fs)
                return final
        self._hold_drive()
        self.limited_by = why
        return final

    def _hold_drive(self) -> None:
        """A raise stopped: the drive stays where it is (a ramp still under way ends here)."""
        synth = self.stream.synth
        if synth.is_ramping:
            synth.ramp_to(synth.phasors, None, 0.0)

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
        ctl.max_drive_v = min(ctl.max_drive_v, self.ceiling_v)
        end = self.stream.synth.sample
        return end, end + cycles_to_samples(self.stream.synth.freq_hz, self.fs,
                                            self.cfg.wait_cycles)
