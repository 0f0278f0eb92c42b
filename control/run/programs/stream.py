"""What every non-sweep test programme shares: the DC-level drive (on the sweep's AO stream,
`control.run.stream.DriveStream`: AO two blocks ahead, every block to the listener), the harness
that always ends with the drives at zero, the wait for a person's answer while the DAQ keeps
streaming, and the check that signals are steady.

A force over the limit or the emergency stop does not let the AO already queued play: the stream
cuts it as a sweep's trip does (`DaqBackend.cut_ao`) and the drives are at 0 V from the first
sample not generated (or fade fast from it, where the backend resumes). Every other end ramps.

The operator is an `control.run.programs.operator.OperatorDesk`; what a person's hands do that the
software must
do on the simulated rig (strike, show a dial gauge, turn the regulator, take the journal out) is an
optional `RigHands`, given only for the simulated rig by the composition root.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from control.run.ao_writer import AoWriter
from control.run.engine import RunStatus
from control.run.listener import Listener
from control.run.programs.operator import Answer, OperatorDesk, Question
from control.run.programs.specs import ProgramSpec
from control.run.stream import DriveStream
from control.signal.synthesis import SineSynthesizer
from daq.backend import DaqBackend
from daq.channels import ChannelMap
from daq.errors import EmergencyStopError
from storage.records import JsonValue, StepRecord

FAULT_RAMP_S = 0.04  # drive fade on a fault [s]


class ProgramError(RuntimeError):
    """A test programme that had to stop: the message says which step and why."""


class ProgramAborted(ProgramError):
    """The operator (or the daemon) asked the programme to stop."""


class ForceTrip(ProgramError):
    """A load cell read more than the programme's force limit: the drives are cut."""


class RigHands(Protocol):
    """What a person does at the rig that, on the simulated rig, the software must do."""

    def strike(self, axis: str, peak_force_n: float, kind: str) -> None:
        """Hit the housing: ``kind`` "ok" (one clean hit), "double" or "overload"."""

    def gauge_reading_m(self, axis: str) -> float:
        """What the dial gauge on ``axis`` shows now [m], to its resolution."""

    def set_supply_pressure(self, pressure_pa: float) -> None:
        """Turn the regulator to ``pressure_pa``."""

    def set_journal(self, installed: bool) -> None:
        """Take the journal out (no seal contact) or put it back."""

    def push(self, axis: str, force_n: float) -> None:
        """Push the housing along ``axis`` with about ``force_n`` through the force gauge and
        hold (0: let go)."""

    def force_gauge_reading_n(self, axis: str) -> float:
        """What the force gauge pushing along ``axis`` shows now [N], to its resolution."""


@dataclass
class ProgramOutcome:
    """What a programme did: steps recorded, and why it stopped if it did not complete."""

    kind: str
    steps: int
    completed: bool
    reason: str = ""
    samples: int = 0
    step_records: list[StepRecord] = field(default_factory=list)

    @property
    def status(self) -> RunStatus:
        """"completed" or "aborted" (`control.run.engine.RunOutcome`)."""
        return "completed" if self.completed else "aborted"


class _NoDriveLimits:
    """The programmes' monitor for `DriveStream`: their levels are clipped to the channels'
    ranges before they are commanded, and the only AI limit is the force, which `Stream` checks
    after every block (after the operator's abort, as the programmes always have)."""

    last_ao: np.ndarray | None = None
    headroom = False  # a programme's AI is read block by block

    def check_ao(self, block: np.ndarray, first_sample: int) -> None:
        pass

    def check_ao_after(self, block: np.ndarray, first_sample: int,
                       before: np.ndarray | None) -> None:
        pass

    def check_ai(self, eng: np.ndarray, first_sample: int) -> None:
        pass

    def contact(self, eng: np.ndarray, first_sample: int) -> tuple[int, str] | None:
        return None


