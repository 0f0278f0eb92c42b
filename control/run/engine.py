"""What the daemon runs: the one `Engine` protocol, which the sweep (`control.run.sweep.engine`)
and the operator programmes (`control.run.programs.engine`) implement, and the `RunOutcome`
every run ends with. The daemon asks an engine only what this protocol says."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, Protocol

from pydantic import BaseModel, JsonValue

from control.wire.heartbeat import RunSummary, Tolerance

#: how a run ended: "failed" when the rig or the software failed, "aborted" when a trip, an
#: interlock or a person stopped it
RunStatus = Literal["completed", "aborted", "failed"]


class RunSpec(Protocol):
    """A run request's spec once validated (`SweepSpec`, the programmes' specs): a pydantic
    model, written whole into the run file, that says whether the run has the oil film."""

    @property
    def lubricated(self) -> bool: ...

    def model_dump_json(self) -> str: ...


#: turns a request's spec (its JSON object) into the validated spec, or raises
#: `pydantic.ValidationError` / `ValueError` naming the field
SpecParser = Callable[[dict[str, JsonValue]], RunSpec]


class RunOutcome(Protocol):
    """How a run ended (`SweepOutcome`, `ProgramOutcome`)."""

    @property
    def status(self) -> RunStatus: ...

    @property
    def reason(self) -> str:
        """"" when it completed cleanly; otherwise why it stopped (or what went wrong)."""
        ...


class OperatorQuestions(Protocol):
    """A person in the loop (`control.run.programs.operator.OperatorDesk`): the question pending
    now, and the answer to one."""

    def pending(self) -> BaseModel | None: ...

    def submit(self, question_id: int, choice: str, text: str = "") -> BaseModel: ...


class Engine(Protocol):
    """One run, built by the daemon's command thread and run in its acquisition thread.

    ``run`` blocks until the run ends (drives at zero) and returns its outcome; it raises
    `TargetError` / `InterlockError` only for a refusal before any output. ``abort``, ``pause``
    and ``resume`` may come from any other thread; ``pause`` only where ``can_pause``.
    """

    @property
    def can_pause(self) -> bool: ...

    @property
    def steps_total(self) -> int | None:
        """The steps planned, or None when the run does not know them ahead (a programme)."""
        ...

    @property
    def summary(self) -> RunSummary | None:
        """JSON-safe: the run's peaks, contact and trip (`control.run.summary`), or None."""
        ...

    @property
    def desk(self) -> OperatorQuestions | None:
        """Where the run asks a person, or None for an unattended run."""
        ...

    def check(self) -> None:
        """Refuse the run now, before its file exists: `TargetError` (targets, limits, channel
        map) or `InterlockError` (the pump). Once passed, ``run`` does not check again."""
        ...

    def run(self) -> RunOutcome: ...

    def abort(self, reason: str) -> None: ...

    def pause(self) -> None: ...

    def resume(self) -> None: ...

    def progress_fields(self) -> dict[str, Any]:
        """Where the run is now, JSON-safe, for the daemon's status (any thread)."""
        ...

    def tolerance(self) -> Tolerance | None:
        """The tolerances a display draws the steps against, or None."""
        ...
