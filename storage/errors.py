"""Errors of the storage layer. Each subclasses a standard exception so callers can catch either."""

from __future__ import annotations


class RunFileError(ValueError):
    """A run file that cannot be read as an sfdrig run: the message names the file and the fault."""


class MissingSignalError(RunFileError, KeyError):
    """A channel or canonical signal the run file does not hold (also a ``KeyError``)."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


class ImportDataError(ValueError):
    """Measured data that cannot be imported: the message names the file and the line, column or
    variable at fault."""


class ExportError(ValueError):
    """A run that cannot be exported as asked: the message names the run and the step range,
    channel or folder at fault."""
