"""Where nidaqmx tasks are made: the local NI-DAQmx driver or an NI gRPC Device Server, with
errors translated to `daq.errors`. Shared by `NidaqmxBackend` (the run's tasks) and
`daq.device_check` (what a device offers, live values)."""

from __future__ import annotations

import contextlib
import logging
import uuid
from collections.abc import Iterator
from typing import Any

from daq.board import grpc_target_problem
from daq.errors import ChannelConfigError, DaqConnectionError, DaqError, error_for_code

_log = logging.getLogger(__name__)

#: gRPC message limit: one read of 100,000 samples x 16 channels is 12.8 MB of doubles.
MAX_MESSAGE_BYTES = 256 * 1024 * 1024


def _nidaqmx() -> Any:
    """Import nidaqmx lazily, so the rest of the project never pays for it."""
    try:
        import nidaqmx
        import nidaqmx.errors
        import nidaqmx.stream_readers
        import nidaqmx.stream_writers
    except ImportError as err:  # pragma: no cover - a pinned dependency
        raise DaqConnectionError(f"the nidaqmx package is not installed: {err}") from None
    return nidaqmx


@contextlib.contextmanager
def translate_errors(action: str) -> Iterator[None]:
    """Re-raise nidaqmx and gRPC errors as our typed errors; ``action`` says what we were doing.

    ``nidaqmx.errors.DaqError`` (and its read/write subclasses) -> `error_for_code` with the
    DAQmx code; ``RpcError`` (server unreachable or lacking a call) and a missing driver
    -> `DaqConnectionError`.
    """
    nidaqmx = _nidaqmx()
    errors = nidaqmx.errors
    try:
        yield
    except errors.DaqError as err:
        message = str(err).split("\n\nStatus Code:")[0].strip()
        raise error_for_code(f"{action}: {message}", err.error_code) from err
    except errors.RpcError as err:
        raise DaqConnectionError(f"{action}: NI gRPC device server error: {err}") from err
    except (errors.DaqNotFoundError, errors.DaqNotSupportedError) as err:
        raise DaqConnectionError(f"{action}: NI-DAQmx driver not available: {err}") from err
    except DaqError:
        raise
    except ConnectionError as err:
        raise DaqConnectionError(f"{action}: {err}") from err


def close_task(task: Any) -> None:
    """Clear a nidaqmx task. A failure (the driver or server has lost it) is logged, not raised:
    there is nothing left to release."""
    try:
        with translate_errors("clearing a task"):
            task.close()
    except DaqError as err:
        _log.warning("close: %s", err)
        # the task is gone from the driver/server: spare nidaqmx's "not explicitly closed"
        # destructor warning (WatchdogTask has one)
        task._handle = None


class NidaqmxSession:
    """The local driver (``grpc_target`` None) or one gRPC channel to a device server, opened
    on first use and closed by `close`.

    Parameters
    ----------
    grpc_target : str or None
        ``"host:port"`` of an NI gRPC Device Server; None for the local NI-DAQmx driver.
    connect_timeout_s : float
        How long the first use waits for a gRPC server to answer [s].
    """

    def __init__(self, grpc_target: str | None, connect_timeout_s: float = 5.0) -> None:
        self.grpc_target = grpc_target
        self.connect_timeout_s = connect_timeout_s
        self._channel: Any = None  # grpc.Channel

    @property
    def where(self) -> str:
        """`` on host:port`` for a gRPC server, empty for the local driver (for messages)."""
        return f" on {self.grpc_target}" if self.grpc_target else ""

    def grpc_options(self) -> Any:
        """nidaqmx's ``GrpcSessionOptions`` for the server (a new server session each time, so
        a crashed client's stale task is never re-attached), or None for the local driver."""
        nidaqmx = _nidaqmx()
        target = self.grpc_target
        if target is None:
            return None
        if self._channel is None:
            import grpc

            problem = grpc_target_problem(target)
            if problem:
                raise ChannelConfigError(f"grpc_target {target!r}: {problem}")
            self._channel = grpc.insecure_channel(target, options=[
                ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
                ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
            ])
            try:
                grpc.channel_ready_future(self._channel).result(timeout=self.connect_timeout_s)
            except grpc.FutureTimeoutError:
                self.close()
                raise DaqConnectionError(
                    f"no NI gRPC device server answers at {target} "
                    f"(waited {self.connect_timeout_s:g} s)"
                ) from None
        return nidaqmx.GrpcSessionOptions(
            self._channel, "",
            initialization_behavior=nidaqmx.grpc_session_options.SessionInitializationBehavior
            .INITIALIZE_SERVER_SESSION,
        )

    def new_task(self, role: str) -> Any:
        """A new ``nidaqmx.Task`` named ``sfdrig-<role>-<uuid>``."""
        nidaqmx = _nidaqmx()
        options = self.grpc_options()
        name = f"sfdrig-{role}-{uuid.uuid4().hex[:12]}"
        with translate_errors(f"creating the {role.upper()} task {name}{self.where}"):
            if options is None:
                return nidaqmx.Task(name)
            return nidaqmx.Task(name, grpc_options=options)

    def device_is_simulated(self, device_name: str) -> bool:
        """What the device says of itself (DAQmx's DevIsSimulated): an NI simulated device, or
        `sfdrig sim-server`, answers yes. A device or driver that cannot say is taken as a real
        board (so nothing reads as a rehearsal that might be the rig)."""
        try:
            from nidaqmx.system import Device

            with translate_errors(f"asking {device_name}{self.where} whether it is simulated"):
                return bool(Device(device_name, grpc_options=self.grpc_options()).is_simulated)
        except (DaqError, ImportError):
            return False

    def close(self) -> None:
        """Close the gRPC channel (safe to call twice; tasks are the caller's to close)."""
        if self._channel is not None:
            self._channel.close()
            self._channel = None
