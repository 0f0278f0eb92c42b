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
    #: the step's index in the run file (from 0); `message` counts from 1, as people do
    step: int | None = None
    channel: str | None = None
    #: the reason without the step and the channel it is about, where the reason names them
    #: (e.g. "signal not in the run (channels fx, x)"): what groups items of one cause
    cause: str = ""

    @property
    def message(self) -> str:
        where = [f"run {self.run}"]
        if self.step is not None:  # people count steps from 1; ``step`` is the file's index
            where.append(f"step {self.step + 1}")
        if self.channel:
            where.append(f"channel {self.channel}")
        return f"{', '.join(where)} [{self.analysis}]: {self.reason}"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["message"] = self.message
        return d


def summarise_skipped(skipped: list[Skipped]) -> list[str]:
    """One line per cause (run, analysis and cause alike), with how many items it covers and in
    which steps and channels: 15 lines "signal 'ay' is not in the run" for 3 dwells x 5 signals
    become one."""
    groups: dict[tuple[str, str, str], list[Skipped]] = {}
    for s in skipped:
        groups.setdefault((s.run, s.analysis, s.cause or s.reason), []).append(s)
    lines = []
    for (run, analysis, cause), items in groups.items():
        if len(items) == 1:
            lines.append(items[0].message)
            continue
        steps = sorted({s.step + 1 for s in items if s.step is not None})  # counted from 1
        channels = sorted({s.channel for s in items if s.channel})
        where = f"run {run}"
        if channels:
            where += f", channel{'s' if len(channels) > 1 else ''} {', '.join(channels)}"
        counted = f"{len(items)} items"
        if steps:
            counted += f" in step{'s' if len(steps) > 1 else ''} {_ranges(steps)}"
        lines.append(f"{where} [{analysis}]: {cause} ({counted})")
    return lines


def _ranges(values: list[int]) -> str:
    """[1, 2, 3, 6] -> "1-3, 6"."""
    out: list[str] = []
    start = prev = values[0]
    for v in [*values[1:], None]:
        if v is not None and v == prev + 1:
            prev = v
            continue
        out.append(f"{start}-{prev}" if prev > start else f"{start}")
        if v is not None:
            start = prev = v
    return ", ".join(out)
