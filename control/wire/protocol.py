"""The daemon's wire protocol: command requests and replies, live-data topics and framing.

Commands (daemon ROUTER socket; clients use DEALER or REQ)
    One request is one JSON frame (after the routing envelope): ``{"cmd": "<name>", ...}``,
    validated by the pydantic models below (unknown fields are errors). Every request gets exactly
    one reply frame: ``{"ok": true|false, "cmd", "request_id", "state", "error_kind", "error",
    "data"}``; ``error`` names what was wrong when ``ok`` is false.

Live data (daemon PUB socket)
    Every message is three frames ``[topic, header JSON, payload]``:

    - ``block``: one acquisition block; payload is float64 little-endian, C order, shape
      ``header["shape"] = (n_ai + n_ao, n)``: the AI rows in engineering units then the drive volts
      actually written, rows named by ``header["channels"]``; ``first_sample`` counts from 0 at the
      start of the run.
    - ``step``: one finished dwell (the step dict of contract A); empty payload.
    - ``status``: heartbeat (state, run id, progress); empty payload.
    - ``event``: log event (``kind``, ``message``, ``sample``); empty payload.

    Every header carries ``run_id`` ("" between runs) and ``seq``, a per-topic sequence number
    that increases by one per message for the life of the daemon, so a subscriber detects lost
    messages as gaps in ``seq``.
"""

from __future__ import annotations

import json
from enum import StrEnum
from typing import Annotated, Any, Literal, NotRequired

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    JsonValue,
    TypeAdapter,
    ValidationError,
    field_validator,
)
from typing_extensions import TypedDict  # pydantic reads this one (not typing's) on Python 3.11

from control.wire.text import RequestId, SafeReason, SafeRequestId, Text, safe_json, safe_text
from daq.config_files import unknown_field_hint

#: Live-data topics (the first frame of every PUB message).
TOPIC_BLOCK = b"block"
TOPIC_STEP = b"step"
TOPIC_STATUS = b"status"
TOPIC_EVENT = b"event"
TOPICS = (TOPIC_BLOCK, TOPIC_STEP, TOPIC_STATUS, TOPIC_EVENT)

#: The payload dtype of block messages: float64, little-endian.
PAYLOAD_DTYPE = np.dtype("<f8")

#: Largest request frame the daemon parses [bytes]; bigger ones are refused unparsed.
MAX_REQUEST_BYTES = 1_000_000
#: Largest frame the command socket accepts at all [bytes] (ZMQ_MAXMSGSIZE): a peer that sends a
#: bigger one is disconnected by ZeroMQ before the frame is held in memory.
MAX_FRAME_BYTES = 4 * MAX_REQUEST_BYTES


class DaemonState(StrEnum):
    """States of the daemon's state machine (see `control.daemon.daemon.TRANSITIONS`)."""

    IDLE = "idle"
    ARMING = "arming"
    RUNNING = "running"
    PAUSED = "paused"
    ABORTING = "aborting"
    FAULT = "fault"


class ErrorKind(StrEnum):
    """Why a request was refused."""

    MALFORMED = "malformed"  # not one JSON object frame
    INVALID = "invalid"  # JSON, but not a valid request (unknown command, bad fields)
    FORBIDDEN = "forbidden"  # valid, but not allowed in the current state (or by an interlock)
    FAILED = "failed"  # allowed, tried, and it failed (e.g. the DAQ refused)


# --- requests ---------------------------------------------------------------------------------
class _Request(BaseModel):
    # strict: "on": "yes" or 1 must not switch a pump; only JSON true/false does.
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)
    request_id: RequestId = Field("", max_length=128, description="echoed in the reply, "
                                  "exactly as sent")


class StartRequest(_Request):
    """Start a sweep. ``spec`` holds the sweep's fields (a `control.run.sweep.engine.SweepSpec` as
    a dict,
    e.g. a sweep TOML file parsed by the client); the daemon validates it."""

    cmd: Literal["start"]
    spec: dict[str, JsonValue]
    operator: Text = Field("", max_length=200)
    notes: Text = Field("", max_length=10_000)


