"""What one dwell achieved: `StepResult`, and the step the run records of it (`to_record`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from control.signal.controller import Assessment
from control.wire.step_plan import StepPlan
from storage.records import StepRecord


@dataclass
class StepResult:
    """What a dwell achieved (recorded as a `StepRecord`: `to_record`).

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

    def to_record(self) -> StepRecord:
        """The step as the run records it (file and wire)."""
        p = self.plan
        return StepRecord(
            index=int(p.index), freq_hz=float(p.freq_hz), target_kind=p.target_kind,
            target_value=float(p.target_value), motion=p.motion,
            first_sample=int(self.first_sample), last_sample=int(self.last_sample),
            updates=int(self.updates), converged=bool(self.converged), reason=self.reason,
            harmonics={name: tuple(complex(z) for z in self.harmonics[i])
                       for i, name in enumerate(self.ai_names)},
            drive_v={name: complex(self.drive_v[i]) for i, name in enumerate(self.ao_names)})
