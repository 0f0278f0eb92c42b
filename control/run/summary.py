"""What a run did at its worst: the peak orbit and load, any journal-housing contact, and where
a trip came (issue 21: a run that trips says what, where, how far and what next).

`RunPeaks` is a listener of the run's stream (contract A) kept by the sweep engine; its
`summary` is a JSON-safe dict that the engine returns in `SweepOutcome.summary`, the daemon puts
in its status's ``last_run`` and the CLI and the page show (`control.wire.summary_lines`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import cast

import numpy as np

from control.run.safety import AxisSignals
from control.wire.heartbeat import RunPlace, RunSummary
from control.wire.summary_lines import CONTACT
from storage.records import StepRecord


class RunPeaks:
    """The largest orbit radius (about the probes' zero, as the limit sees it) and load of a run,
    with the step and frequency they came at, and the first journal-housing contact."""

    def __init__(self, signals: AxisSignals, displacement_limit_m: float,
                 max_load_n: float) -> None:
        self.signals = signals
        self.displacement_limit_m = displacement_limit_m
        self.max_load_n = max_load_n
        self.peak_displacement_m = 0.0
        self.peak_load_n = 0.0
        self.where_displacement: RunPlace = {}
        self.where_load: RunPlace = {}
        self.contact = ""
        self.tripped_at: RunPlace | None = None
        #: where the run is (step index from 0, steps, frequency, target, motion)
        self.where: RunPlace = {}
        #: whose drive plays at a sample (the stream's `DriveStream.owner_at`: a step's `where`
        #: from its first own drive command, the fade and ring-down of the drive before and a
        #: late host's replay of it still the step before's); None: `where`, as the engine
        #: keeps it up to date
        self.playing: Callable[[int], object] | None = None

    def _where(self, sample: int) -> RunPlace:
        """Where the run was at ``sample``: the step whose drive played it."""
        if self.playing is None:
            return self.where
        owner = self.playing(sample)
        return cast("RunPlace", owner) if isinstance(owner, dict) else {}

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        d = self.signals.displacement(ai)
        r = np.hypot(d[0], d[1])
        k = int(np.argmax(r))
        if float(r[k]) > self.peak_displacement_m:
            self.peak_displacement_m = float(r[k])
            self.where_displacement = {**self._where(first_sample + k), "sample": first_sample + k}
        load = np.max(np.abs(self.signals.load(ai)), axis=0)
        k = int(np.argmax(load))
        if float(load[k]) > self.peak_load_n:
            self.peak_load_n = float(load[k])
            self.where_load = {**self._where(first_sample + k)}

    def on_step(self, step: StepRecord) -> None:
        pass

    def on_event(self, kind: str, message: str, sample: int) -> None:
        if kind in ("fault", "limit_trip") and message.startswith(CONTACT) and not self.contact:
            self.contact = message
        if kind == "limit_trip" and self.tripped_at is None:
            self.tripped_at = {**self._where(sample), "message": message, "sample": sample}

    @property
    def summary(self) -> RunSummary:
        return {
            "peak_displacement_m": self.peak_displacement_m,
            "peak_displacement_at": self.where_displacement,
            "displacement_limit_m": self.displacement_limit_m,
            "peak_load_n": self.peak_load_n,
            "peak_load_at": self.where_load,
            "max_load_n": self.max_load_n,
            "contact": self.contact,
            "tripped_at": self.tripped_at,
        }
