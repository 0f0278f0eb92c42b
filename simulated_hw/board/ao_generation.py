"""`AoStream`: the samples of one AO generation, as the board plays them (its AO and DO tasks,
`simulated_hw.board.ao_stream`; the in-process `simulated_hw.backend.SimulatedBackend` is an
adapter over the same board)."""

from __future__ import annotations

import numpy as np


class AoStream:
    """One AO generation's samples, in the order they play: the buffer written and not yet
    generated (non-regenerating: chunks taken once, in order) or the loop a regenerating
    generation plays (position ``k mod size`` at sample ``k``), the count generated and the
    last value generated. The board's AO tasks generate through it (`ao_stream.take`,
    `ao_stream.skip`)."""

    def __init__(self, loop: np.ndarray | None = None) -> None:
        self.chunks: list[np.ndarray] = []  # non-regenerating: written, not yet generated
        self.queued = 0  # samples in ``chunks``
        self.written = 0  # samples ever written
        self.generated = 0  # samples generated since the start
        self.last: np.ndarray | None = None  # last value generated, per channel [V]
        self.loop = loop  # regenerating: the buffer played in a loop

    def queue(self, block: np.ndarray) -> None:
        """Append ``block`` (n_ch, n) to the samples to generate in order."""
        self.chunks.append(block.copy())
        self.queued += block.shape[1]
        self.written += block.shape[1]

    def overwrite(self, block: np.ndarray, position: int) -> None:
        """Write ``block`` into the loop from ``position`` on (modulo its size; a block longer
        than the loop leaves its last ``size`` samples)."""
        assert self.loop is not None
        size = self.loop.shape[1]
        idx = (position + np.arange(block.shape[1])) % size
        self.loop[:, idx[-size:]] = block[:, -size:]
        self.written += block.shape[1]

    def freeze(self) -> None:
        """The samples queued so far become the loop (a regenerating task's start)."""
        if self.chunks:
            self.loop = np.concatenate(self.chunks, axis=1)
            self.chunks, self.queued = [], 0

    def take_into(self, out: np.ndarray) -> int:
        """Generate the next samples into ``out`` (n_ch, n), from its first column on, up to
        the end of the samples queued; returns how many (the caller says what the terminals
        show for the rest)."""
        limit = out.shape[1]
        got = 0
        if self.loop is not None:
            out[:, :limit] = self.loop[:, (self.generated + np.arange(limit)) % self.loop.shape[1]]
            got = limit
        else:
            while got < limit and self.chunks:
                chunk = self.chunks[0]
                k = min(limit - got, chunk.shape[1])
                out[:, got:got + k] = chunk[:, :k]
                if k == chunk.shape[1]:
                    self.chunks.pop(0)
                else:
                    self.chunks[0] = chunk[:, k:]
                got += k
            self.queued -= got
        self.generated += got
        if got:
            self.last = out[:, got - 1].copy()
        return got

    def discard(self) -> None:
        """Drop the samples not generated and the loop (a stop; the counts stay)."""
        self.chunks, self.queued, self.loop = [], 0, None

    def keep_queued(self, keep: int) -> None:
        """Drop all but the first ``keep`` samples queued (a cut of what is not generated)."""
        dropped = self.queued - max(keep, 0)
        while dropped > 0:
            tail = self.chunks[-1]
            if tail.shape[1] <= dropped:
                self.chunks.pop()
                dropped -= tail.shape[1]
                self.queued -= tail.shape[1]
            else:
                self.chunks[-1] = tail[:, :tail.shape[1] - dropped]
                self.queued -= dropped
                dropped = 0
