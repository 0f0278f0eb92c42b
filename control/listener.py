"""Contract A: the one stream of a sweep, consumed by the run writer, the publisher and others."""

from __future__ import annotations

import logging
from typing import Any, Protocol, runtime_checkable

import numpy as np

log = logging.getLogger(__name__)

EVENT_KINDS = ("state", "limit_trip", "abort", "fault", "pump", "operator", "warning", "error",
               "info")


@runtime_checkable
class SweepListener(Protocol):
    """Receives every block, every step result and every event of a run, in order.

    ``on_block(first_sample, ai, ao)``: ``ai`` engineering units, float64 (n_ai, n) in channel-map
    order; ``ao`` the drive volts written for those same samples (n_ao, n); ``first_sample``
    counts from 0 at the start of the run; blocks are contiguous. ``on_step(step)``:
    ``StepResult.to_dict()``. ``on_event(kind, message, sample)``: kind in `EVENT_KINDS`.
    """

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None: ...

    def on_step(self, step: dict[str, Any]) -> None: ...

    def on_event(self, kind: str, message: str, sample: int) -> None: ...


class NullListener:
    """Discards everything."""

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        return None

    def on_step(self, step: dict[str, Any]) -> None:
        return None

    def on_event(self, kind: str, message: str, sample: int) -> None:
        return None


class Fanout:
    """Sends the stream to several listeners, in the order given."""

    def __init__(self, *listeners: SweepListener) -> None:
        self.listeners = list(listeners)

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        for lst in self.listeners:
            lst.on_block(first_sample, ai, ao)

    def on_step(self, step: dict[str, Any]) -> None:
        for lst in self.listeners:
            lst.on_step(step)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        for lst in self.listeners:
            lst.on_event(kind, message, sample)


class RecordingListener:
    """Keeps everything in memory (tests, benchmarks, short runs)."""

    def __init__(self, keep_blocks: bool = True) -> None:
        self.keep_blocks = keep_blocks
        self.blocks: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.steps: list[dict[str, Any]] = []
        self.events: list[tuple[str, str, int]] = []
        self.samples = 0

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        if first_sample != self.samples:
            raise ValueError(f"blocks not contiguous: block at {first_sample}, expected "
                             f"{self.samples}")
        self.samples += ai.shape[1]
        if self.keep_blocks:
            self.blocks.append((first_sample, ai.copy(), ao.copy()))

    def on_step(self, step: dict[str, Any]) -> None:
        self.steps.append(step)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        self.events.append((kind, message, sample))

    def ai(self) -> np.ndarray:
        return np.concatenate([b[1] for b in self.blocks], axis=1)

    def ao(self) -> np.ndarray:
        return np.concatenate([b[2] for b in self.blocks], axis=1)

    def events_of(self, kind: str) -> list[tuple[str, str, int]]:
        return [e for e in self.events if e[0] == kind]
