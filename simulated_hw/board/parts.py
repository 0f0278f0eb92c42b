"""The contract of the servicer's RPC parts, said once: what every part (`CounterRpcs`,
`WatchdogRpcs`, `DeviceRpcs`, `DigitalRpcs`, `ChannelAttrRpcs`, `TriggerRpcs`, `WaveformRpcs`,
`LoggingRpcs`) uses of the `SimulatedDaqmxServicer` that composes them. Each part subclasses
`ServicerParts`; the servicer provides every member (`DeviceRpcs` provides ``_check_device``)."""

from __future__ import annotations

from typing import Any, Protocol

from session_pb2 import Session

from simulated_hw.board.tasks import SimChannel, SimTask
from simulated_hw.board.watchdog import Watchdog


class ServicerParts(Protocol):
    """The servicer as its RPC parts see it."""

    #: the board every RPC acts on, a `SimDevice` (not imported: the device calls the parts'
    #: hooks, and an import back would close a circle)
    device: Any
    #: task -> (reference clock source, rate [Hz])
    ref_clock: dict[str, tuple[str, float]]

    def _task(self, session: Session) -> SimTask:
        """The task a session names, or the DAQmx error of a task that does not exist."""
        ...

    def _others(self) -> list[SimTask]:
        """Every task on the server (a part checks a resource against them)."""
        ...

    def _channels(self, task: SimTask, names: str) -> list[SimChannel]:
        """The task's channels a channel string names (all for "")."""
        ...

    def _create(self, name: str, behaviour: int, watchdog: Watchdog | None = None
                ) -> tuple[SimTask, bool]:
        """(the task, whether it is new) for a Create* RPC's name and initialisation."""
        ...

    def _check_device(self, name: str) -> None:
        """The DAQmx error of a device name this server does not have."""
        ...
