"""The daemon's status, said once: what every heartbeat (the ``status`` topic, every 0.25 s)
and every ``status`` reply carry. A field is added here and in `Daemon.status`; a client reads
the same keys (`CommandClient.status`, the page, ``sfdrig watch``)."""

from __future__ import annotations

from typing import TypedDict

from pydantic import JsonValue


class SafetyEnvelope(TypedDict):
    """What a display draws the orbit and the step table against [m, m, N, V]."""

    radial_clearance_m: float
    displacement_limit_m: float
    load_limit_n: float
    drive_limit_v: float


class LeaseStatus(TypedDict):
    """A structure test's operator lease: how long it is, how long since it was renewed [s]."""

    lease_s: float
    silent_s: float


class Heartbeat(TypedDict):
    """The daemon's status: state, run, progress, pump, sequence numbers, the board."""

    state: str
    #: the requests taken now (a front end's buttons follow them)
    allowed: list[str]
    run_id: str
    run_path: str
    #: the engine's progress (`control.run.engine.Engine.progress_fields`)
    progress: dict[str, JsonValue]
    samples: int
    #: durable in the run file (a reader, or a crash, sees at least these)
    samples_flushed: int
    pump_on: bool
    #: dry sweeps wait [s]; rounded up: 0 only once a dry start is allowed
    film_drains_for_s: float
    safety: SafetyEnvelope
    tolerance: dict[str, float] | None
    fault_reason: str
    #: incidents of no run written to the incident log since start
    idle_incidents: int
    #: what a structure test asks the operator now (`control.run.programs.operator.Question`)
    question: dict[str, JsonValue] | None
    operator_lease: LeaseStatus | None
    last_run: dict[str, JsonValue]
    recovered_at_start: list[dict[str, JsonValue]]
    next_seq: dict[str, int]
    dropped_in_daemon: int
    sample_rate_hz: float
    channels: list[str]
    units: dict[str, str]
    drives: list[str]
    #: each input's range in its units (a display shows how much of it is used)
    input_ranges: dict[str, list[float]]
    endpoints: dict[str, str]
    board: dict[str, str]
    pid: int
