"""One planned dwell of a sweep: what to hold, at which frequency. What the sweep request
(`sweep_spec`) enumerates; shared with the run's safety and the sweep engine (kept apart so that
safety does not depend on the sweep module)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

TargetKind = Literal["displacement", "load"]


@dataclass(frozen=True)
class StepPlan:
    """A dwell: hold ``shape`` (complex X, Y amplitudes up to a common phase) at ``freq_hz``.

    Attributes
    ----------
    index : int
        Position in the sweep (0-based, as in the run file and on the wire; people read
        ``index + 1``: `describe`).
    freq_hz : float
        Excitation frequency [Hz].
    target_kind : "displacement" | "load"
        What is held: the mean probe displacement [m] or the load-cell force [N].
    target_value : float
        Amplitude of the fundamental of the reference axis (X, or Y for motion "y") [m or N].
    motion : str
        "x", "y", "circular_forward", "circular_backward" or "elliptical".
    shape : complex array (2,)
        Target complex amplitudes of X and Y [m or N] (`controller.motion_shape`).
    steps_total : int
        Dwells in the sweep (0: not known), for `describe`'s "step 2/5".
    """

    index: int
    freq_hz: float
    target_kind: TargetKind
    target_value: float
    motion: str
    shape: np.ndarray
    steps_total: int = 0

    @property
    def unit(self) -> str:
        return "m" if self.target_kind == "displacement" else "N"

    @property
    def number(self) -> str:
        """The step as people count it: from 1, of the total when known ("2/5")."""
        return f"{self.index + 1}" + (f"/{self.steps_total}" if self.steps_total else "")

    def describe(self) -> str:
        value = (
            f"{self.target_value * 1e6:.3g} um" if self.target_kind == "displacement"
            else f"{self.target_value:.3g} N"
        )
        return (f"step {self.number} ({self.motion}, {value} {self.target_kind}, "
                f"{self.freq_hz:g} Hz)")
