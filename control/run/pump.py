"""The oil pump relay and its interlock with the shakers.

`PumpRelay` switches the pump through a relay line of the DAQ (`DaqBackend.set_do`). One owner
holds the relay for a run (`PumpRelay.shakers_running`: the daemon from a run's start to its end,
for a sweep and a programme alike); a sweep engine only asks it whether the pump is on
(`PumpState`). While the relay is held the pump stays as it was when the run started, and this
class is the one place that refuses a switch, with `InterlockError` saying why: off during a
lubricated run (a squeeze film must not be drained while the housing is shaken), on during a dry
run (oil in the film would make dwells wet that the run file records as dry). The pressure side of
the interlock (a lubricated sweep waits, with zero drive, for the inlet pressure to build) lives in
the sweep engine, which owns the acquisition. The film does not empty when the pump stops:
`PumpRelay.drains_for_s` says how long it still drains (``drain_s`` after the switch off), and the
daemon refuses a dry sweep until then, for the same reason as a pump on during a dry run.
A run that switches the pump itself (the flow test) holds the relay as its owner: only its own
switches (``owner=``) go through, every other one is refused until it ends.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Protocol

from control.run.errors import InterlockError
from daq.backend import DaqBackend


class PumpState(Protocol):
    """What a run asks the pump's owner: whether the pump is on (a `PumpRelay` is one)."""

    @property
    def is_on(self) -> bool: ...


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
    drain_s : float
        How long the film takes to drain after the pump goes off [s] (0: at once).
    clock : callable, optional
        Monotonic clock [s] (tests).
    """

    def __init__(
        self,
        backend: DaqBackend,
        name: str = "pump",
        on_change: Callable[[bool, str], None] | None = None,
        drain_s: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not drain_s >= 0:
            raise ValueError(f"drain_s must be >= 0 s, got {drain_s!r}")
        backend.channel_map.relay(name)  # KeyError naming the missing relay
        self._backend = backend
        self.name = name
        self._on_change = on_change
        self._lock = threading.Lock()
        self._on = False
        # what holds the relay (outermost first), with its owner (None: nobody may switch it)
        self._holds: list[tuple[str, object | None]] = []
        self.drain_s = float(drain_s)
        self._clock = clock
        self._off_at: float | None = None  # when it last went from on to off

    @property
    def is_on(self) -> bool:
        """Whether the relay was last switched on."""
        return self._on

    def drains_for_s(self) -> float:
        """How much longer the film drains [s]: 0 when the pump is on (the film is full, not
        draining) or has been off for at least ``drain_s``."""
        if self._on or self._off_at is None:
            return 0.0
        return max(0.0, self.drain_s - (self._clock() - self._off_at))

    @property
    def shakers_active(self) -> bool:
        """Whether a run holds the interlock (its shakers may be moving)."""
        return bool(self._holds)

    def set(self, on: bool, owner: object | None = None) -> None:
        """Switch the pump on or off (switching it to the state it is in is allowed unless a
        run owns the relay). ``owner``: the token of the run that owns the relay, if this is
        its switch (`shakers_running`).

        Raises
        ------
        InterlockError
            On an attempt to switch it while a run holds it: off during a lubricated run, on
            during a dry one, either way during a run that owns it (the flow test).
        """
        with self._lock:
            for what, held_by in self._holds:
                if held_by is not None and held_by is not owner:
                    raise InterlockError(
                        f"pump {self.name!r} cannot be switched by hand during {what}: the test "
                        "switches it itself; abort the test or let it end first")
            fixed = [what for what, held_by in self._holds if held_by is None]
            if fixed and bool(on) != self._on:
                what = fixed[0]
                if on:
                    raise InterlockError(
                        f"pump {self.name!r} cannot be switched on during {what}: its dwells "
                        "are recorded as dry and oil in the film would make them wet; abort "
                        "the run or let it end first"
                    )
                raise InterlockError(
                    f"pump {self.name!r} cannot be switched off while the shakers run "
                    f"({what}): a squeeze film must not be drained while the housing is "
                    "shaken; abort the run or let it end first"
                )
            self._backend.set_do(self.name, bool(on))
            changed = self._on != bool(on)
            if changed and not on:
                self._off_at = self._clock()
            self._on = bool(on)
        if changed and self._on_change is not None:
            self._on_change(self._on, f"pump {self.name!r} switched {'on' if on else 'off'}")

    def switched_off_by_board(self, why: str) -> None:
        """The board turned the relay off by itself (its watchdog expired): the pump is off
        and the film starts to drain, whatever a run holds (``why`` goes to the run log)."""
        with self._lock:
            changed = self._on
            if changed:
                self._on = False
                self._off_at = self._clock()
        if changed and self._on_change is not None:
            self._on_change(False, f"pump {self.name!r} switched off by the board ({why})")

    @contextmanager
    def shakers_running(self, what: str = "", owner: object | None = None) -> Iterator[None]:
        """Hold the interlock for the duration of a run: the pump stays as it is now (on for a
        lubricated run, off for a dry one), or, with an ``owner`` token, only the run's own
        switches (``set(on, owner=token)``) go through. ``what`` names the run in refusals."""
        with self._lock:
            name = what or ("a lubricated run" if self._on else "a dry run")
            entry = (name, owner)
            self._holds.append(entry)
        try:
            yield
        finally:
            with self._lock:
                self._holds.remove(entry)
