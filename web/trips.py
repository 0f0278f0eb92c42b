"""Trips, emergency stops, watchdogs and interrupted runs across a test day, from the run files.

Each run file keeps its events and how it ended, and the daemon's incident log
(`storage.incident_log`) those that happen while no run is going (an emergency stop pressed
or released between runs, the board's watchdog expiring while idle); nothing here asks the
daemon. One row per
incident: a limit trip (``limit_trip`` event), an emergency stop (an ``error`` naming
``EmergencyStopError``), the board's watchdog (an event naming the watchdog), a
journal-housing contact (``fault``), a run that was interrupted (its writer died: status
"interrupted") or failed for another reason. An operator's abort is not an incident.

Each row says when (the event's time), what (its message), where (the step and its frequency:
the recorded step whose record holds the sample, else the planned step that was running, from
the run's sweep spec) and the peak orbit radius [um] and load [N] in the samples around it
(`PEAK_BEFORE_S` before to `PEAK_AFTER_S` after: what led to it and the ramp down).
"""

from __future__ import annotations

import csv
import io
import math
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from web.view import finite

if TYPE_CHECKING:  # storage (h5py) is imported at first use
    from storage.reader import RunData
    from storage.records import StepRecord

INCIDENTS = ("trip", "e-stop", "watchdog", "contact", "interrupted", "failed")
PEAK_BEFORE_S = 1.0
PEAK_AFTER_S = 0.2
#: where an incident of no run happened
IDLE_WHERE = "between runs (no run going)"
CSV_COLUMNS = ("time_utc", "run_id", "incident", "what", "where", "run_time_s",
               "peak_orbit_um", "peak_load_n", "run_status", "file")


class TripRow(TypedDict):
    """One row of the trips table (and of its CSV, `CSV_COLUMNS`): when, which run ("" for
    none), which incident (`INCIDENTS`), its message, where in the run, the run time [s], the
    peak orbit [um] and load [N] around it (None: not known), the run's status and its file."""

    time_utc: str
    run_id: str
    incident: str
    what: str
    where: str
    run_time_s: float | None
    peak_orbit_um: float | None
    peak_load_n: float | None
    run_status: str
    file: str


def incident_of(kind: str, message: str) -> str | None:
    """The incident an event is (None: not one)."""
    text = message.lower()
    if kind == "limit_trip":
        return "trip"
    if kind in ("error", "fault") and ("emergencystop" in text or "emergency stop" in text
                                       or "e-stop" in text):
        return "e-stop"
    if kind in ("error", "fault", "warning") and "watchdog" in text:
        return "watchdog"
    if kind == "fault":
        return "contact" if "contact" in text else "failed"
    return None


def parse_since(text: str) -> datetime:
    """An ISO 8601 date or date and time (UTC when it names no zone).

    Raises
    ------
    ValueError
        naming the text, for anything else.
    """
    try:
        when = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"since={text!r} is not an ISO 8601 date or time (e.g. 2026-11-25 "
                         "or 2026-11-25T08:00)") from None
    return when if when.tzinfo else when.replace(tzinfo=UTC)


def _when(iso: str) -> datetime | None:
    try:
        return parse_since(iso) if iso else None
    except ValueError:
        return None


def _planned(test_spec: dict[str, Any] | None) -> list[float]:
    """The sweep's planned frequencies in running order ([] for other tests or a bad spec)."""
    if not test_spec:
        return []
    from control.wire.errors import TargetError
    from control.wire.sweep_spec import sweep_spec_from_dict

    try:
        return [p.freq_hz for p in sweep_spec_from_dict(test_spec).steps()]
    except (TargetError, TypeError, ValueError):
        return []


def where_of(sample: int, steps: list[StepRecord], planned: list[float], fs: float) -> str:
    """``step 3/12 at 90.0 Hz, 1.200 s into the run``: the step whose record holds ``sample``,
    or the one running after the last recorded (its frequency from the plan); for a test of no
    steps the run time alone."""
    at = f"{sample / fs:.3f} s into the run" if fs > 0 and sample >= 0 else ""
    index = None
    for s in steps:
        if s.first_sample <= sample < s.last_sample:
            index = s.index
            break
    if index is None:
        done = [s for s in steps if s.last_sample <= sample]
        index = done[-1].index + 1 if done else 0
    of = f"/{len(planned)}" if planned else ""
    freq: float | None = None
    if index < len(planned):
        freq = planned[index]
    else:
        recorded = [s.freq_hz for s in steps if s.index == index]
        freq = recorded[0] if recorded else None
    if not planned and not steps:  # a test without dwells: its time alone
        return at
    step = f"step {index + 1}{of}" + (f" at {freq:.1f} Hz" if freq is not None else "")
    return f"{step}, {at}" if at else step


