"""The errors raised while a run runs. Each subclasses a standard exception, so callers may catch
either. A request refused before anything runs (`TargetError`, `SpecError`) is in
`control.wire.errors`, since clients see it too.

- `InterlockError` (RuntimeError): the pump interlock refuses (pump off, no inlet pressure) or the
  pump may not be switched off while the shakers run.
- `LimitTrip` (RuntimeError): a safety limit was exceeded while running; carries the sample.
- `OpenLoopError` (LimitTrip): drive without response (stinger or amplifier).
- `ConvergenceError` (RuntimeError): a step did not reach its tolerance within the allowed updates.
"""

from __future__ import annotations

from control.wire.errors import ControlError


class InterlockError(ControlError, RuntimeError):
    """The pump interlock refuses an action."""


class LimitTrip(ControlError, RuntimeError):
    """A safety limit was exceeded.

    Attributes
    ----------
    sample : int
        Run sample index at which the limit was first exceeded (-1 when not tied to a sample).
    limit : str
        Short name of the limit ("drive_v", "load_n", "displacement_m", "drive_slew", ...).
    """

    def __init__(self, message: str, sample: int = -1, limit: str = "") -> None:
        super().__init__(message)
        self.sample = sample
        self.limit = limit


class OpenLoopError(LimitTrip):
    """The shakers are driven but no force reaches the housing."""


class ConvergenceError(ControlError, RuntimeError):
    """A step did not converge within the allowed number of controller updates."""


class StreamStalled(ControlError, RuntimeError):
    """The acquisition loop fell behind the output (AO backlog ran out) or the DAQ stopped."""
