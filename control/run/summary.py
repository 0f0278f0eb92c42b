"""What a run did at its worst: the peak orbit and load, any journal-housing contact, and where
a trip came (issue 21: a run that trips says what, where, how far and what next).

`RunPeaks` is a listener of the run's stream (contract A) kept by the sweep engine; its
`summary` is a JSON-safe dict that the engine returns in `SweepOutcome.summary`, the daemon puts
in its status's ``last_run`` and the CLI (`peak_line`, `end_line`) and the page show.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from control.run.safety import AxisSignals

#: the safety monitor's and the engine's words for a contact
CONTACT = "journal-housing contact"


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
        self.where_displacement: dict[str, Any] = {}
        self.where_load: dict[str, Any] = {}
        self.contact = ""
        self.tripped_at: dict[str, Any] | None = None
        #: where the run is (step index from 0, steps, frequency, target, unit, motion), kept
        #: up to date by the engine
        self.where: dict[str, Any] = {}

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        d = self.signals.displacement(ai)
        r = np.hypot(d[0], d[1])
        k = int(np.argmax(r))
        if float(r[k]) > self.peak_displacement_m:
            self.peak_displacement_m = float(r[k])
            self.where_displacement = {**self.where, "sample": first_sample + k}
        load = float(np.max(np.abs(self.signals.load(ai))))
        if load > self.peak_load_n:
            self.peak_load_n = load
            self.where_load = dict(self.where)

    def on_step(self, step: dict[str, Any]) -> None:
        pass

    def on_event(self, kind: str, message: str, sample: int) -> None:
        if kind in ("fault", "limit_trip") and message.startswith(CONTACT) and not self.contact:
            self.contact = message
        if kind == "limit_trip" and self.tripped_at is None:
            self.tripped_at = {**self.where, "message": message, "sample": sample}

    @property
    def summary(self) -> dict[str, Any]:
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


def _at(where: dict[str, Any] | None) -> str:
    if not where or where.get("step_index", -1) < 0:
        return ""
    of = f"/{where['steps_total']}" if where.get("steps_total") else ""
    return f"step {where['step_index'] + 1}{of}, {where.get('freq_hz', float('nan')):.1f} Hz"


def peak_line(summary: dict[str, Any]) -> str:
    """``peak orbit 52.0 um of the 63.5 um limit (step 1/1, 150.0 Hz), peak load 402.1 N of
    448 N; no journal-housing contact``."""
    d, lim = summary["peak_displacement_m"] * 1e6, summary["displacement_limit_m"] * 1e6
    at_d, at_f = _at(summary.get("peak_displacement_at")), _at(summary.get("peak_load_at"))
    line = (f"peak orbit {d:.1f} um of the {lim:.4g} um limit" + (f" ({at_d})" if at_d else "")
            + f", peak load {summary['peak_load_n']:.1f} N of {summary['max_load_n']:g} N"
            + (f" ({at_f})" if at_f else ""))
    contact = summary.get("contact") or ""
    return line + (f"; {contact}" if contact else f"; no {CONTACT}")


def _advice(message: str, contact: bool) -> str:
    first = ("check the journal and the housing for contact marks and the probes for damage, "
             "then " if contact else "")
    if "displacement" in message or message.startswith(CONTACT):
        return (first + "lower the target at that frequency (its orbit passed the limit), or "
                "look for what changed (shaker gain, probe calibration, a loose fixture) if the "
                "same target ran before")
    if "load" in message:
        return first + "lower the load target, or check the force transducer and shaker gain"
    if "pressure" in message:
        return first + "check the pump, the supply and the inlet pressure sensor"
    return first + "see the run's events (sfdrig watch --file RUN.h5) and the daemon's log"


def end_line(run_id: str, status: str, reason: str, steps: int,
             summary: dict[str, Any] | None) -> str:
    """The CLI's last line: how the run ended; after a trip, what tripped, at which step and
    frequency, the peak, and what to do."""
    line = f"run {run_id} {status}" + (f": {reason}" if reason else "") + f" ({steps} steps)"
    trip = (summary or {}).get("tripped_at")
    if "-200290" in reason:  # not a trip: the computer did not keep the AO fed
        return (line + ". What to do: the AO stream ran dry (the computer fell behind its 30 ms "
                "lead; the drives ramped to zero): ease the machine's load or start the daemon "
                "with --priority high, then run again.")
    if not trip or summary is None:
        return line
    at = _at(trip)
    target = f" ({trip.get('motion', '')} {trip['target']})" if trip.get("target") else ""
    contact = summary.get("contact") or ""
    peak = (f"peak orbit {summary['peak_displacement_m'] * 1e6:.1f} um of the "
            f"{summary['displacement_limit_m'] * 1e6:.4g} um limit"
            + (f", {contact}" if contact else ""))
    return (f"run {run_id} {status} by a limit trip" + (f" at {at}{target}" if at else "")
            + f": {trip['message']}; {peak}; the drives were cut to 0 V ({steps} steps "
            f"recorded). What to do: {_advice(trip['message'], bool(contact))}.")