class StartTestRequest(_Request):
    """Start a structure or instrument test (the report's sections IV-V, Appendix A) with the
    operator in the loop; ``spec`` holds fields of its spec (`control.run.programs.specs`).
    The reply's ``lease`` and ``lease_s``: the operator's lease, which the client renews with
    `AliveRequest` at least every quarter of ``lease_s`` (`control.daemon.lease`)."""

    cmd: Literal["start_test"]
    test: Literal["static", "impact", "probe_calibration", "flow"]
    spec: dict[str, JsonValue] = Field(default_factory=dict)
    operator: Text = Field("", max_length=200)
    notes: Text = Field("", max_length=10_000)


class AnswerRequest(_Request):
    """Answer the question a running test asks (the daemon's status has it): a choice and, for
    an entry, the text typed ("0.0021 in"); the daemon checks the unit and the range."""

    cmd: Literal["answer"]
    question_id: int = Field(ge=1)
    choice: Text = Field(min_length=1, max_length=32)
    text: Text = Field("", max_length=200)


class AliveRequest(_Request):
    """The operator is still there: renews the lease of the running test (``lease``: the token
    of its ``start_test`` reply; `control.daemon.lease`). A test whose lease lapses is aborted."""

    cmd: Literal["alive"]
    lease: Text = Field(min_length=1, max_length=64)


#: How often a client renews an operator lease, as a share of the lease: three renewals may be
#: lost (a loaded PC) before it lapses.
RENEW_SHARE = 0.25


def renew_every_s(lease_s: float) -> float:
    """How often a client renews an operator lease of ``lease_s`` [s]."""
    return lease_s * RENEW_SHARE


class PauseRequest(_Request):
    cmd: Literal["pause"]


class ResumeRequest(_Request):
    cmd: Literal["resume"]


class AbortRequest(_Request):
    """Abort the run. Never refused for what it carries (only for the state: nothing to abort):
    a reason with NULs, lone surrogates, too long or not text is replaced (`SafeReason`, noted
    in the reason), a request id a reply cannot carry is made safe (`SafeRequestId`) and
    unknown fields are ignored."""

    model_config = ConfigDict(extra="ignore", frozen=True, strict=True)
    cmd: Literal["abort"]
    request_id: SafeRequestId = ""
    reason: SafeReason = "operator abort"


class PumpRequest(_Request):
    cmd: Literal["pump"]
    on: bool


class StatusRequest(_Request):
    cmd: Literal["status"]


class ListRunsRequest(_Request):
    cmd: Literal["list_runs"]


class RunListing(TypedDict):
    """One run file of the ``list_runs`` reply's ``runs`` (newest first): the run being
    written only with its path, id and "running"; an unreadable one with why
    (``status_reason``)."""

    path: str
    run_id: str
    #: the file's status, "running" for the daemon's current run, "unreadable"
    status: str
    kind: NotRequired[str]
    status_reason: NotRequired[str]
    start_time: NotRequired[str]
    stop_time: NotRequired[str]
    n_samples: NotRequired[int]
    n_steps: NotRequired[int]


class ResetRequest(_Request):
    """Acknowledge a fault: fault -> idle (refused while a run is going). While idle there is
    nothing to reset: answered ok with ``data["nothing_to_reset"]`` true, and nothing changes."""

    cmd: Literal["reset"]


#: every request the daemon takes
AnyRequest = (StartRequest | PauseRequest | ResumeRequest | AbortRequest | PumpRequest
              | StatusRequest | ListRunsRequest | ResetRequest | StartTestRequest | AnswerRequest
              | AliveRequest)
Request = Annotated[AnyRequest, Field(discriminator="cmd")]
COMMANDS = ("start", "pause", "resume", "abort", "pump", "status", "list_runs", "reset",
            "start_test", "answer", "alive")
_REQUEST_ADAPTER: TypeAdapter[AnyRequest] = TypeAdapter(Request)


class RequestError(ValueError):
    """A request frame that cannot be accepted; ``kind`` says how it is wrong."""

    def __init__(self, kind: ErrorKind, message: str, cmd: str = "", request_id: str = "") -> None:
        super().__init__(message)
        self.kind = kind
        self.cmd = cmd
        self.request_id = request_id