class Stream:
    """A programme's drive: a DC level per shaker that moves by linear ramps, on the sweep's own
    AO stream (`control.run.stream.DriveStream`: a 0 Hz drive whose phasors are the levels), so
    the ring, a late host's skip, the cut and the fade are written once. AO two blocks ahead,
    AI read block by block, every block passed to the listener.

    ``level_v`` is the level of the last sample written.
    """

    def __init__(self, backend: DaqBackend, listener: Listener, block: int,
                 max_force_n: float = float("inf"), operator: OperatorDesk | None = None) -> None:
        self.backend = backend
        self.operator = operator
        # a simulated rig running faster than real time is paced while a person is asked, so a
        # minute at the prompt is a minute of record, not an hour
        self.pace_waits = not backend.realtime
        self.max_force_n = max_force_n
        self.where = ""  # what the programme is doing, for the trip message
        self.listener = listener
        self.cm = backend.channel_map
        self.fs = backend.sample_rate_hz
        self.block = block
        self.n_ao = len(self.cm.ao)
        if self.n_ao == 0:
            raise ProgramError("a test programme needs the shakers' AO channels; the channel "
                               "map has none")
        self._range_v = np.array([ch.range_v for ch in self.cm.ao], dtype=float)
        self.drive = DriveStream(backend, SineSynthesizer(self.n_ao, self.fs), _NoDriveLimits(),
                                 listener, block, ahead_blocks=2, keep_samples=block,
                                 interrupt=self._after_block)
        self.drive.check_limits = False  # the force is checked in `_after_block`
        self.drive.writer.watch_backlog = False
        self.drive.taps.append(self._keep_last)
        self._target: np.ndarray | None = None
        self._last_block = np.zeros((len(self.cm.ai), 0))
        self.last_ai = np.zeros((len(self.cm.ai), 0))  # what the last `step` read

    @property
    def sample(self) -> int:
        """The next AI sample to read."""
        return self.drive.sample

    @property
    def level_v(self) -> np.ndarray:
        return self.drive.synth.phasors.real

    @property
    def writer(self) -> AoWriter:
        """The AO's writer (queued, or the ring a late host cannot underflow)."""
        return self.drive.writer

    def _keep_last(self, first: int, ai: np.ndarray, ao: np.ndarray) -> None:
        self._last_block = ai

    def _after_block(self) -> None:
        """After every block read while running: the operator's abort, then the force (a trip
        is seen within one block)."""
        if self.operator is not None and self.operator.abort_reason:
            raise ProgramAborted(f"{self.where or 'programme'}: {self.operator.abort_reason}")
        self._check_force(self._last_block)

    def _command(self, target_v: np.ndarray, ramp_s: float) -> None:
        """A new target starts a linear ramp from the present level over ``ramp_s`` (clipped to
        the channels' ranges, as the level then stays within them); the same target goes on."""
        target_v = np.clip(np.asarray(target_v, dtype=float), self._range_v[:, 0],
                           self._range_v[:, 1])
        if self._target is not None and np.array_equal(target_v, self._target):
            return
        self._target = target_v
        remaining = float(np.max(np.abs(target_v - self.level_v)))
        ramp = int(ramp_s * self.fs) if remaining > 0 else 1
        self.drive.synth.ramp_to(target_v.astype(np.complex128), None, max(ramp, 1) / self.fs)

    def start(self) -> None:
        self.drive.start()

    def step(self, target_v: np.ndarray, ramp_s: float) -> np.ndarray:
        """Move toward ``target_v``, read a block (more while a late host catches up); AI in
        engineering units, every sample from the one `sample` named before the call."""
        self._command(target_v, ramp_s)
        first = self.drive.sample
        self.drive.cycle()
        self.last_ai = self.drive.window(first, self.drive.sample)[0]
        return self.last_ai

    def _check_force(self, ai: np.ndarray) -> None:
        for name in ("fx", "fy"):
            if name in self.cm.ai_names:
                peak = float(np.max(np.abs(ai_row(self.cm, ai, name)), initial=0.0))
                if peak > self.max_force_n:
                    raise ForceTrip(f"{self.where or 'programme'}: {name} reached "
                                       f"{peak:.1f} N, over the {self.max_force_n:g} N limit")

    def hold(self, target_v: np.ndarray, seconds: float, ramp_s: float) -> tuple[int, np.ndarray]:
        """Hold ``target_v`` for ``seconds``; returns (first sample, AI (n_ai, n)).

        The blocks already queued (written before this call) and the ramp are let out first, so
        every returned sample was generated at the target level.
        """
        lead = self.drive.queued_blocks + int(np.ceil(ramp_s * self.fs / self.block))
        for _ in range(lead):
            self.step(target_v, ramp_s)
        first = self.sample
        end = first + max(int(np.ceil(seconds * self.fs / self.block)), 1) * self.block
        blocks = []
        while self.sample < end:
            blocks.append(self.step(target_v, ramp_s))
        return first, np.concatenate(blocks, axis=1)

    def finish(self, ramp_s: float, cut: bool = False) -> None:
        """Ramp to zero in ``ramp_s``, read out, stop (always called; `DriveStream.shutdown`).

        ``cut`` (a force trip or the emergency stop): the queued blocks do not play; the
        motion is read out for as long as they and the ramp would have taken.
        """
        self.drive.shutdown(ramp_s, cut=cut)