def peaks_around(run: RunData, sample: int) -> tuple[float | None, float | None]:
    """The largest orbit radius [um] and load [N] from `PEAK_BEFORE_S` before ``sample`` to
    `PEAK_AFTER_S` after (None where the run has no such signal)."""
    fs = run.sample_rate_hz
    n = run.n_samples
    if n <= 0 or fs <= 0:
        return None, None
    sample = min(max(sample, 0), n)
    lo, hi = max(0, sample - int(PEAK_BEFORE_S * fs)), min(n, sample + int(PEAK_AFTER_S * fs))
    if hi <= lo:
        lo, hi = max(0, n - int(PEAK_BEFORE_S * fs)), n
    orbit = load = None
    if run.has_signal("x") and run.has_signal("y"):
        orbit = float(np.max(np.hypot(run.signal("x", lo, hi), run.signal("y", lo, hi)))) * 1e6
    elif run.has_signal("x"):
        orbit = float(np.max(np.abs(run.signal("x", lo, hi)))) * 1e6
    loads = [float(np.max(np.abs(run.signal(f, lo, hi)))) for f in ("fx", "fy")
             if run.has_signal(f)]
    if loads:
        load = max(loads)
    return orbit, load


def incidents_of_run(run: RunData, status: str, file: str, changed_at: float
                     ) -> list[TripRow]:
    """Every incident of one open run (`storage.reader.RunData`) whose status is ``status``;
    ``changed_at`` is the file's last change [s since the epoch], the time of an interruption
    not yet closed by a daemon (as `storage.recovery.close_interrupted` will record it)."""
    fs = run.sample_rate_hz
    steps = run.step_records
    planned = _planned(run.test_spec) if run.kind == "sweep" else []
    found: list[tuple[str, str, str, int]] = []
    for e in run.events:
        what = incident_of(e["kind"], e["message"])
        if what is not None:
            found.append((what, e["time"], e["message"], int(e["sample"])))
    reason = str(run.attrs.get("status_reason", ""))
    last = max(0, run.n_samples - 1)
    changed = datetime.fromtimestamp(changed_at, UTC).isoformat(timespec="milliseconds")
    if status == "interrupted":
        found.append(("interrupted", run.stop_time or changed,
                      reason or "the run was interrupted (its writer is gone)", last))
    elif status == "failed" and not found:
        found.append(("failed", run.stop_time or changed, reason or "the run failed", last))
    rows: list[TripRow] = []
    for what, time, message, sample in found:
        sample = last if sample < 0 else sample
        orbit, load = peaks_around(run, sample)
        rows.append({
            "time_utc": time, "run_id": run.run_id, "incident": what, "what": message,
            "where": where_of(sample, steps, planned, fs),
            "run_time_s": finite(sample / fs) if fs > 0 else None,
            "peak_orbit_um": finite(orbit) if orbit is not None else None,
            "peak_load_n": finite(load) if load is not None else None,
            "run_status": status, "file": file,
        })
    return rows


def idle_rows(records: list[dict[str, Any]], file: str) -> list[TripRow]:
    """The rows of the daemon's incident log (`storage.incident_log`): incidents while no run
    was going (an emergency stop pressed or released between runs, the board's watchdog), in
    no run file."""
    return [{"time_utc": r["time"], "run_id": "", "incident": r["incident"], "what": r["what"],
             "where": IDLE_WHERE, "run_time_s": None, "peak_orbit_um": None,
             "peak_load_n": None, "run_status": "", "file": file} for r in records]


def select(rows: list[TripRow], incidents: set[str] | None,
           since: datetime | None) -> list[TripRow]:
    """The rows of those incidents (all for None), from ``since`` on, newest first."""
    out = [r for r in rows if (incidents is None or r["incident"] in incidents)
           and (since is None or ((w := _when(r["time_utc"])) is not None and w >= since))]
    oldest = datetime.min.replace(tzinfo=UTC)
    out.sort(key=lambda r: _when(r["time_utc"]) or oldest, reverse=True)
    return out


def parse_incidents(text: str) -> set[str] | None:
    """``trip,e-stop`` -> {"trip", "e-stop"}; "" or "all" -> None (every incident).

    Raises
    ------
    ValueError
        naming an unknown incident and the known ones.
    """
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names or names == ["all"]:
        return None
    unknown = [n for n in names if n not in INCIDENTS]
    if unknown:
        raise ValueError(f"incident {unknown[0]!r} is not one of {', '.join(INCIDENTS)} "
                         "(or all)")
    return set(names)


def to_csv(rows: list[TripRow]) -> str:
    """The rows as CSV (a header of `CSV_COLUMNS`; text quoted; no value read as a formula)."""
    buf = io.StringIO()
    w = csv.writer(buf, quoting=csv.QUOTE_NONNUMERIC, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in CSV_COLUMNS])
    return buf.getvalue()


def _cell(v: object) -> object:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, str) and v[:1] in ("=", "+", "-", "@"):
        return "'" + v  # a spreadsheet must not run it
    return v
