"""Contract A: the one stream of a run (a sweep or a structure test), consumed by the run writer,
the publisher and others: the `Listener` protocol and the one fan-out to several of them. Its
records (`StepRecord`, the event kinds) are said once, in `storage.records`."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from storage.records import EVENT_KINDS, JsonValue, StepRecord

log = logging.getLogger(__name__)

__all__ = ["EVENT_KINDS", "FanOut", "Listener", "NullListener", "RecordingListener"]


@runtime_checkable
class Listener(Protocol):
    """Receives every block, every step result and every event of a run, in order.

    ``on_block(first_sample, ai, ao)``: ``ai`` engineering units, float64 (n_ai, n) in channel-map
    order; ``ao`` the drive volts written for those same samples (n_ao, n); ``first_sample``
    counts from 0 at the start of the run; blocks are contiguous. ``on_step(step)``: a
    `StepRecord`. ``on_event(kind, message, sample)``: kind in `EVENT_KINDS`.
    """

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None: ...

    def on_step(self, step: StepRecord) -> None: ...

    def on_event(self, kind: str, message: str, sample: int) -> None: ...


class NullListener:
    """Discards everything."""

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        return None

    def on_step(self, step: StepRecord) -> None:
        return None

    def on_event(self, kind: str, message: str, sample: int) -> None:
        return None


class FanOut:
    """One stream, many consumers: the ``required`` ones get every call, in order, and their
    errors stop the run (the run file); the ``best_effort`` ones (live consumers) never stop it:
    their errors are counted and logged."""

    def __init__(self, required: Sequence[Listener],
                 best_effort: Sequence[Listener] = ()) -> None:
        self.required = list(required)
        self.best_effort = list(best_effort)
        self.errors = 0
        self.last_sample = 0  # one past the last sample seen

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        self.last_sample = first_sample + ai.shape[1]
        for r in self.required:
            r.on_block(first_sample, ai, ao)
        for b in self.best_effort:
            self._try(b.on_block, first_sample, ai, ao)

    def on_step(self, step: StepRecord) -> None:
        for r in self.required:
            r.on_step(step)
        for b in self.best_effort:
            self._try(b.on_step, step)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        for r in self.required:
            r.on_event(kind, message, sample)
        for b in self.best_effort:
            self._try(b.on_event, kind, message, sample)

    def _try(self, fn: Callable[..., None], *args: Any) -> None:
        try:
            fn(*args)
        except Exception:  # a live consumer must never stop acquisition
            self.errors += 1
            log.exception("live consumer failed")


class RecordingListener:
    """Keeps everything in memory (tests, benchmarks, short runs)."""

    def __init__(self, keep_blocks: bool = True) -> None:
        self.keep_blocks = keep_blocks
        self.blocks: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.steps: list[StepRecord] = []
        self.events: list[tuple[str, str, int]] = []
        self.samples = 0

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        if first_sample != self.samples:
            raise ValueError(f"blocks not contiguous: block at {first_sample}, expected "
                             f"{self.samples}")
        self.samples += ai.shape[1]
        if self.keep_blocks:
            self.blocks.append((first_sample, ai.copy(), ao.copy()))

    def on_step(self, step: StepRecord) -> None:
        self.steps.append(step)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        self.events.append((kind, message, sample))

    @property
    def wire_steps(self) -> list[dict[str, JsonValue]]:
        """The steps as a subscriber or a reader of the file sees them (`StepRecord.to_wire`)."""
        return [s.to_wire() for s in self.steps]

    def ai(self) -> np.ndarray:
        return np.concatenate([b[1] for b in self.blocks], axis=1)

    def ao(self) -> np.ndarray:
        return np.concatenate([b[2] for b in self.blocks], axis=1)

    def events_of(self, kind: str) -> list[tuple[str, str, int]]:
        return [e for e in self.events if e[0] == kind]
