"""The oil pump relay and its interlock with the shakers.

`PumpRelay` switches the pump through a relay line of the DAQ (`DaqBackend.set_do`). While a sweep
engine holds the relay (`PumpRelay.shakers_running`), switching the pump off is refused with
`InterlockError`: a squeeze film must not be drained while the housing is shaken. The pressure side
of the interlock (a lubricated sweep waits, with zero drive, for the inlet pressure to build) lives
in the sweep engine, which owns the acquisition.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from control.errors import InterlockError
from daq.backend import DaqBackend


class PumpRelay:
    """The pump's relay line, with the shaker interlock.

    Parameters
    ----------
    backend : DaqBackend
        A configured backend whose channel map has the relay ``name``.
    name : str
        Relay (digital output) name in the channel map.
    on_change : callable(on: bool, message: str), optional
        Called after every switch (for the run log).
    """

    def __init__(
        self,
        backend: DaqBackend,
        name: str = "pump",
        on_change: Callable[[bool, str], None] | None = None,
    ) -> None:
        backend.channel_map.relay(name)  # KeyError naming the missing relay
        self._backend = backend
        self.name = name
        self._on_change = on_change
        self._lock = threading.Lock()
        self._on = False
        self._holds = 0

    @property
    def is_on(self) -> bool:
        """Whether the relay was last switched on."""
        return self._on

    @property
    def shakers_active(self) -> bool:
        """Whether a sweep engine holds the interlock (its shakers may be moving)."""
        return self._holds > 0

    def set(self, on: bool) -> None:
        """Switch the pump on or off.

        Raises
        ------
        InterlockError
            On an attempt to switch it off while the shakers run.
        """
        with self._lock:
            if not on and self._holds > 0:
                raise InterlockError(
                    f"pump {self.name!r} cannot be switched off while the shakers run: "
                    "stop or abort the sweep first"
                )
            self._backend.set_do(self.name, bool(on))
            changed = self._on != bool(on)
            self._on = bool(on)
        if changed and self._on_change is not None:
            self._on_change(self._on, f"pump {self.name!r} switched {'on' if on else 'off'}")

    @contextmanager
    def shakers_running(self) -> Iterator[None]:
        """Hold the interlock for the duration of a run: the pump cannot be switched off."""
        with self._lock:
            self._holds += 1
        try:
            yield
        finally:
            with self._lock:
                self._holds -= 1
