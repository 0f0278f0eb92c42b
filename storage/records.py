"""The run's records, said once: what a run streams (contract A) and what its file and the wire
hold. A field is added here, and the run file's layout (`storage.layout`), the reader, the
publisher's headers and the page's view follow.

- `StepRecord`: one step (a dwell of a sweep, one point of a structure test): the columns of
  ``/steps``, the step's harmonics and drive 1X, and its further keys (``extra``).
- `EventRecord`: one logged event (state change, trip, abort, operator entry, fault).
- `BlockHeader`: what a live-data block says about its samples (the samples are the payload).
- `RunFileStatus`: how a run file's run stands (``status``; ``status_reason`` says why).

Frozen dataclasses (no validation on construction: the producers are our own code); a record
that arrives from outside (a wire header, an imported file's step) goes through ``from_wire``,
which checks every field and names the one that is wrong. On the wire and in the reader's
``steps`` a record is its JSON dict (`to_wire`), with the same keys as ever.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, get_args

#: A JSON value as the wire and the ``extra`` column carry it.
JsonValue = None | bool | int | float | str | list["JsonValue"] | dict[str, "JsonValue"]
#: Event kinds (a writer keeps any other kind as given).
EventKind = Literal["state", "limit_trip", "abort", "fault", "pump", "operator", "warning",
                    "error", "info"]
EVENT_KINDS: tuple[str, ...] = get_args(EventKind)
#: How a run file's run stands: "running" until the writer closes it.
RunFileStatus = Literal["running", "completed", "aborted", "failed"]
STATUSES: tuple[str, ...] = get_args(RunFileStatus)
#: The step's table columns, in the order of ``/steps`` and of the wire's step dict.
STEP_KEYS = ("index", "freq_hz", "target_kind", "target_value", "motion", "first_sample",
             "last_sample", "updates", "converged", "reason")


@dataclass(frozen=True, slots=True)
class StepRecord:
    """One step of a run.

    Attributes
    ----------
    index : int
        Step number, 0-based, in the order run.
    freq_hz : float
        Excitation frequency [Hz]; 0 for a step without excitation.
    target_kind : str
        What ``target_value`` is: "displacement" [m], "load" [N], "pressure" [Pa] or "".
    target_value : float
        What the step asked (NaN when nothing was).
    motion : str
        x, y, circular_forward, circular_backward, elliptical, or the axis ("" for none).
    first_sample, last_sample : int
        Half-open span of the step's record (run sample indices).
    updates : int
        Corrections the amplitude controller made.
    converged : bool
    reason : str
        Why the step did not converge or ended ("" when it converged).
    harmonics : mapping of channel name to complex tuple
        1X..5X of each channel over the record, engineering units (fewer, or none, where the
        step has no excitation).
    drive_v : mapping of drive name to complex
        The 1X of each drive [V].
    extra : mapping of str to JSON value
        The step's further keys (an impact hit's ``accepted``, a commissioning ``stage``).
    """

    index: int
    freq_hz: float
    target_kind: str
    target_value: float
    motion: str
    first_sample: int
    last_sample: int
    updates: int = 0
    converged: bool = False
    reason: str = ""
    harmonics: Mapping[str, tuple[complex, ...]] = field(default_factory=dict)
    drive_v: Mapping[str, complex] = field(default_factory=dict)
    extra: Mapping[str, JsonValue] = field(default_factory=dict)

    def to_wire(self) -> dict[str, JsonValue]:
        """The step as the JSON dict of the wire and of `RunData.steps`: the columns, then
        ``harmonics`` ({name: [[re, im], ...]}) and ``drive_v`` ({name: [re, im]}), then the
        further keys."""
        out: dict[str, JsonValue] = {
            "index": int(self.index), "freq_hz": float(self.freq_hz),
            "target_kind": self.target_kind, "target_value": float(self.target_value),
            "motion": self.motion, "first_sample": int(self.first_sample),
            "last_sample": int(self.last_sample), "updates": int(self.updates),
            "converged": bool(self.converged), "reason": self.reason,
            "harmonics": {name: [[float(z.real), float(z.imag)] for z in zs]
                          for name, zs in self.harmonics.items()},
            "drive_v": {name: [float(z.real), float(z.imag)]
                        for name, z in self.drive_v.items()},
        }
        out.update(self.extra)
        return out

    @classmethod
    def from_wire(cls, step: Mapping[str, object], index: int = 0) -> StepRecord:
        """A step from its JSON dict (a wire header, an imported or restored step); keys beyond
        the record go to ``extra``; a missing column takes its default (``index`` the one
        given). Raises ValueError naming the field that is not what it should be."""
        got = {k: v for k, v in step.items() if k not in ("harmonics", "drive_v")}
        extra = {k: v for k, v in got.items() if k not in STEP_KEYS}
        try:
            return cls(
                index=_int(got.get("index", index), "index"),
                freq_hz=_real(got.get("freq_hz"), "freq_hz"),
                target_kind=_str(got.get("target_kind"), "target_kind"),
                target_value=_real(got.get("target_value"), "target_value"),
                motion=_str(got.get("motion"), "motion"),
                first_sample=_int(got.get("first_sample", -1), "first_sample"),
                last_sample=_int(got.get("last_sample", -1), "last_sample"),
                updates=_int(got.get("updates", 0), "updates"),
                converged=bool(got.get("converged", False)),
                reason=_str(got.get("reason"), "reason"),
                harmonics={str(name): tuple(_pair(p, f"harmonics.{name}") for p in _list(
                    values, f"harmonics.{name}"))
                    for name, values in _mapping(step.get("harmonics"), "harmonics").items()},
                drive_v={str(name): _pair(p, f"drive_v.{name}")
                         for name, p in _mapping(step.get("drive_v"), "drive_v").items()},
                extra=extra,  # type: ignore[arg-type]  # JSON values, as received
            )
        except ValueError as err:
            raise ValueError(f"step {step.get('index', index)!r}: {err}") from None


@dataclass(frozen=True, slots=True)
class EventRecord:
    """One logged event: ``kind`` (one of `EVENT_KINDS`), what happened, at which run sample."""

    kind: str
    message: str
    sample: int

    def to_wire(self, time_s: float) -> dict[str, JsonValue]:
        """The event header's fields, stamped with ``time_s`` (epoch seconds)."""
        return {"kind": self.kind, "message": self.message, "sample": int(self.sample),
                "time": time_s}

    @classmethod
    def from_wire(cls, header: Mapping[str, object]) -> EventRecord:
        return cls(_str(header.get("kind"), "kind"), _str(header.get("message"), "message"),
                   _int(header.get("sample", 0), "sample"))


