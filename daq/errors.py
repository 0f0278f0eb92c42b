"""Typed DAQ errors. Every error from a backend reaches callers as one of these, carrying the
NI-DAQmx status code where there is one, so a gap in the data is never silent."""

from __future__ import annotations

# NI-DAQmx status codes the project names (same numbers as the NI driver).
READ_TIMEOUT = -200284
INPUT_BUFFER_OVERWRITTEN = -200279
OUTPUT_UNDERFLOW = -200290
INVALID_ATTRIBUTE_VALUE = -200077
SAMPLE_RATE_TOO_HIGH = -200332
RESOURCE_RESERVED = -50103
DEVICE_NOT_FOUND = -200220


class DaqError(RuntimeError):
    """An error reported by the data-acquisition layer (driver, device server or simulation).

    Attributes
    ----------
    code : int
        NI-DAQmx status code (negative), or 0 when the failure has no DAQmx code.
    """

    def __init__(self, message: str, code: int = 0) -> None:
        super().__init__(f"{message} (DAQmx code {code})" if code else message)
        self.code = code


class DaqTimeoutError(DaqError, TimeoutError):
    """A read did not get its samples in time (DAQmx -200284)."""


class DaqBufferOverflowError(DaqError):
    """Input samples were overwritten before they were read (DAQmx -200279)."""


class DaqUnderflowError(DaqError):
    """The output buffer ran dry: the writer fell behind the generation (DAQmx -200290)."""


class DaqConnectionError(DaqError, ConnectionError):
    """The driver or the gRPC device server could not be reached, or it lacks a needed call."""


class ChannelConfigError(ValueError):
    """A channel map or device description is invalid; the message names the field and value."""


def error_for_code(message: str, code: int) -> DaqError:
    """The most specific `DaqError` subclass for an NI-DAQmx status code."""
    cls: type[DaqError] = {
        READ_TIMEOUT: DaqTimeoutError,
        INPUT_BUFFER_OVERWRITTEN: DaqBufferOverflowError,
        OUTPUT_UNDERFLOW: DaqUnderflowError,
    }.get(code, DaqError)
    return cls(message, code)
