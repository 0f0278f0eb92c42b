"""The one seam between logic and hardware: the `DaqBackend` protocol.

Life cycle: ``configure(channel_map)`` -> ``write_ao(prefill)`` -> ``start()`` -> loop
{``read_ai(n)``; ``write_ao(block)``} -> ``stop()`` -> ``close()``.

- AI is hardware-timed and continuous; ``read_ai`` returns the next ``n`` samples per channel, in
  volts, shape ``(n_ai, n)``, in channel-map order, with no gap: a lost sample is an exception
  (`daq.errors.DaqBufferOverflowError`), never a silent jump.
- AO streams on the AI sample clock and AI start trigger, so sample ``k`` of the AO stream is
  generated at the instant AI sample ``k`` is taken, in one of two modes (`ao_ring_samples`):
  non-regenerating (None): every sample written plays once, in order; running dry raises
  `daq.errors.DaqUnderflowError` (-200290). Regenerating (a ring of B samples): the board plays
  ring position ``k mod B`` at sample ``k`` for ever, whatever was last written there; the caller
  writes each block at its absolute sample (``write_ao(block, at=k)``) a lead ahead of
  `ao_generated`, and a caller that is late makes the board repeat what the ring held (from one
  ring earlier) instead of underflowing. Before `start` the whole ring is written (the prefill).
  A write is only sure to play if it lands ahead of the generation by at least `ao_min_lead`
  samples (a board's on-board FIFO already holds the samples just ahead of the generation).
- ``set_do`` switches a relay line at once (software-timed).
- ``estop_pressed`` reads the optional emergency-stop input (False without one). ``read_ai``
  raises `daq.errors.EmergencyStopError` once when it finds it pressed (later reads deliver the
  ramp-down); the first ``write_ao`` of a run refuses while it is pressed.
- ``cut_ao`` (a trip) stops the AO already queued from playing: the samples written but not yet
  generated are dropped, and the drives either go on with the next ``write_ao`` from the sample it
  names (the caller writes a fast fade from there) or are at 0 V from that sample on (the
  generation stopped, AO idle output 0 V). A drive is never left holding a non-zero value: where
  neither can be done, nothing is dropped.
- ``board`` names the board (`daq.board.Board`: simulated, or the nidaqmx device and its gRPC
  target), the one description every tool shows; available once configured.
- ``feed_watchdog`` resets the board's watchdog timer, where the backend has one (`read_ai` feeds
  it too); if nobody feeds it, the board turns the relays off and the drives to 0 V by itself.
- ``realtime``: the samples come at the board's clock (a board, a paced simulation), or as fast
  as they are read (the simulated rig's fast mode: a caller then never waits for the clock).

`BackendBase` holds what every backend does the same way (the map, the e-stop that ``read_ai``
raises once per press, the ring's length).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from daq.board import Board
from daq.channels import ChannelMap
from daq.errors import DaqError, EmergencyStopError


@dataclass(frozen=True)
class AoCut:
    """What `DaqBackend.cut_ao` did: the AO samples from ``at`` on (counted from the start of
    the run, = the AI sample each is generated with) will not play. ``resumes``: the next
    ``write_ao`` is generated from sample ``at`` on; otherwise the generation has stopped and
    the drives show 0 V from ``at`` on (later writes are not generated)."""

    at: int
    resumes: bool


@runtime_checkable
class DaqBackend(Protocol):
    """Hardware-timed AI, streaming AO on the same clock, and relay lines."""

    @property
    def channel_map(self) -> ChannelMap: ...

    @property
    def sample_rate_hz(self) -> float: ...

    @property
    def board(self) -> Board:
        """The board this backend drives (`Board.describe` says it in words); once configured."""

    @property
    def realtime(self) -> bool:
        """Samples come at the board's clock (True), or as fast as they are read (False)."""

    def configure(self, channel_map: ChannelMap) -> None:
        """Create the AI, AO and DO tasks for ``channel_map``; nothing starts yet."""

    def start(self) -> None:
        """Start AO (armed on the AI start trigger), then AI. Prefill AO first."""

    @property
    def ao_ring_samples(self) -> int | None:
        """The regenerating AO ring's length [samples], or None for a non-regenerating stream."""

    @property
    def ao_min_lead(self) -> int:
        """How far ahead of the generation a ring write must land to be sure to play [samples]."""

    def write_ao(self, block: np.ndarray, at: int | None = None) -> None:
        """Write AO samples, volts, shape ``(n_ao, n)``. Non-regenerating: queued after the last
        (``at`` must be None or that position). Regenerating: written to ring positions
        ``(at + i) mod B`` (``at`` None: right after the last sample written; ``n <= B``)."""

    def ao_generated(self) -> int:
        """AO samples generated since `start` (DAQmx TotalSampPerChanGenerated); 0 before."""

    def read_ai(self, n: int, timeout_s: float = 10.0) -> np.ndarray:
        """The next ``n`` AI samples per channel, volts, shape ``(n_ai, n)``."""

    def ai_on_host(self) -> int:
        """AI samples a host that fell behind has already taken from the board, which
        `read_ai` hands out without a call or a wait (0 when on time, or where the backend
        never reads ahead)."""

    def set_do(self, name: str, value: bool) -> None:
        """Set the relay line called ``name`` in the channel map."""

    def estop_pressed(self) -> bool:
        """Whether the emergency-stop input reads pressed (False when there is none)."""

    def feed_watchdog(self) -> None:
        """Reset the board's watchdog timer (no-op without one); the daemon calls it while
        idle, `read_ai` during a run."""

    def cut_ao(self) -> AoCut:
        """Stop the AO already queued from playing, at once (see `AoCut`)."""

    def ao_backlog(self) -> int:
        """Samples written to AO but not yet generated: the end of the samples written less
        `ao_generated` (regenerating, negative when the generation has passed the last sample
        written: the ring is repeating)."""

    def stop(self) -> None:
        """Stop the tasks; the last AO samples written stay on the outputs (write zeros first)."""

    def close(self) -> None:
        """Release every task; safe to call twice."""


