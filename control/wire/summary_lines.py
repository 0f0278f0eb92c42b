"""How a run's summary reads (`control.run.summary.RunPeaks.summary`, as the daemon's status
carries it in ``last_run``): the peak line, the host's lateness, the CLI's last line after a
trip, and the word for a contact. Clients (the CLI, the page) and the sweep engine print the
same lines."""

from __future__ import annotations

from control.wire.heartbeat import RunPlace, RunSummary

#: the safety monitor's and the engine's words for a contact
CONTACT = "journal-housing contact"


def _at(where: RunPlace | None) -> str:
    if not where or where.get("step_index", -1) < 0:
        return ""
    of = f"/{where['steps_total']}" if where.get("steps_total") else ""
    return f"step {where['step_index'] + 1}{of}, {where.get('freq_hz', float('nan')):.1f} Hz"


def peak_line(summary: RunSummary) -> str:
    """``peak orbit 52.0 um of the 63.5 um limit (step 1/1, 150.0 Hz), peak load 402.1 N of
    448 N; no journal-housing contact``."""
    d, lim = summary["peak_displacement_m"] * 1e6, summary["displacement_limit_m"] * 1e6
    at_d, at_f = _at(summary["peak_displacement_at"]), _at(summary["peak_load_at"])
    line = (f"peak orbit {d:.1f} um of the {lim:.4g} um limit" + (f" ({at_d})" if at_d else "")
            + f", peak load {summary['peak_load_n']:.1f} N of {summary['max_load_n']:g} N"
            + (f" ({at_f})" if at_f else ""))
    contact = summary["contact"]
    return line + (f"; {contact}" if contact else f"; no {CONTACT}")


def lateness_line(summary: RunSummary | None) -> str:
    """When the computer fell behind the AO and that cost the run time, what it cost and what
    to do (`SweepEngine.summary`'s ``host_late``); "" when it kept up."""
    late = summary.get("host_late") if summary else None
    if late is None or not late["events"] or late["played_from_ring_s"] <= 0:
        return ""
    return (f"the computer fell behind the drive {late['events']} times (at worst "
            f"{late['worst_ms']:.1f} ms late): {late['played_from_ring_s']:.3f} s of drive played "
            "from the AO ring meanwhile, time the controller waited for the drive it asked for. "
            "What to do: ease the machine's load, or start the daemon with --priority high.")


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
             summary: RunSummary | None) -> str:
    """The CLI's last line: how the run ended; after a trip, what tripped, at which step and
    frequency, the peak, and what to do."""
    line = f"run {run_id} {status}" + (f": {reason}" if reason else "") + f" ({steps} steps)"
    trip = summary["tripped_at"] if summary is not None else None
    if "-200290" in reason:  # not a trip: the computer did not keep the AO fed
        return (line + ". What to do: the AO stream ran dry (the computer fell behind its 30 ms "
                "lead; the drives ramped to zero): ease the machine's load or start the daemon "
                "with --priority high, then run again.")
    if not trip or summary is None:
        return line
    at = _at(trip)
    target = f" ({trip.get('motion', '')} {trip['target']})" if trip.get("target") else ""
    contact = summary["contact"]
    peak = (f"peak orbit {summary['peak_displacement_m'] * 1e6:.1f} um of the "
            f"{summary['displacement_limit_m'] * 1e6:.4g} um limit"
            + (f", {contact}" if contact else ""))
    return (f"run {run_id} {status} by a limit trip" + (f" at {at}{target}" if at else "")
            + f": {trip.get('message', '')}; {peak}; the drives were cut to 0 V ({steps} steps "
            f"recorded). What to do: {_advice(trip.get('message', ''), bool(contact))}.")
