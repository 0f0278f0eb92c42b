"""Where a stream's AO goes: queued in order (a non-regenerating backend) or into the backend's
regenerating ring at its absolute sample, a lead ahead of the generation (`DaqBackend.write_ao`).

With a ring the board never runs dry: a host that answers late makes it repeat what the ring
holds (the drive written one ring earlier) instead of underflowing. The writer keeps its own
mirror of the ring, so it knows what played while it was late; it reads the generation count
before each write and, when the next sequential position is already closer to the generation
than ``margin`` (or behind it), skips forward by whole blocks. The caller advances its
synthesiser over the skipped samples (phase-continuous by absolute sample) and records what
`played` returns for them: the recorded drive is what was generated, and the AI stays gapless.

The one AO stream of every run (`control.run.stream.DriveStream`, a sweep's or a programme's)
writes through one.
"""

from __future__ import annotations

import math

import numpy as np

from daq.backend import DaqBackend


class AoWriter:
    """The AO of one run, written block by block.

    Parameters
    ----------
    backend : DaqBackend
        Configured, not started.
    block : int
        Samples per block (the unit of a skip).
    lead : int
        Samples the writer keeps written ahead of the generation (ring mode): it writes while
        its position is at most ``lead`` ahead, so after a write it is ``lead`` to
        ``lead + block`` ahead.
    """

    def __init__(self, backend: DaqBackend, block: int, lead: int) -> None:
        self.backend = backend
        self.block = block
        self.lead = lead
        self.n_ao = len(backend.channel_map.ao)
        self.ring: int | None = backend.ao_ring_samples
        #: how close to the generation a write may land and still be sure to play [samples]
        self.margin = block + int(backend.ao_min_lead)
        if self.ring is not None and self.ring < lead + 2 * block + self.margin:
            raise ValueError(f"AO ring of {self.ring} samples is too short for a lead of "
                             f"{lead} samples in blocks of {block}")
        self.mirror = np.zeros((self.n_ao, self.ring or 0))
        self.pos = 0  # absolute sample of the next sample this stream writes
        self.generated = 0  # the generation count read last (ring mode)
        #: how often the host was late (had to skip forward), by how much at worst [samples],
        #: and how many samples the ring repeated (played what it held, not what was meant)
        self.late_events = 0
        self.max_late = 0
        self.repeated = 0
        #: the fewest samples written ahead of the generation before a write (negative: the
        #: generation had passed the last sample written), and the sample where that was
        self.min_backlog: int | None = None
        self.min_backlog_at = 0
        self._to_clear: tuple[int, int] | None = None  # live samples to zero once played
        #: without a ring: read the backlog before each write, for the report's underflow
        #: margin (a round trip through gRPC each block)
        self.watch_backlog = True

    @property
    def regenerating(self) -> bool:
        return self.ring is not None

    def prefill(self, data: np.ndarray) -> None:
        """Before the start: ``data`` plays first; ring mode fills the rest of the ring with
        zeros (a late start then plays 0 V, never stale drive)."""
        if self.ring is None:
            self.backend.write_ao(data)
        else:
            full = np.zeros((self.n_ao, self.ring))
            full[:, :data.shape[1]] = data
            self.backend.write_ao(full, at=0)
            self.mirror = full
        self.pos = data.shape[1]

    def late_skip(self, sample: int) -> int:
        """Ring mode: read the generation count and answer how many samples (whole blocks) the
        stream must skip before its next write lands far enough ahead (0: on time). ``sample``
        (the next AI sample to read) only labels the backlog statistic."""
        if self.ring is None:
            if self.watch_backlog:
                self._note_backlog(self.backend.ao_backlog(), sample)
            return 0
        self.generated = self.backend.ao_generated()
        self._note_backlog(self.pos - self.generated, sample)
        need = self.generated + self.margin - self.pos
        if need <= 0:
            return 0
        skip = self.block * math.ceil(need / self.block)
        self.late_events += 1
        self.max_late = max(self.max_late, need)
        self.repeated += skip
        return skip

    def _note_backlog(self, backlog: int, sample: int) -> None:
        if self.min_backlog is None or backlog < self.min_backlog:
            self.min_backlog, self.min_backlog_at = backlog, sample

    def played(self, n: int) -> np.ndarray:
        """What the ring played (or will play: too close to write) at the next ``n`` samples,
        which the stream skips; advances the position."""
        assert self.ring is not None
        k = (self.pos + np.arange(n)) % self.ring
        self.pos += n
        return self.mirror[:, k].copy()

    def wants_write(self) -> bool:
        """Whether the next block should be written now: always without a ring (one per
        cycle); with one, while the position is at most ``lead`` ahead of the generation."""
        return self.ring is None or self.pos <= self.generated + self.lead

    def write(self, block: np.ndarray) -> None:
        """Write ``block`` at the position and advance it."""
        if self.ring is None:
            self.backend.write_ao(block)
        else:
            self.write_at(self.pos, block)
        self.pos += block.shape[1]

    def write_at(self, at: int, data: np.ndarray) -> None:
        """Ring mode: write ``data`` at absolute sample ``at`` without moving the position (a
        fade and the zeros after it)."""
        assert self.ring is not None
        n = min(data.shape[1], self.ring)
        self.backend.write_ao(data[:, :n], at=at)
        self.mirror[:, (at + np.arange(n)) % self.ring] = data[:, :n]

    def fill_ring(self, at: int, data: np.ndarray, urgent: bool = False) -> int:
        """Ring mode: write ``data`` at ``at`` followed by zeros up to the samples the ring will
        play next (the generation read last plus a ring), so that no drive from before is left
        to repeat beyond what is still to play before ``at``; returns the end written. The
        samples ``generated..at`` still hold drive for one ring: `clear_played` zeroes them
        once they have played. ``urgent`` (a stop): ``data`` goes in a write of its own, first,
        and the zeros after it in a second one: through gRPC a whole ring of zeros takes a
        busy host tens of milliseconds to send, and the fade must land before the generation
        reaches ``at``."""
        assert self.ring is not None
        n = self.generated + self.ring - at
        if n < data.shape[1]:
            raise ValueError(f"{data.shape[1]} samples do not fit in the ring from {at}")
        if urgent:
            self.write_at(at, data)
            if n > data.shape[1]:
                self.write_at(at + data.shape[1], np.zeros((self.n_ao, n - data.shape[1])))
        else:
            full = np.zeros((self.n_ao, n))
            full[:, :data.shape[1]] = data
            self.write_at(at, full)
        self._to_clear = (self.generated, at + data.shape[1])
        return at + n

    def clear_played(self) -> None:
        """Once the generation has passed what `fill_ring` left live (the samples before its
        zeros), write zeros there for the next ring: the whole ring is then 0 V."""
        if self._to_clear is None:
            return
        first, last = self._to_clear
        if self.generated >= last:
            assert self.ring is not None
            self.write_at(first + self.ring, np.zeros((self.n_ao, last - first)))
            self._to_clear = None

    def report(self, fs: float) -> str:
        """The lead and how the host kept it, in words."""
        lead_ms = 1e3 * self.lead / fs
        if self.ring is None:
            if self.min_backlog is None:
                return f"AO lead {lead_ms:.0f} ms; no block written after the start"
            return (f"AO lead {lead_ms:.0f} ms; underflow margin "
                    f"{1e3 * self.min_backlog / fs:.1f} ms at the tightest (AI sample "
                    f"{self.min_backlog_at})")
        text = (f"AO ring {self.ring / fs:g} s, lead {lead_ms:.0f} ms; host late "
                f"{self.late_events} times")
        if self.late_events:
            text += (f" (its next sample at worst {1e3 * self.max_late / fs:.1f} ms short of "
                     f"the generation + the {1e3 * self.margin / fs:.0f} ms margin), "
                     f"{self.repeated} samples ({self.repeated / fs:.3f} s) played from the "
                     "ring while it was late")
        if self.min_backlog is not None:
            text += (f"; tightest lead {1e3 * self.min_backlog / fs:.1f} ms (AI sample "
                     f"{self.min_backlog_at})")
        return text
