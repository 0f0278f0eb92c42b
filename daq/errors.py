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
ATTR_NOT_SUPPORTED = -200197
ATTR_NOT_SUPPORTED_IN_TASK = -200452  # the device lacks the property
WATCHDOG_TIMER_NOT_SUPPORTED = -200662
CANT_RESET_EXPIRED_WATCHDOG = -200644
WRITE_FAILED_WATCHDOG_EXPIRED = -200678


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


class DaqWatchdogExpiredError(DaqError):
    """The board's watchdog timer expired: relays off, drives at their expiration states, writes
    refused (DAQmx -200678, or -200644 on a reset) until the expiration is cleared."""


class EmergencyStopError(DaqError):
    """The emergency-stop input reads pressed: the drives must ramp to zero and the daemon
    latches a fault until it is released and reset."""


class DaqConnectionError(DaqError, ConnectionError):
    """The driver or the gRPC device server could not be reached, or it lacks a needed call."""


class ConfigFileError(ValueError):
    """A configuration file that cannot be used. ``problems``: one line per problem, each
    naming the file and the place (field path, or line and column); the message holds them
    all, under a heading."""

    problems: tuple[str, ...] = ()

    def lines(self) -> list[str]:
        """One line per problem (the message's first line when none were itemised)."""
        return list(self.problems) or [str(self).splitlines()[0]]


class ChannelConfigError(ConfigFileError):
    """A channel map or device description is invalid; the message names the field and value."""


def error_for_code(message: str, code: int) -> DaqError:
    """The most specific `DaqError` subclass for an NI-DAQmx status code."""
    cls: type[DaqError] = {
        READ_TIMEOUT: DaqTimeoutError,
        INPUT_BUFFER_OVERWRITTEN: DaqBufferOverflowError,
        OUTPUT_UNDERFLOW: DaqUnderflowError,
        CANT_RESET_EXPIRED_WATCHDOG: DaqWatchdogExpiredError,
        WRITE_FAILED_WATCHDOG_EXPIRED: DaqWatchdogExpiredError,
    }.get(code, DaqError)
    return cls(message, code)
