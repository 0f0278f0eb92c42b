"""The operator protocol: what a test programme asks a person, and what the person answers, as data.

A programme posts one `Question` at a time to an `OperatorDesk` and keeps the DAQ streaming while
it waits; a front end (the terminal of `sfdrig structure`, the browser view) shows the question
(it is in the daemon's status) and sends an answer: a choice and, for an entry, the typed text.
The desk validates the text here, once, for every front end: a number with a unit of the entry's
quantity, inside the entry's range. A refused entry changes nothing and its message says what was
wrong; every answer, accepted or refused, is logged (``on_event``) with the time by the run file.

Choices: ``ok`` (do it / the value typed), ``repeat`` (this point again), ``skip`` (leave this point
out), ``abort`` (end the programme the safe way, keeping the points so far), ``reject`` (an impact
hit the operator does not want), and on the simulated rig ``double`` / ``overload`` (ask the
simulated hammer for a bad hit, so the rejection is testable).
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Quantity = Literal["force", "length", "pressure"]

#: Units accepted per quantity, with their factor to SI.
UNITS: dict[str, dict[str, float]] = {
    "force": {"N": 1.0, "kN": 1e3, "lbf": 4.4482216152605, "lb": 4.4482216152605},
    "length": {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "in": 0.0254, "mil": 25.4e-6},
    "pressure": {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "psi": 6894.757293168},
}
CHOICE_WORDS: dict[str, str] = {
    "ok": "accept", "repeat": "repeat this point", "skip": "skip this point",
    "abort": "abort the programme", "reject": "reject this hit",
    "double": "simulated double hit", "overload": "simulated overload",
}
_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-zµ]*)\s*$")


class EntryError(ValueError):
    """A typed entry or a choice that cannot be accepted; the message says what and why."""


class Entry(BaseModel):
    """One value the operator types: a quantity in the given display unit, within a range."""

    model_config = ConfigDict(extra="forbid")
    name: str
    label: str
    quantity: Quantity
    unit: str = Field(description="display unit, and the unit of a bare number")
    min_si: float
    max_si: float

    def parse(self, text: str) -> float:
        """``text`` ("0.0021 in", "53 um", "-40") in SI, or `EntryError` naming the problem."""
        m = _NUMBER.match(text)
        units = UNITS[self.quantity]
        if m is None:
            raise EntryError(f"{self.label}: {text.strip()!r} is not a number with a unit "
                             f"(e.g. '12.5 {self.unit}'; units: {', '.join(units)})")
        unit = m.group(2) or self.unit
        factor = units.get(unit)
        if factor is None:
            low = {k.lower(): v for k, v in units.items()}
            factor = low.get(unit.lower())
        if factor is None:
            raise EntryError(f"{self.label}: {unit!r} is not a unit of {self.quantity} "
                             f"(use {', '.join(units)})")
        value = float(m.group(1)) * factor
        if not self.min_si <= value <= self.max_si:
            raise EntryError(f"{self.label}: {text.strip()} is outside "
                             f"{self.show(self.min_si)} .. {self.show(self.max_si)}")
        return value

    def show(self, value_si: float) -> str:
        return f"{value_si / UNITS[self.quantity][self.unit]:.6g} {self.unit}"


class Question(BaseModel):
    """One thing asked of the operator. ``trigger``: a hammer strike on the armed acquisition
    answers it too (no typing needed on the real rig)."""

    model_config = ConfigDict(extra="forbid")
    id: int
    where: str = Field(description="programme, step and point, e.g. 'probe_calibration x 3/7'")
    prompt: str
    info: list[str] = Field(default_factory=list, description="measured values to show")
    entry: Entry | None = None
    choices: list[str] = Field(default_factory=lambda: ["ok", "repeat", "skip", "abort"])
    trigger: bool = False
    shows: str = Field("", description="what a simulated instrument shows (the simulated rig "
                       "only; on the real rig the person reads the instrument)")


class Answer(BaseModel):
    model_config = ConfigDict(extra="forbid")
    question_id: int
    choice: str
    text: str = ""
    value_si: float | None = None


class OperatorDesk:
    """One pending question at a time, answered from another thread (the command socket).

    The programme side: `post`, `poll` (non-blocking), `withdraw`, `abort_reason`. The front-end
    side: `pending`, `submit`. ``on_event(kind, message)`` logs every answer and refusal.
    """

    def __init__(self, on_event: Callable[[str, str], None] | None = None) -> None:
        self._lock = threading.Lock()
        self._pending: Question | None = None
        self._answer: Answer | None = None
        self._next_id = 1
        self.abort_reason = ""
        self.on_event = on_event or (lambda kind, message: None)

    # --- the programme's side -------------------------------------------------------------
    def post(self, question: Question) -> Question:
        """Ask ``question`` (its id is assigned here); replaces any pending one."""
        with self._lock:
            q = question.model_copy(update={"id": self._next_id})
            self._next_id += 1
            self._pending, self._answer = q, None
        shown = "".join(f"; {line}" for line in q.info)
        self.on_event("operator", f"asked #{q.id} ({q.where}): {q.prompt}{shown}")
        return q

    def poll(self) -> Answer | None:
        """The answer to the posted question once given (then nothing is pending)."""
        with self._lock:
            answer, self._answer = self._answer, None
            if answer is not None:
                self._pending = None
            return answer

    def withdraw(self, why: str = "") -> None:
        with self._lock:
            q, self._pending, self._answer = self._pending, None, None
        if q is not None and why:
            self.on_event("operator", f"#{q.id} ({q.where}) {why}")

    def abort(self, reason: str) -> None:
        self.abort_reason = reason or "operator abort"

    # --- the front end's side -------------------------------------------------------------
    def pending(self) -> Question | None:
        with self._lock:
            return None if self._answer is not None else self._pending

    def submit(self, question_id: int, choice: str, text: str = "") -> Answer:
        """Validate and accept an answer; `EntryError` (nothing changes) if it cannot be."""
        with self._lock:
            q = self._pending
            try:
                if q is None or self._answer is not None:
                    raise EntryError(f"question #{question_id} is not pending (nothing is asked "
                                     "now)")
                if q.id != question_id:
                    raise EntryError(f"question #{question_id} is not pending (#{q.id} is)")
                if choice not in q.choices:
                    raise EntryError(f"#{q.id}: {choice!r} is not a choice here "
                                     f"({', '.join(q.choices)})")
                value = None
                if choice == "ok" and q.entry is not None:
                    value = q.entry.parse(text)
            except EntryError as err:
                refused = str(err)
            else:
                refused = ""
                ans = Answer(question_id=q.id, choice=choice, text=text, value_si=value)
                self._answer = ans
        if refused:
            typed = f"entry {text!r}" if text else f"choice {choice!r}"
            self.on_event("operator", f"refused {typed}: {refused}")
            raise EntryError(refused)
        assert q is not None
        typed = f" {text.strip()!r}" if text.strip() else ""
        shown = f" = {q.entry.show(value)}" if q.entry is not None and value is not None else ""
        self.on_event("operator", f"answer #{q.id} ({q.where}): {choice}{typed}{shown}")
        return ans


__all__ = ["CHOICE_WORDS", "UNITS", "Answer", "Entry", "EntryError", "OperatorDesk", "Question"]
