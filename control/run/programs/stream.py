"""What every non-sweep test programme shares: the DC-level stream (AO written two blocks ahead,
every block to the listener), the harness that always ends with the drives at zero, the wait for a
person's answer while the DAQ keeps streaming, and the check that signals are steady.

A force over the limit or the emergency stop does not let the AO already queued play: as in a
sweep, the backend drops it (`DaqBackend.cut_ao`) and the drives are at 0 V from the first sample
not generated (or fade fast from it, where the backend resumes). Every other end ramps.

The operator is an `control.run.programs.operator.OperatorDesk`; what a person's hands do that the
software must
do on the simulated rig (strike, show a dial gauge, turn the regulator, take the journal out) is an
optional `RigHands`, given only for the simulated rig by the composition root.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from control.run.ao_writer import AoWriter
from control.run.engine import RunStatus
from control.run.listener import Listener
from control.run.programs.operator import Answer, OperatorDesk, Question
from daq.backend import DaqBackend
from daq.errors import EmergencyStopError

FAULT_RAMP_S = 0.04  # drive fade on a fault [s]
#: ring mode: blocks of the predicted level written per cycle beyond the lead
PREDICT_BLOCKS = 8


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
    step_dicts: list[dict[str, Any]] = field(default_factory=list)

    @property
    def status(self) -> RunStatus:
        """"completed" or "aborted" (`control.run.engine.RunOutcome`)."""
        return "completed" if self.completed else "aborted"


class Stream:
    """AO written two blocks ahead, AI read block by block, every block passed to the listener.

    The drive is a DC level per shaker that moves by linear ramps; ``level_v`` is the level the
    next written block ends at.
    """

    def __init__(self, backend: DaqBackend, listener: Listener, block: int,
                 max_force_n: float = float("inf"), operator: OperatorDesk | None = None) -> None:
        self.backend = backend
        self.operator = operator
        # a simulated rig running faster than real time is paced while a person is asked, so a
        # minute at the prompt is a minute of record, not an hour
        self.pace_waits = getattr(backend, "realtime", True) is False
        self.max_force_n = max_force_n
        self.where = ""  # what the programme is doing, for the trip message
        self._fading = False  # set while ramping to zero at the end: no more trips
        self.listener = listener
        self.cm = backend.channel_map
        self.fs = backend.sample_rate_hz
        self.block = block
        self.n_ao = len(self.cm.ao)
        self.level_v = np.zeros(self.n_ao)
        self._written: deque[np.ndarray] = deque()
        self._target: np.ndarray | None = None
        self._rate = np.zeros(self.n_ao)  # ramp rate toward the target [V per sample]
        self.sample = 0  # next AI sample to read
        self.last_ai = np.zeros((len(self.cm.ai), 0))
        self._shown_v = np.zeros(self.n_ao)  # the drive at the end of the last block read
        self._started = False
        #: the AO's writer: queued, or (a regenerating backend) the ring a late host cannot
        #: underflow, two blocks ahead of the generation
        self.writer = AoWriter(backend, block, 2 * block)
        self._prefill: list[np.ndarray] = []
        # ring mode: the current ramp's continuation written ahead (level, target, rate), the
        # target it follows (`_cmd` counts new targets) and where it has reached
        self._cmd = 0
        self._pred_cmd = -1
        self._pred: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._pred_end = 0

    def _write(self, target_v: np.ndarray, ramp_samples: int) -> None:
        """Write the next block moving linearly toward ``target_v`` (a regenerating backend: as
        many as keep the lead, after skipping what the ring played while the host was late:
        the ramp moves on over those samples, and what the ring played is what is recorded)."""
        if not self.writer.regenerating:
            self.backend.write_ao(self._next(target_v, ramp_samples))
            return
        if not self._started:  # the prefill: written as the ring's start by `start`
            self._prefill.append(self._next(target_v, ramp_samples))
            return
        skip = self.writer.late_skip(self.sample)
        for _ in range(skip // self.block):
            self._next(target_v, ramp_samples)
            self._written[-1] = self.writer.played(self.block)
        self.writer.clear_played()
        while self.writer.wants_write():
            blk = self._next(target_v, ramp_samples)
            if self._pred_cmd == self._cmd and self._pred_end >= self.writer.pos + self.block:
                self.writer.pos += self.block  # the ring holds this block already
            else:
                self.writer.write(blk)
        self._predict()

    def _predict(self) -> None:
        """Ring mode: keep the ring filled, up to a ring ahead of the generation, with the
        current ramp's continuation (as `DriveStream` does), so a late host hears the level it
        is moving to, not one from a ring ago. A new target restarts it from the position."""
        w = self.writer
        assert w.ring is not None
        if self._pred_cmd != self._cmd or self._pred_end < w.pos:
            target = self.level_v if self._target is None else self._target
            self._pred = (self.level_v.copy(), target.copy(), self._rate.copy())
            self._pred_cmd, self._pred_end = self._cmd, w.pos
        assert self._pred is not None
        level, target, rate = self._pred
        limit = w.generated + w.ring - self.block - w.margin
        start, parts = self._pred_end, list[np.ndarray]()
        while len(parts) < PREDICT_BLOCKS and self._pred_end + self.block <= limit:
            blk = self._ramp_block(level, target, rate)
            level = blk[:, -1].copy()
            parts.append(blk)
            self._pred_end += self.block
        self._pred = (level, target, rate)
        if parts:
            w.write_at(start, np.concatenate(parts, axis=1))

    def _next(self, target_v: np.ndarray, ramp_samples: int) -> np.ndarray:
        """The next block moving linearly toward ``target_v``, queued to be read: a new target
        sets the rate so that the whole change takes ``ramp_samples``; the level then arrives
        exactly."""
        target_v = np.asarray(target_v, dtype=float)
        if self._target is None or not np.array_equal(target_v, self._target):
            self._target = target_v.copy()
            self._rate = np.abs(target_v - self.level_v) / max(int(ramp_samples), 1)
            self._cmd += 1
        blk = self._ramp_block(self.level_v, self._target, self._rate)
        self._written.append(blk)
        self.level_v = blk[:, -1].copy()
        return blk

    def _ramp_block(self, level: np.ndarray, target: np.ndarray,
                    rate: np.ndarray) -> np.ndarray:
        """One block from ``level`` toward ``target`` at ``rate`` [V per sample], clipped to
        the channels' ranges."""
        delta = target - level
        k = np.arange(1, self.block + 1)[None, :]
        moved = np.minimum(rate[:, None] * k, np.abs(delta)[:, None])
        blk = level[:, None] + np.sign(delta)[:, None] * moved
        for row, ch in enumerate(self.cm.ao):
            lo, hi = ch.range_v
            np.clip(blk[row], lo, hi, out=blk[row])
        return blk

    def _read(self) -> np.ndarray:
        """Read the block the oldest written AO is generated with; AI in engineering units."""
        volts = self.backend.read_ai(self.block)
        ai = self.cm.to_engineering(volts)
        self.last_ai = ai
        ao = self._written.popleft()
        self.listener.on_block(self.sample, ai, ao)
        self.sample += self.block
        self._shown_v = ao[:, -1].copy()
        return ai

    def start(self) -> None:
        self._prefill = []
        for _ in range(2):
            self._write(self.level_v, 1)
        if self.writer.regenerating:
            self.writer.prefill(np.concatenate(self._prefill, axis=1))
        self.backend.start()
        self._started = True

    def step(self, target_v: np.ndarray, ramp_s: float) -> np.ndarray:
        """Write one block moving toward ``target_v``, read one block; AI in engineering units."""
        remaining = np.max(np.abs(target_v - self.level_v)) if self.n_ao else 0.0
        ramp = int(ramp_s * self.fs) if remaining > 0 else 1
        self._write(target_v, ramp)
        ai = self._read()
        if not self._fading:
            if self.operator is not None and self.operator.abort_reason:
                raise ProgramAborted(f"{self.where or 'programme'}: "
                                     f"{self.operator.abort_reason}")
            self._check_force(ai)  # every block: a trip is seen within one block
        return ai

    def _check_force(self, ai: np.ndarray) -> None:
        for name in ("fx", "fy"):
            if name in self.cm.ai_names:
                peak = float(np.max(np.abs(ai_row(self.cm, ai, name))))
                if peak > self.max_force_n:
                    raise ForceTrip(f"{self.where or 'programme'}: {name} reached "
                                       f"{peak:.1f} N, over the {self.max_force_n:g} N limit")

    def hold(self, target_v: np.ndarray, seconds: float, ramp_s: float) -> tuple[int, np.ndarray]:
        """Hold ``target_v`` for ``seconds``; returns (first sample, AI (n_ai, n)).

        The blocks already queued (written before this call) and the ramp are let out first, so
        every returned sample was generated at the target level.
        """
        lead = len(self._written) + int(np.ceil(ramp_s * self.fs / self.block))
        if np.max(np.abs(target_v - self.level_v), initial=0.0) > 0 or lead:
            for _ in range(lead):
                self.step(target_v, ramp_s)
        first = self.sample
        n_blocks = max(int(np.ceil(seconds * self.fs / self.block)), 1)
        blocks = [self.step(target_v, ramp_s) for _ in range(n_blocks)]
        return first, np.concatenate(blocks, axis=1)

    def finish(self, ramp_s: float, cut: bool = False) -> None:
        """Ramp to zero, let the queued blocks out, stop (always called).

        ``cut`` (a force trip or the emergency stop): the queued blocks do not play
        (`_cut`); the motion is read out for as long as they and the ramp would have taken.
        """
        if not self._started:
            return
        zero = np.zeros(self.n_ao)
        self._fading = True
        try:
            if cut:
                self._cut(ramp_s)
            n_blocks = int(np.ceil(ramp_s * self.fs / self.block)) + 3
            if not cut and self.writer.regenerating and self._fade_in_ring(ramp_s, n_blocks):
                return
            for _ in range(n_blocks):
                self.step(zero, ramp_s)
        finally:
            self.backend.stop()

    def _fade_in_ring(self, ramp_s: float, n_blocks: int) -> bool:
        """Ring mode: the ramp to zero and zeros over the rest of the ring in one write, so a
        host late while it plays cannot make the ring repeat an earlier level; then read out."""
        zero = np.zeros(self.n_ao)
        ramp = int(ramp_s * self.fs)
        skip = self.writer.late_skip(self.sample)
        for _ in range(skip // self.block):
            self._next(zero, ramp)
            self._written[-1] = self.writer.played(self.block)
        at = self.writer.pos
        if self.writer.generated + (self.writer.ring or 0) - at < (n_blocks + 1) * self.block:
            return False
        blocks = [self._next(zero, ramp) for _ in range(n_blocks)]
        self.writer.fill_ring(at, np.concatenate(blocks, axis=1))
        self.writer.pos = at + n_blocks * self.block
        while self._written:
            self._read()
            self.writer.generated = self.sample
            self.writer.clear_played()
        return True

    def _cut(self, ramp_s: float) -> None:
        """Drop the AO not yet generated; the drives are at 0 V from there, or (a backend that
        resumes) ramp to zero in ``ramp_s`` from the level they had reached. The blocks to read
        are rebuilt to what the outputs show, and read out."""
        queued = (np.concatenate(list(self._written), axis=1) if self._written
                  else np.zeros((self.n_ao, 0)))
        done = self.backend.cut_ao()
        if self.writer.regenerating and done.at > self.sample + queued.shape[1]:
            # the host was late: the ring played on past what was written, up to the cut
            n = self.block * int(np.ceil((done.at - self.sample - queued.shape[1]) / self.block))
            queued = np.concatenate([queued, self.writer.played(n)], axis=1)
        at = min(max(done.at, self.sample), self.sample + queued.shape[1]) - self.sample
        kept = queued[:, :at]
        level = kept[:, -1] if at else self._shown_v
        n_ramp = max(int(ramp_s * self.fs), 1) if done.resumes else 0
        fade = level[:, None] * (1.0 - np.arange(1, n_ramp + 1) / n_ramp)[None, :]
        total = self.block * int(np.ceil((queued.shape[1] + n_ramp) / self.block))
        zeros = np.zeros((self.n_ao, total - at - n_ramp))
        if done.resumes and self.writer.regenerating:
            self.writer.generated = self.sample + at
            self.writer.fill_ring(self.sample + at, np.concatenate([fade, zeros], axis=1))
        elif done.resumes:
            self.backend.write_ao(np.concatenate([fade, zeros], axis=1))
        tail = np.concatenate([kept, fade, zeros], axis=1)
        self._written = deque(tail[:, i:i + self.block] for i in range(0, total, self.block))
        self.level_v = np.zeros(self.n_ao)
        self._target = None
        while self._written:
            self._read()


def ai_row(cm: Any, ai: np.ndarray, name: str) -> np.ndarray:
    return ai[cm.ai_index(name)]


def signal(cm: Any, ai: np.ndarray, name: str) -> np.ndarray:
    """Canonical signal from a block: the channel, or the mean of probes x1, x2..."""
    if name in cm.ai_names:
        return ai_row(cm, ai, name)
    rows = [i for i, n in enumerate(cm.ai_names) if n.startswith(name) and n[len(name):].isdigit()]
    if not rows:
        raise ProgramError(f"no channel or probes for signal {name!r} (have {cm.ai_names})")
    return ai[rows].mean(axis=0)


def step_dict(index: int, target_kind: str, target_value: float, motion: str, first: int,
               last: int, updates: int = 0, converged: bool = True, reason: str = "",
               **extra: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "index": index, "freq_hz": 0.0, "target_kind": target_kind,
        "target_value": float(target_value), "motion": motion, "first_sample": int(first),
        "last_sample": int(last), "updates": int(updates), "converged": bool(converged),
        "reason": reason, "harmonics": {}, "drive_v": {},
    }
    d.update(extra)
    return d


def run_program(kind: str, backend: DaqBackend, listener: Listener, spec: Any,
                body: Callable[[Stream, list[dict[str, Any]]], None],
                operator: OperatorDesk | None = None) -> ProgramOutcome:
    """Run ``body`` on a started stream; whatever happens, the drives end ramped to zero (fast
    on a fault or an abort) and the outcome says how many steps were recorded and why it stopped.
    """
    stream = Stream(backend, listener, spec.block_samples, spec.max_force_n, operator)
    steps: list[dict[str, Any]] = []
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
    outcome.steps, outcome.samples, outcome.step_dicts = len(steps), stream.sample, steps
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


def unsteady(cm: Any, ai: np.ndarray, checks: Sequence[Steadiness]) -> list[str]:
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
    "journal_out", "run_program", "signal", "step_dict", "unsteady",
]