def ai_row(cm: ChannelMap, ai: np.ndarray, name: str) -> np.ndarray:
    return ai[cm.ai_index(name)]


def signal(cm: ChannelMap, ai: np.ndarray, name: str) -> np.ndarray:
    """Canonical signal from a block: the channel, or the mean of probes x1, x2..."""
    if name in cm.ai_names:
        return ai_row(cm, ai, name)
    rows = [i for i, n in enumerate(cm.ai_names) if n.startswith(name) and n[len(name):].isdigit()]
    if not rows:
        raise ProgramError(f"no channel or probes for signal {name!r} (have {cm.ai_names})")
    return ai[rows].mean(axis=0)


def point_step(index: int, target_kind: str, target_value: float, motion: str, first: int,
               last: int, updates: int = 0, converged: bool = True, reason: str = "",
               extra: Mapping[str, JsonValue] | None = None) -> StepRecord:
    """One point of a structure test (no excitation: freq_hz 0, no harmonics); ``extra`` its
    further keys."""
    return StepRecord(index=index, freq_hz=0.0, target_kind=target_kind,
                      target_value=float(target_value), motion=motion, first_sample=int(first),
                      last_sample=int(last), updates=int(updates), converged=bool(converged),
                      reason=reason, extra=dict(extra or {}))


def run_program(kind: str, backend: DaqBackend, listener: Listener, spec: ProgramSpec,
                body: Callable[[Stream, list[StepRecord]], None],
                operator: OperatorDesk | None = None) -> ProgramOutcome:
    """Run ``body`` on a started stream; whatever happens, the drives end ramped to zero (fast
    on a fault or an abort) and the outcome says how many steps were recorded and why it stopped.
    """
    stream = Stream(backend, listener, spec.block_samples, spec.max_force_n, operator)
    steps: list[StepRecord] = []
    listener.on_event("state", f"{kind} programme started: {spec.model_dump_json()}", 0)
    outcome = ProgramOutcome(kind, 0, True)
    clean = cut = False
    try:
        stream.start()
        body(stream, steps)
        clean = True
    except ProgramError as err:
        outcome.completed, outcome.reason = False, str(err)
        cut = isinstance(err, ForceTrip)
        listener.on_event("abort", str(err), stream.sample)
    except EmergencyStopError:
        cut = True
        raise
    finally:
        if operator is not None:
            operator.withdraw()
        # a fault (ProgramError or anything unexpected) fades the drives fast; a force trip or
        # the emergency stop cuts them
        stream.finish(spec.ramp_s if clean else FAULT_RAMP_S, cut=cut)
    state = "completed" if outcome.completed else "aborted"
    listener.on_event("state", f"{kind} programme {state}", stream.sample)
    outcome.steps, outcome.samples, outcome.step_records = len(steps), stream.sample, steps
    return outcome


def ask(stream: Stream, question: Question, hold_v: np.ndarray, ramp_s: float,
        watch: Callable[[int, np.ndarray], bool] | None = None) -> Answer | None:
    """Post ``question`` and stream at ``hold_v`` until it is answered.

    ``watch(first_sample, ai)`` sees every block while waiting; when it returns True (a hammer
    strike on the armed channel) the question is withdrawn and None is returned. The choice
    "abort" raises `ProgramAborted`, so the programme ends the safe way with its points so far.
    """
    desk = stream.operator
    if desk is None:
        raise ProgramError(f"{stream.where}: this programme needs an operator")
    q = desk.post(question)
    while True:
        answer = desk.poll()
        if answer is not None:
            if answer.choice == "abort":
                raise ProgramAborted(f"{q.where}: aborted by the operator")
            return answer
        first = stream.sample
        ai = stream.step(hold_v, ramp_s)
        if watch is not None and watch(first, ai):
            desk.withdraw("answered by a strike on the armed channel")
            return None
        if stream.pace_waits:
            time.sleep(stream.block / stream.fs)


