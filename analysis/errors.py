"""Errors and skip records of the analysis: messages name the run, the step and the channel."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


class AnalysisError(ValueError):
    """Data that cannot be analysed as asked: the message names run, step and channel."""


@dataclass(frozen=True)
class Skipped:
    """One thing the analysis left out, and why (shown in the report and the JSON)."""

    run: str
    analysis: str
    reason: str
    step: int | None = None
    channel: str | None = None

    @property
    def message(self) -> str:
        where = [f"run {self.run}"]
        if self.step is not None:
            where.append(f"step {self.step}")
        if self.channel:
            where.append(f"channel {self.channel}")
        return f"{', '.join(where)} [{self.analysis}]: {self.reason}"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["message"] = self.message
        return d