@dataclass(frozen=True, slots=True)
class BlockHeader:
    """What a live-data block says of its payload: float64 rows (the AI channels in engineering
    units, then the drive volts) of ``n_samples`` samples from run sample ``first_sample``."""

    first_sample: int
    n_samples: int
    n_ai: int
    channels: tuple[str, ...]
    sample_rate_hz: float
    t_acquired: float

    def to_wire(self) -> dict[str, JsonValue]:
        return {"first_sample": self.first_sample, "n_samples": self.n_samples,
                "shape": [len(self.channels), self.n_samples], "dtype": "<f8",
                "n_ai": self.n_ai, "channels": list(self.channels),
                "sample_rate_hz": self.sample_rate_hz, "t_acquired": self.t_acquired}

    @classmethod
    def from_wire(cls, header: Mapping[str, object]) -> BlockHeader:
        channels = _list(header.get("channels"), "channels")
        return cls(_int(header.get("first_sample"), "first_sample"),
                   _int(header.get("n_samples"), "n_samples"), _int(header.get("n_ai"), "n_ai"),
                   tuple(_str(c, "channels") for c in channels),
                   _real(header.get("sample_rate_hz"), "sample_rate_hz"),
                   _real(header.get("t_acquired", 0.0), "t_acquired"))


def run_file_status(text: str) -> RunFileStatus:
    """``text`` as a run file's status; ValueError if it is none."""
    for status in get_args(RunFileStatus):
        if text == status:
            return status  # type: ignore[no-any-return]
    raise ValueError(f"run status {text!r} is not one of {', '.join(STATUSES)}")


# --- checks of what arrives from outside ------------------------------------------------------
def _int(value: object, what: str) -> int:
    if not isinstance(value, bool):  # True is no sample number
        if isinstance(value, int):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        index = getattr(value, "__index__", None)  # numpy integers
        if index is not None:
            return int(index())
    raise ValueError(f"{what} must be a whole number, not {value!r}")


def _real(value: object, what: str) -> float:
    if value is None:
        return math.nan
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, not {value!r}") from None


def _str(value: object, what: str) -> str:
    if value is None:
        return ""
    if not isinstance(value, str):
        raise ValueError(f"{what} must be text, not {value!r}")
    return value


def _mapping(value: object, what: str) -> Mapping[str, object]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{what} must be a mapping of names, not {value!r}")
    return value


def _list(value: object, what: str) -> list[object]:
    if isinstance(value, str) or not hasattr(value, "__iter__"):
        raise ValueError(f"{what} must be a list, not {value!r}")
    return list(value)  # type: ignore[call-overload]


def _pair(value: object, what: str) -> complex:
    """[re, im] as a complex number."""
    pair = _list(value, what)
    if len(pair) < 2:
        raise ValueError(f"{what} must be [re, im], not {value!r}")
    return complex(_real(pair[0], what), _real(pair[1], what))