#: what the operator does next, by test: the shakers load the housing, or the operator does
NEXT_AFTER_JOURNAL_OUT = {
    "shakers": "stand clear of the housing: the shakers will load it",
    "hammer": "the shakers stay at 0 V; have the hammer ready: you will strike the housing",
    "hand": "the shakers stay at 0 V; have the force gauge ready: you will push the housing",
}


def journal_out(stream: Stream, hands: RigHands | None, kind: str, loaded_by: str) -> None:
    """Ask for the journal to be taken out: the report's structure tests had no seal contact.

    ``loaded_by``: a key of ``NEXT_AFTER_JOURNAL_OUT`` (who moves the housing next).
    """
    if stream.operator is None:
        return
    stream.where = f"{kind} setup"
    ask(stream, Question(
        id=0, where=f"{kind} setup", choices=["ok", "abort"],
        prompt="Take the journal out (no seal contact, as in the report's structure tests), "
               "leave the shakers attached through the load cells; "
               f"{NEXT_AFTER_JOURNAL_OUT[loaded_by]}; accept when ready"),
        np.zeros(stream.n_ao), 0.1)
    if hands is not None:
        hands.set_journal(False)
        stream.listener.on_event("operator", "journal out (simulated rig)", stream.sample)


def ask_unsteady(stream: Stream, label: str, moving: str, timeout_s: float,
                 hold_v: np.ndarray, ramp_s: float, info: Sequence[str] = ()) -> str:
    """A point that did not settle is never recorded: the operator repeats or skips it."""
    answer = ask(stream, Question(
        id=0, where=label, choices=["repeat", "skip", "abort"], info=list(info),
        prompt=f"Not steady within {timeout_s:g} s ({moving}): repeat or skip this point"),
        hold_v, ramp_s)
    assert answer is not None
    stream.listener.on_event("operator", f"{stream.where}: not steady ({moving}); "
                             f"{answer.choice}", stream.sample)
    return answer.choice


@dataclass
class Steadiness:
    """How steady a signal must be to record it: over the window, the means of its quarters
    may spread by at most ``abs_tol + rel_tol * |mean|`` (in the signal's SI unit)."""

    signal: str
    abs_tol: float
    rel_tol: float = 0.005


def unsteady(cm: ChannelMap, ai: np.ndarray, checks: Sequence[Steadiness]) -> list[str]:
    """What is not steady in ``ai`` (one clause per signal), empty if all are."""
    out = []
    for c in checks:
        x = signal(cm, ai, c.signal)
        quarters = [float(q.mean()) for q in np.array_split(x, 4)]
        spread = max(quarters) - min(quarters)
        limit = c.abs_tol + c.rel_tol * abs(float(x.mean()))
        if not spread <= limit:
            out.append(f"{c.signal} moved {spread:.3g} (limit {limit:.3g})")
    return out


def hold_steady(stream: Stream, target_v: np.ndarray, record_s: float, ramp_s: float,
                checks: Sequence[Steadiness], timeout_s: float) -> tuple[int, np.ndarray, str]:
    """Hold and record ``record_s`` until the signals are steady over the whole record, at most
    ``timeout_s``; (first sample, AI, "" or what stayed unsteady)."""
    waited = 0.0
    while True:
        first, ai = stream.hold(target_v, record_s, ramp_s)
        moving = unsteady(stream.cm, ai, checks)
        waited += record_s
        if not moving or waited >= timeout_s:
            return first, ai, "; ".join(moving)


__all__: Sequence[str] = [
    "FAULT_RAMP_S", "ForceTrip", "ProgramAborted", "ProgramError", "ProgramOutcome",
    "RigHands", "Steadiness", "Stream", "ai_row", "ask", "ask_unsteady", "hold_steady",
    "journal_out", "run_program", "signal", "point_step", "unsteady",
]