def parse_request(frame: bytes) -> AnyRequest:
    """Validate one request frame; return the request model or raise `RequestError`.

    The message of the error names the field and the problem, e.g.
    ``"pump.on: Input should be a valid boolean"``.
    """
    if len(frame) > MAX_REQUEST_BYTES:
        raise RequestError(ErrorKind.MALFORMED,
                           f"request of {len(frame)} bytes exceeds {MAX_REQUEST_BYTES} bytes")
    try:
        data = json.loads(frame)
    except RecursionError:
        raise RequestError(ErrorKind.MALFORMED, "request is not JSON: nested too deeply") from None
    except ValueError as err:  # not UTF-8, not JSON, or an integer of more than 4,300 digits
        raise RequestError(ErrorKind.MALFORMED, f"request is not JSON: {err}") from None
    if not isinstance(data, dict):
        raise RequestError(ErrorKind.MALFORMED,
                           f"request must be a JSON object, got {type(data).__name__}")
    cmd = data.get("cmd")
    rid = data.get("request_id")
    rid = safe_text(rid, 128) if isinstance(rid, str) else ""
    if cmd not in COMMANDS:
        raise RequestError(
            ErrorKind.INVALID,
            f"unknown command {cmd!r}; commands are {', '.join(COMMANDS)}",
            request_id=rid,
        )
    try:
        return _REQUEST_ADAPTER.validate_python(data)
    except ValidationError as err:
        raise RequestError(ErrorKind.INVALID, describe_errors(err, str(cmd)), cmd=str(cmd),
                           request_id=rid) from None
    except RecursionError:
        raise RequestError(ErrorKind.MALFORMED, "request nested too deeply", cmd=str(cmd),
                           request_id=rid) from None


def describe_errors(err: ValidationError, where: str,
                    model: type[BaseModel] | None = None) -> str:
    """One clause per problem: ``where.field.path: message (got value)``; given the ``model``
    validated, a field it does not have gets the one it probably means ("did you mean")."""
    parts = []
    for e in err.errors()[:10]:
        loc = ".".join(str(p) for p in e["loc"] if p not in COMMANDS)
        value = e.get("input")
        shown = (repr(value) if isinstance(value, str | float | bool)
                 or isinstance(value, int) and abs(value) < 10**30 else type(value).__name__)
        got = "" if e["type"] == "missing" else f" (got {shown[:80]})"
        hint = unknown_field_hint(model, e["loc"]) if e["type"] == "extra_forbidden" else ""
        parts.append(f"{where}{'.' + loc if loc else ''}: {e['msg']}{got}{hint}")
    return "; ".join(parts)


# --- replies ----------------------------------------------------------------------------------
class Reply(BaseModel):
    """The daemon's answer to one request. Serialisable by construction: every string goes
    through `safe_text` and ``data`` through `safe_json`, whatever a request echoed into them."""

    model_config = ConfigDict(extra="forbid")
    ok: bool
    cmd: str = ""
    request_id: str = ""
    state: DaemonState
    error_kind: ErrorKind | None = None
    error: str = ""
    data: dict[str, Any] = Field(default_factory=dict)

    @field_validator("cmd", "error", mode="before")
    @classmethod
    def _safe_str(cls, v: object) -> str:
        return safe_text(v, 20_000)

    @field_validator("request_id", mode="before")
    @classmethod
    def _safe_request_id(cls, v: object) -> str:
        return safe_text(v, 128)

    @field_validator("data", mode="before")
    @classmethod
    def _safe_data(cls, v: Any) -> Any:
        return safe_json(v) if isinstance(v, dict) else v

    def to_frame(self) -> bytes:
        return self.model_dump_json().encode()

    @classmethod
    def from_frame(cls, frame: bytes) -> Reply:
        return cls.model_validate_json(frame)


# --- live-data framing ------------------------------------------------------------------------
def encode_header(header: dict[str, Any]) -> bytes:
    """A header as compact JSON bytes (NaN written as ``NaN``, which Python's json reads)."""
    return json.dumps(header, separators=(",", ":")).encode()


def decode_block(header: dict[str, Any], payload: bytes | memoryview) -> np.ndarray:
    """The array of a ``block`` message, shape ``header["shape"]``, float64 (read-only view).

    Raises
    ------
    ValueError
        if the payload length does not match the header's shape.
    """
    rows, n = (int(v) for v in header["shape"])
    arr = np.frombuffer(payload, dtype=PAYLOAD_DTYPE)
    if arr.size != rows * n:
        raise ValueError(
            f"block seq {header.get('seq')}: payload holds {arr.size} values, header shape "
            f"({rows}, {n}) needs {rows * n}"
        )
    return arr.reshape(rows, n)
