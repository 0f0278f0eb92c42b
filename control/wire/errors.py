"""A request refused before anything runs, as a client sees it (the daemon answers with the
message). Each subclasses a standard exception, so callers may catch either.

- `ControlError`: base of every error raised by the control package (`control.run.errors` holds
  the ones raised while running).
- `TargetError` (ValueError): a sweep or target that must not be run (bad amplitude, frequency out
  of range, over a limit); raised before any output is written.
- `SpecError` (TargetError): an invalid sweep description; the message names the field and value.
"""

from __future__ import annotations


class ControlError(Exception):
    """Base of every error raised by the control package."""


class TargetError(ControlError, ValueError):
    """A target, sweep description or limit set that is refused before any output is written."""


class SpecError(TargetError):
    """An invalid sweep description (TOML or dict); the message names the field and the value."""
