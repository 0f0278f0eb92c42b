"""The sweep engine: unattended multi-frequency, multi-amplitude tests (contract C).

`SweepEngine.run()` is blocking and runs in the acquisition thread; `pause`, `resume` and `abort`
may be called from any other thread. Whatever happens, the drives end ramped to zero: a limit
trip, an open loop, an operator abort, a DAQ error or any other exception fades both drives to
zero (within 100 ms of the offending sample for trips), reads the buffer out and stops the tasks.
Every block, step and event goes to the listener (contract A).

Refusals (bad targets, limits inconsistent with the channel map, the pump interlock with the pump
off) raise `TargetError` / `InterlockError` before any output is written. Once output has started,
`run` returns a `SweepOutcome` rather than raising.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from control.run.engine import OperatorQuestions, RunStatus
from control.run.errors import InterlockError, LimitTrip
from control.run.listener import FanOut, Listener, NullListener
from control.run.pump import PumpState
from control.run.safety import AxisSignals, SafetyLimits, SafetyMonitor, validate_targets
from control.run.stream import DriveStream
from control.run.summary import RunPeaks
from control.run.sweep.approach import unreachable_targets
from control.run.sweep.dwell import StepResult, StepRunner
from control.run.sweep.dwell_states import DwellState
from control.run.sweep.states import FINAL, State, StateMachine
from control.signal.synthesis import SineSynthesizer
from control.wire.errors import TargetError
from control.wire.heartbeat import RunSummary, Tolerance
from control.wire.step_plan import StepPlan
from control.wire.summary_lines import peak_line
from control.wire.sweep_spec import (
    ControlSettings,
    SweepSpec,
    load_sweep_spec,
    sweep_spec_from_dict,
)
from daq.backend import DaqBackend
from daq.channels import ChannelMap
from daq.errors import DaqError, EmergencyStopError

log = logging.getLogger(__name__)

__all__ = [
    "ControlSettings", "SweepEngine", "SweepOutcome", "SweepProgress", "SweepSpec", "StepResult",
    "load_sweep_spec", "sweep_spec_from_dict", "check_sweep",
]


class _Abort(Exception):
    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class _Pause(Exception):
    pass


@dataclass(frozen=True)
class SweepProgress:
    """A snapshot of where the sweep is (safe to read from any thread)."""

    state: str = State.IDLE.value
    step_index: int = -1
    steps_total: int = 0
    freq_hz: float = 0.0
    target_value: float = 0.0
    updates: int = 0
    sample: int = 0
    steps_done: int = 0
    dwell: str = ""  # the present dwell's state (`dwell_states.DwellState`); "" before the first


@dataclass
class SweepOutcome:
    """How a run ended.

    Attributes
    ----------
    status : "completed" | "aborted" | "failed"
    reason : str
        "" when completed; otherwise why (trip, operator abort, error).
    steps : list of StepResult
    samples : int
        Samples acquired in the run.
    sample_rate_hz : float
    summary : RunSummary or None
        `control.run.summary.RunPeaks.summary`: peak orbit and load, contact, where a trip came
        (None: the run ended before it started).
    """

    status: RunStatus
    reason: str
    steps: list[StepResult] = field(default_factory=list)
    samples: int = 0
    sample_rate_hz: float = 0.0
    summary: RunSummary | None = None

    @property
    def rig_time_s(self) -> float:
        return self.samples / self.sample_rate_hz if self.sample_rate_hz else 0.0


#: the engine's final states as the run's outcome
_RUN_STATUS: dict[State, RunStatus] = {State.COMPLETED: "completed", State.ABORTED: "aborted",
                                       State.FAILED: "failed"}


class SweepEngine:
    """Runs a `SweepSpec` on a backend, step by step, safely.

    Parameters
    ----------
    backend : DaqBackend
        Configured (its channel map is used), not started; the engine starts and stops it.
    spec : SweepSpec or dict
    limits : SafetyLimits, optional
        Defaults to `SafetyLimits()`.
    listener : Listener, optional
        Receives the stream (`control.run.listener.FanOut` for several).
    pump : PumpState, optional
        Required for a lubricated sweep: the engine asks it whether the pump is on (before the
        start and while the inlet pressure builds). The engine does not hold the relay: its
        owner does (`PumpRelay.shakers_running`; the daemon from the run's start to its end).
    """

    can_pause = True
    desk: OperatorQuestions | None = None  # unattended: nobody is asked anything

    def __init__(
        self,
        backend: DaqBackend,
        spec: SweepSpec | dict[str, Any],
        limits: SafetyLimits | None = None,
        listener: Listener | None = None,
        pump: PumpState | None = None,
    ) -> None:
        self.backend = backend
        self.spec = spec if isinstance(spec, SweepSpec) else sweep_spec_from_dict(spec)
        self.limits = limits if limits is not None else SafetyLimits()
        self.listener: Listener = listener if listener is not None else NullListener()
        self.pump = pump
        self.plan: list[StepPlan] = self.spec.steps()
        self._lock = threading.Lock()
        self._abort_reason: str | None = None
        self._pause = False
        self._resume = threading.Event()
        self._progress = SweepProgress(steps_total=len(self.plan))
        self._machine = StateMachine(self._on_state)
        self._stream: DriveStream | None = None
        self._monitor: SafetyMonitor | None = None  # the run's limits, on its stream
        self.results: list[StepResult] = []
        self.peaks: RunPeaks | None = None
        self._checked = False  # `check` passed: `run` does not repeat it

    # --- thread-safe controls ---------------------------------------------------------------
    @property
    def progress(self) -> SweepProgress:
        return self._progress

    def progress_fields(self) -> dict[str, Any]:
        """`progress` and the spec's ``max_updates``, as the daemon's status shows them."""
        return {**asdict(self._progress), "max_updates": self.spec.max_updates}

    @property
    def steps_total(self) -> int:
        return len(self.plan)

    def tolerance(self) -> Tolerance:
        return {"amplitude_pct": self.spec.tolerance_amplitude_pct,
                "phase_deg": self.spec.tolerance_phase_deg}

    @property
    def state(self) -> State:
        return self._machine.state

    @property
    def summary(self) -> RunSummary | None:
        """The run's peaks, contact and trip (`RunPeaks.summary`) and, once it streams, how the
        host kept the AO lead (``host_late``: times late, the drive the ring played meanwhile
        [s]); None before it started."""
        if self.peaks is None:
            return None
        out = self.peaks.summary
        if self._stream is not None:
            w, fs = self._stream.writer, self._stream.cm.sample_rate_hz
            out["host_late"] = {"events": w.late_events, "played_from_ring_s": w.repeated / fs,
                                "worst_ms": 1e3 * w.max_late / fs}
        return out

    def pause(self) -> None:
        """Ramp the drives to zero and hold (acquisition continues) until `resume`."""
        with self._lock:
            self._pause = True
            self._resume.clear()

    def resume(self) -> None:
        """Continue a paused sweep; the interrupted step is run again from its start."""
        with self._lock:
            self._pause = False
            self._resume.set()

    def abort(self, reason: str = "operator abort") -> None:
        """Stop the sweep: drives ramp to zero, the outcome is "aborted" with ``reason``."""
        with self._lock:
            if self._abort_reason is None:
                self._abort_reason = reason or "operator abort"
            self._resume.set()

    # --- internals --------------------------------------------------------------------------
    def _sample(self) -> int:
        return self._stream.sample if self._stream is not None else 0

    def _emit(self, kind: str, message: str, sample: int | None = None) -> None:
        self.listener.on_event(kind, message, self._sample() if sample is None else sample)

    def _emit_safe(self, kind: str, message: str, sample: int | None = None) -> None:
        """`_emit` on the way out: a failing listener must not stop the safe shutdown."""
        try:
            self._emit(kind, message, sample)
        except Exception:
            log.exception("listener failed on event %s: %s", kind, message)

    def _on_state(self, old: State, new: State) -> None:
        self._progress = replace(self._progress, state=new.value, sample=self._sample())
        self._emit_safe("state", f"{old.value} -> {new.value}")

    def _interrupt(self) -> None:
        """Called after every block: operator abort or pause."""
        if self._abort_reason is not None:
            raise _Abort(self._abort_reason)
        if self._pause and self._machine.state is State.RUNNING:
            raise _Pause()
        self._progress = replace(self._progress, sample=self._sample())

    def check(self) -> None:
        """Refuse the sweep before any output (`TargetError`, `InterlockError`): targets and
        limits against the channel map, and for a lubricated sweep the pump and its pressure
        input. Done once: by the daemon before the run file exists, else by `run`."""
        if self._checked:
            return
        self._check_config()
        self._check_interlock_before_start()
        self._checked = True

    def _check_config(self) -> None:
        try:
            cm = self.backend.channel_map
        except DaqError as err:
            raise TargetError(f"sweep refused: {err}") from None
        check_sweep(self.spec, self.limits, cm, self.plan)

    def _check_interlock_before_start(self) -> None:
        if not self.spec.lubricated:
            return
        if self.pump is None:
            raise InterlockError("lubricated sweep refused: no pump relay given to the engine")
        if not self.pump.is_on:
            raise InterlockError("lubricated sweep refused: the pump is off (switch it on first)")
        try:
            self.backend.channel_map.ai_index("p_in")
        except KeyError:
            raise InterlockError(
                "lubricated sweep refused: the channel map has no inlet pressure channel 'p_in'"
            ) from None

    def _prime(self, stream: DriveStream) -> None:
        """Zero drive until p_in exceeds its threshold (bounded wait), then let the film fill."""
        cm = self.backend.channel_map
        row = cm.ai_index("p_in")
        lim = self.limits
        fs = cm.sample_rate_hz
        deadline = stream.sample + int(lim.pressure_wait_s * fs)
        while True:
            assert self.pump is not None
            if not self.pump.is_on:
                raise InterlockError("the pump was switched off while waiting for pressure")
            stream.cycle()
            ai, _ = stream.window(stream.sample - stream.block, stream.sample)
            p = float(np.mean(ai[row]))
            if p >= lim.min_inlet_pressure_pa:
                self._emit("pump", f"inlet pressure {p / 1e3:.2f} kPa reached (threshold "
                                   f"{lim.min_inlet_pressure_pa / 1e3:.2f} kPa)")
                break
            if stream.sample >= deadline:
                raise InterlockError(
                    f"lubricated sweep refused: inlet pressure p_in = {p / 1e3:.2f} kPa, below "
                    f"{lim.min_inlet_pressure_pa / 1e3:.2f} kPa after {lim.pressure_wait_s:g} s "
                    "with the pump on"
                )
        stream.advance_to(stream.sample + int(lim.film_prime_s * fs), held=True)
        assert self._monitor is not None
        self._monitor.pressure_row = row  # from now on, losing the pressure trips

    # --- the run ----------------------------------------------------------------------------
    def run(self) -> SweepOutcome:
        """Run the sweep to the end, or until aborted or tripped (blocking).

        Raises
        ------
        TargetError, InterlockError
            When the sweep is refused, before any output is written.
        """
        if self._machine.state is not State.IDLE:
            raise RuntimeError("a SweepEngine runs once; make a new one")
        self._machine.to(State.CHECKING)
        try:
            self.check()
        except (TargetError, InterlockError) as err:
            self._emit_safe("abort", f"refused: {err}", 0)
            self._machine.to(State.REFUSED)
            raise
        cm = self.backend.channel_map
        fs = cm.sample_rate_hz
        cfg = self.spec.control
        block = max(1, int(round(cfg.block_s * fs)))
        # what the lock-in looks back over: a control window (the recording is demodulated as
        # it arrives, never read back), so a long record does not hold its samples in memory
        keep = int(fs * (cfg.window_cycles + 2) / min(p.freq_hz for p in self.plan)) + 4 * block
        np.linalg.solve(np.eye(2), np.ones(2))  # load LAPACK now, not in the first step
        # the run's peak orbit and load and any contact, for the end of run (issue 21)
        self.peaks = RunPeaks(AxisSignals.from_channel_map(cm), self.limits.displacement_limit_m,
                              self.limits.max_load_n)
        self.listener = FanOut([self.listener, self.peaks])
        synth = SineSynthesizer(len(cm.ao), fs)
        self._monitor = SafetyMonitor(self.limits, cm)
        stream = DriveStream(
            self.backend, synth, self._monitor, self.listener, block,
            cfg.ahead_blocks, keep, self._interrupt,
        )
        self._stream = stream
        self.peaks.playing = stream.owner_at  # samples belong to the step whose drive plays
        runner = StepRunner(stream, self.spec, self.limits, self._emit)
        runner.on_update = self._on_update
        runner.dwell.on_change = self._on_dwell
        status, reason = State.COMPLETED, ""
        cut = False  # a trip or the emergency stop: the AO already queued does not play
        try:
            stream.start()
            self._emit("info", f"sweep {self.spec.name!r}: {len(self.plan)} steps, "
                               f"{self.spec.motion}, {self.spec.target_kind} held; block "
                               f"{block} samples, AO {cfg.ahead_blocks} blocks ahead")
            if self.spec.lubricated:
                self._machine.to(State.PRIMING)
                self._prime(stream)
            self._machine.to(State.RUNNING)
            self._run_steps(runner, stream)
            if not all(r.converged for r in self.results):
                bad = sum(not r.converged for r in self.results)
                reason = f"{bad} of {len(self.results)} steps did not converge"
        except _Abort as ab:
            status, reason = State.ABORTED, ab.reason
            self._emit_safe("abort", reason, stream.generation())
        except LimitTrip as trip:
            status, reason, cut = State.ABORTED, str(trip), True
            self._emit_safe("limit_trip", reason, trip.sample if trip.sample >= 0 else None)
        except InterlockError as err:
            status, reason = State.ABORTED, str(err)
            self._emit_safe("abort", reason)
        except _StepFailed as err:
            status, reason = State.ABORTED, str(err)
            self._emit_safe("abort", reason)
        except EmergencyStopError as err:
            status, reason, cut = State.FAILED, f"{type(err).__name__}: {err}", True
            self._emit_safe("error", reason)
        except Exception as err:  # noqa: BLE001 - any failure must end in a safe stop
            log.exception("sweep failed")
            status, reason = State.FAILED, f"{type(err).__name__}: {err}"
            self._emit_safe("error", reason)
        finally:
            if self._machine.state not in FINAL and self._machine.state is not State.STOPPING:
                self._machine.to(State.STOPPING)
            stream.shutdown(self.limits.fade_s, cut=cut)
            self._emit_safe("info", stream.margin_report())
            if stream.contact_event is not None:
                # the housing touched the journal (maybe after a trip, while fading)
                k, msg = stream.contact_event
                if not reason.startswith("journal-housing contact"):
                    self._emit_safe("fault", msg, k)
                if status is State.COMPLETED:
                    status, reason = State.FAILED, msg
            self._emit_safe("info", peak_line(self.peaks.summary))
            self._machine.to(status)
        return SweepOutcome(_RUN_STATUS[status], reason, list(self.results), stream.sample, fs,
                            self.summary)

    def _on_dwell(self, state: DwellState) -> None:
        self._progress = replace(self._progress, dwell=state.value, sample=self._sample())

    def _on_update(self, updates: int) -> None:
        self._progress = replace(self._progress, updates=updates, sample=self._sample())

    def _run_steps(self, runner: StepRunner, stream: DriveStream) -> None:
        i = 0
        while i < len(self.plan):
            plan = self.plan[i]
            self._progress = replace(
                self._progress, step_index=plan.index, freq_hz=plan.freq_hz,
                target_value=plan.target_value, updates=0, sample=stream.sample,
            )
            # the step's drive from its first own command (`DriveStream.claim_drive`): the
            # last step's drive, still playing through the lead, its fade and ring-down (and on
            # a ring, a late host's replay of it) are the last step's peaks, not this one's
            stream.claim_drive({"step_index": plan.index, "steps_total": len(self.plan),
                                "freq_hz": plan.freq_hz, "motion": plan.motion,
                                "target": (f"{plan.target_value * 1e6:.4g} um"
                                           if plan.target_kind == "displacement"
                                           else f"{plan.target_value:.4g} N")})
            try:
                result = runner.run(plan)
            except _Pause:
                self._paused(stream)
                continue  # the interrupted step runs again from its start
            self.results.append(result)
            self._progress = replace(self._progress, steps_done=len(self.results),
                                     updates=result.updates)
            self.listener.on_step(result.to_record())
            if not result.converged:
                msg = f"{plan.describe()}: {result.reason}"
                if self.spec.on_not_converged == "abort":
                    raise _StepFailed(msg)
                self._emit("warning", msg)
            i += 1
        # normal end: ramp down at the envelope rate (the shutdown then only reads out zeros)
        self._machine.to(State.STOPPING)
        peak = float(np.max(np.abs(stream.synth.phasors))) if len(self.plan) else 0.0
        stream.ramp_down(max(self.spec.control.min_ramp_s,
                             peak / self.limits.max_drive_rate_v_per_s))

    def _paused(self, stream: DriveStream) -> None:
        self._machine.to(State.PAUSED)
        self._emit("operator", "paused: drives ramping to zero")
        peak = float(np.max(np.abs(stream.synth.phasors)))
        stream.ramp_down(max(self.spec.control.min_ramp_s,
                             peak / self.limits.max_drive_rate_v_per_s))
        # keep acquiring with zero drive until resumed or aborted; a backend that runs faster
        # than real time (the fast simulator) is paced to the wall clock while paused, so that
        # a pause does not fill the run file as fast as the machine can compute
        fast = not self.backend.realtime
        while True:
            with self._lock:
                if self._abort_reason is not None:
                    raise _Abort(self._abort_reason)
                if not self._pause:
                    break
            if fast:
                self._resume.wait(stream.block / stream.cm.sample_rate_hz)
            stream.cycle()
        self._machine.to(State.RUNNING)
        self._emit("operator", "resumed: repeating the interrupted step")


def check_sweep(spec: SweepSpec, limits: SafetyLimits, cm: ChannelMap,
                plan: list[StepPlan] | None = None) -> None:
    """Everything that must hold before a sweep may write anything: the drive limit within the AO
    ranges, a drive for both axes, the shutdown budget (block_s x (1 + ahead_blocks) + fade_s
    <= 100 ms), every target within the limits (`validate_targets`) and within what the
    controller reaches (`unreachable_targets`: a share of the limit).

    Raises
    ------
    TargetError
        Naming what is wrong.
    """
    for ao in cm.ao:
        lo, hi = ao.range_v
        if limits.max_drive_v > min(-lo, hi):
            raise TargetError(
                f"max_drive_v = {limits.max_drive_v:g} V exceeds the range {ao.range_v} of "
                f"AO channel {ao.name!r}"
            )
    for axis in "xy":
        try:
            cm.ao_for_axis(axis)
        except KeyError:
            raise TargetError(f"channel map has no shaker drive for axis {axis}") from None
    block_s = spec.control.block_s
    latency = block_s * (1 + spec.control.ahead_blocks) + limits.fade_s
    if latency > 0.1 + 1e-12:
        raise TargetError(
            f"block_s x (1 + ahead_blocks) + fade_s = {latency * 1e3:.0f} ms exceeds the "
            "100 ms shutdown budget"
        )
    plan = spec.steps() if plan is None else plan
    validate_targets(plan, limits, cm)
    unreachable = unreachable_targets(plan, limits, spec.control.algorithm)
    if unreachable:
        raise TargetError("sweep refused: a target the controller would never reach (its steps "
                          "would spend their updates and fail):\n  " + "\n  ".join(unreachable))


class _StepFailed(RuntimeError):
    pass


def summarize(outcome: SweepOutcome) -> str:
    """One line per step: frequency, target, updates, converged (for logs and the CLI)."""
    lines = [f"status {outcome.status}{': ' + outcome.reason if outcome.reason else ''}; "
             f"{len(outcome.steps)} steps, {outcome.rig_time_s:.2f} s of rig time"]
    for r in outcome.steps:
        p = r.plan
        a = r.assessment
        err = "" if a is None else a.describe()
        lines.append(f"  {p.index:3d} {p.freq_hz:8.2f} Hz {p.target_value:.4g} {p.unit} "
                     f"updates {r.updates} {'ok' if r.converged else 'NOT converged'} {err}")
    return "\n".join(lines)

