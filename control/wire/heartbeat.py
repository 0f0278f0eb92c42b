"""The daemon's status, said once: what every heartbeat (the ``status`` topic, every 0.25 s)
and every ``status`` reply carry. A field is added here and in `Daemon.status`; every reader
takes it through `heartbeat_from_wire` (`CommandClient.status`, `Subscriber.wait_connected`,
`Message.heartbeat`: the page, ``sfdrig status``, ``sfdrig watch``, the terminal operator).

On the wire a heartbeat is the JSON object of these keys (a TypedDict is that object, typed):
the status reply's ``data`` and the ``status`` header's ``status``.
"""

from __future__ import annotations

from functools import cache
from typing import NotRequired

from pydantic import ConfigDict, JsonValue, TypeAdapter, ValidationError, with_config
from typing_extensions import TypedDict  # pydantic reads this one (not typing's) on Python 3.11


class SafetyEnvelope(TypedDict):
    """What a display draws the orbit and the step table against [m, m, N, V]."""

    radial_clearance_m: float
    displacement_limit_m: float
    load_limit_n: float
    drive_limit_v: float


class Tolerance(TypedDict):
    """A sweep's convergence tolerances, which a display draws the steps against [%, deg]."""

    amplitude_pct: float
    phase_deg: float


class LeaseStatus(TypedDict):
    """A structure test's operator lease: how long it is, how long since it was renewed [s]."""

    lease_s: float
    silent_s: float


class AskedEntry(TypedDict):
    """A value the operator types (`control.run.programs.operator.Entry`) [SI between the
    bounds; ``unit`` is the display unit]."""

    name: str
    label: str
    quantity: str
    unit: str
    min_si: float
    max_si: float


class AskedQuestion(TypedDict):
    """What a structure test asks the operator (`control.run.programs.operator.Question`, its
    JSON form): the front ends (the page, the terminal) show it and answer its ``id``."""

    id: int
    where: str
    prompt: str
    info: list[str]
    entry: AskedEntry | None
    choices: list[str]
    trigger: bool
    shows: str


class RunPlace(TypedDict, total=False):
    """Where in a run a peak or a trip came: the sweep's step (``step_index`` from 0, -1 before
    the first), its frequency [Hz], motion and target; a trip's ``message``; the run sample."""

    step_index: int
    steps_total: int
    freq_hz: float
    motion: str
    #: the target as shown, with its unit ("45 um", "300 N")
    target: str
    sample: int
    message: str


class HostLate(TypedDict):
    """How the host kept the AO lead: times late, the drive the ring played meanwhile [s], the
    worst lateness [ms]."""

    events: int
    played_from_ring_s: float
    worst_ms: float


class RunSummary(TypedDict):
    """What a sweep did at its worst (`control.run.summary.RunPeaks.summary`) [m, N]: the
    peaks, where they came, any journal-housing contact, where a trip came."""

    peak_displacement_m: float
    peak_displacement_at: RunPlace
    displacement_limit_m: float
    peak_load_n: float
    peak_load_at: RunPlace
    max_load_n: float
    #: the first contact's event message ("" for none)
    contact: str
    tripped_at: RunPlace | None
    #: once the sweep streamed (`control.run.sweep.engine.SweepEngine.summary`)
    host_late: NotRequired[HostLate]


class LastRun(TypedDict, total=False):
    """How the daemon's last run ended: every key once a run has ended, none before."""

    run_id: str
    path: str
    #: the run file's status ("completed", "aborted", "failed")
    status: str
    reason: str
    #: the run's peaks, contact and trip, when it has them (`control.wire.summary_lines`)
    summary: RunSummary


class RecoveredRun(TypedDict):
    """A run a dead writer left running, closed at the daemon's start
    (`control.run.files.recover_interrupted`)."""

    path: str
    #: "interrupted", or "unrecovered" (``error`` says why)
    status: str
    last_sample: NotRequired[int]
    error: NotRequired[str]


@with_config(ConfigDict(extra="allow"))  # a newer daemon's further keys reach the page as sent
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
    tolerance: Tolerance | None
    fault_reason: str
    #: incidents of no run written to the incident log since start
    idle_incidents: int
    #: what a structure test asks the operator now (`control.run.programs.operator.Question`)
    question: AskedQuestion | None
    operator_lease: LeaseStatus | None
    last_run: LastRun
    recovered_at_start: list[RecoveredRun]
    next_seq: dict[str, int]
    dropped_in_daemon: int
    sample_rate_hz: float
    channels: list[str]
    units: dict[str, str]
    drives: list[str]
    #: each input's range in its units (a display shows how much of it is used)
    input_ranges: dict[str, list[float]]
    endpoints: dict[str, str]
    #: ``backend``, ``device``, ``grpc_target``, ``description`` (`daq.board.Board.as_dict`)
    board: dict[str, str]
    pid: int


@cache
def _adapter() -> TypeAdapter[Heartbeat]:
    return TypeAdapter(Heartbeat)


def heartbeat_from_wire(value: object, source: str = "the daemon") -> Heartbeat:
    """A heartbeat (or a status reply's data) received from ``source``, every field checked;
    ValueError naming the first field that is missing or not what it should be."""
    try:
        return _adapter().validate_python(value)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "the status"
        raise ValueError(f"status from {source}: {where}: {first['msg']}") from None


__all__ = ["AskedEntry", "AskedQuestion", "Heartbeat", "HostLate", "LastRun", "LeaseStatus",
           "RecoveredRun", "RunPlace", "RunSummary", "SafetyEnvelope", "Tolerance",
           "heartbeat_from_wire"]
