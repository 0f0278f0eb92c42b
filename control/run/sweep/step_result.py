"""What one dwell achieved: `StepResult` (the run file's and the wire's step record)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from control.signal.controller import Assessment
from control.wire.step_plan import StepPlan


@dataclass
class StepResult:
    """What a dwell achieved (contract A's step dict, via `to_dict`).

    Attributes
    ----------
    plan : StepPlan
    first_sample, last_sample : int
        Half-open span of the recorded whole cycles (run sample indices).
    updates : int
        Controller corrections made in this step.
    converged : bool
    reason : str
        Why not converged ("" when converged).
    harmonics : complex array (n_ai, 5)
        1X..5X of every AI channel over the span, engineering units.
    drive_v : complex array (n_ao,)
        1X of every drive over the span [V].
    ai_names, ao_names : list of str
    start_sample : int
        Run sample at which the step began (its ramp).
    """

    plan: StepPlan
    first_sample: int
    last_sample: int
    updates: int
    converged: bool
    reason: str
    harmonics: np.ndarray
    drive_v: np.ndarray
    ai_names: list[str]
    ao_names: list[str]
    start_sample: int = 0
    assessment: Assessment | None = field(default=None, repr=False)
    controlled: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict in the layout of contract A."""
        p = self.plan
        return {
            "index": int(p.index),
            "freq_hz": float(p.freq_hz),
            "target_kind": p.target_kind,
            "target_value": float(p.target_value),
            "motion": p.motion,
            "first_sample": int(self.first_sample),
            "last_sample": int(self.last_sample),
            "updates": int(self.updates),
            "converged": bool(self.converged),
            "reason": self.reason,
            "harmonics": {
                name: [[float(z.real), float(z.imag)] for z in self.harmonics[i]]
                for i, name in enumerate(self.ai_names)
            },
            "drive_v": {
                name: [float(self.drive_v[i].real), float(self.drive_v[i].imag)]
                for i, name in enumerate(self.ao_names)
            },
        }