def ring_samples(ring_s: float, sample_rate_hz: float) -> int:
    """The AO ring of ``ring_s`` seconds in samples (at least one)."""
    return max(int(round(ring_s * sample_rate_hz)), 1)


class BackendBase:
    """What the backends share: the channel map once configured, and the emergency stop that
    `read_ai` raises once per press (`check_estop`). A subclass sets ``_map`` in ``configure``
    and says how the e-stop reads (``estop_pressed``)."""

    #: a board's samples come at its clock; the simulated rig's fast mode says False
    realtime: bool = True

    def __init__(self) -> None:
        self._map: ChannelMap | None = None
        self._estop_latched = False  # read_ai has raised for this press already

    @property
    def channel_map(self) -> ChannelMap:
        if self._map is None:
            raise DaqError("backend not configured: call configure(channel_map) first")
        return self._map

    @property
    def sample_rate_hz(self) -> float:
        return self.channel_map.sample_rate_hz

    def estop_pressed(self) -> bool:
        raise NotImplementedError

    def check_estop(self) -> None:
        """Raise `EmergencyStopError` if the e-stop reads pressed, once per press (the reads
        of the ramp-down go on); a run's first write re-arms it (`rearm_estop`)."""
        if not self._estop_latched and self.estop_pressed():
            self._estop_latched = True
            raise EmergencyStopError(f"emergency stop pressed ({self.estop_where()})")

    def rearm_estop(self) -> None:
        self._estop_latched = False

    def estop_where(self) -> str:
        """The e-stop input in words, for its messages."""
        estop = self.channel_map.estop
        return f"input {estop.name} on {estop.physical_channel}" if estop else "none"
