"""A run file's catalog row: what the run was, how it ended, and the conditions it was recorded
under (lubricated, seal, motion), read from the file's header (`read_row`) or stated by its
writer (`storage.runfile.RunWriter`, which records its run in the run index)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from storage.errors import RunFileError
from storage.reader import open_run
from storage.recovery import writer_gone


@dataclass(frozen=True)
class RunRow:
    """One catalog row.

    Attributes
    ----------
    id : str
        Run id ("" when the file cannot be read).
    date : str
        Start time, ISO 8601 UTC.
    kind : str
        Kind of test (sweep, static, impact, probe_calibration, flow, imported, commissioning).
    steps : int
        Dwells recorded.
    status : str
        running, completed, aborted, failed; "interrupted" for a run left "running" by a writer
        that is gone (`storage.recovery.writer_gone`), or closed so by a restarted daemon;
        "unreadable" for a broken file (see ``error``).
    duration_s : float
        Recorded span [s] (samples / sample rate).
    file : str
        Path of the run file.
    error : str
        Why the file is unreadable ("" otherwise).
    lubricated : bool or None
        Run with the oil film (None: unreadable file).
    seal : str
        The end seal (`seal_of`): "none", "unknown", its friction force F_mu [N] as a number,
        or "" when not stated.
    motion : str
        The motion driven (`motion_of`): x, y, circular_forward, circular_backward,
        elliptical; several joined by commas; "" when none is recorded.
    stop_time : str
        When the run ended, ISO 8601 UTC ("" while running, or unknown).
    n_samples : int
        Samples recorded per channel.
    status_reason : str
        Why the run did not complete, as its file says ("" when it did, or is running).
    """

    id: str
    date: str
    kind: str
    steps: int
    status: str
    duration_s: float
    file: str
    error: str = ""
    lubricated: bool | None = None
    seal: str = ""
    motion: str = ""
    stop_time: str = ""
    n_samples: int = 0
    status_reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def seal_of(test_spec: Any, rig_config: Any) -> str:
    """The end seal as the importer states it: "none", "unknown", F_mu in N (``repr`` of a
    float), or "" (not stated): an imported run's stated condition, else the rig
    description's seal."""
    spec = test_spec if isinstance(test_spec, dict) else {}
    conditions = spec.get("conditions")
    stated = conditions.get("seal") if isinstance(conditions, dict) else None
    if stated:
        return str(stated)
    seal = rig_config.get("seal") if isinstance(rig_config, dict) else None
    if not isinstance(seal, dict):
        return ""
    force = seal.get("friction_force_n")
    if not seal.get("enabled", True) or not force:
        return "none"
    return repr(float(force))


def seal_friction_n(seal: str) -> float:
    """The friction force F_mu [N] of a `seal_of` value: 0 for no seal, NaN when unknown or not
    stated."""
    if seal == "none":
        return 0.0
    try:
        return float(seal)
    except ValueError:
        return math.nan


def motion_of(step_motions: Iterable[str], test_spec: Any) -> str:
    """The motion of a run: its steps' motions (sorted, joined by commas), else the one its
    test spec names (a run before its first step, a test of no steps), else ""."""
    motions = sorted({m for m in step_motions if m})
    if motions:
        return ",".join(motions)
    spec = test_spec if isinstance(test_spec, dict) else {}
    conditions = spec.get("conditions")
    named = spec.get("motion") or (conditions.get("motion") if isinstance(conditions, dict)
                                   else None)
    return named if isinstance(named, str) else ""


def read_row(path: Path, now: float | None = None) -> RunRow:
    """The catalog row of one file, from its header (an "unreadable" row when it is broken)."""
    try:
        with open_run(path) as run:
            status = run.status
            if status == "running" and writer_gone(run.attrs, path, now):
                status = "interrupted"
            steps = run.steps
            return RunRow(id=run.run_id, date=run.start_time, kind=run.kind,
                          steps=len(steps), status=status,
                          duration_s=round(run.duration_s, 6), file=str(path),
                          lubricated=bool(run.attrs.get("lubricated", False)),
                          seal=seal_of(run.test_spec, run.rig_config),
                          motion=motion_of((str(s.get("motion", "")) for s in steps),
                                           run.test_spec),
                          stop_time=run.stop_time, n_samples=int(run.n_samples),
                          status_reason=str(run.attrs.get("status_reason", "")))
    except RunFileError as err:
        return RunRow(id="", date="", kind="", steps=0, status="unreadable", duration_s=0.0,
                      file=str(path), error=str(err))
