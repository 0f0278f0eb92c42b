"""The acquisition loop's I/O: synthesise a drive block, check it, write it, read the next AI
block, convert, check, publish. The one AO stream of every run: a sweep's sines, and the
programmes' DC levels (a 0 Hz drive, `control.run.programs.stream.Stream`).

AO streams ahead of the generation by ``ahead_blocks`` blocks, through
`control.run.ao_writer.AoWriter`.
On a regenerating backend (`DaqBackend.ao_ring_samples`) the blocks go into the ring at their
absolute sample and a late host makes the board repeat the ring instead of underflowing: the
stream then skips forward (the synthesiser is phase-continuous by absolute sample) and records
what the ring played. A stop (abort, pause, normal end) rewrites the ring from the generation
plus the writer's margin with the fade and then zeros over a whole ring, so nothing stale can
play again whatever the host does next. A trip does not let the AO queued play: the backend
stops it (`DaqBackend.cut_ao`) and the drives are at 0 V from the first sample not generated
(or, where the backend resumes, fade from it). Samples read are kept for a while
(`DriveStream.window`) so that the lock-in can look back over them.
"""

from __future__ import annotations

import bisect
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from control.run.ao_writer import AoWriter
from control.run.errors import LimitTrip
from control.run.listener import Listener
from control.signal.synthesis import SineSynthesizer
from daq.backend import DaqBackend

log = logging.getLogger(__name__)

#: What the soft limit (`DriveStream.guard`) leaves of the drive.
GUARD_CUT = 0.5
#: The stop budget: an abort has the drives at 0 V this long after it is handled [s].
STOP_S = 0.1
#: Ring mode: a command that has lasted this many blocks has its prediction extended over the
#: rest of the ring at once (commands that come every few blocks, a raise's, are not: the
#: restart's blocks reach far enough), and from then on this many blocks at a time (through
#: gRPC each write is two round trips).
PREDICT_BLOCKS = 8
#: Ring mode: blocks written at once when a new command restarts the prediction. Commands come
#: every block while a step is approached, so the 8 a cycle never got further than 80 ms into
#: the ring and a host late past that heard an earlier drive (or the zeros before the step):
#: 300 ms of the present command at each command keep most late hosts on it (bench_lab_day).
PREDICT_RESTART_BLOCKS = 30
#: A cycle reads at most this many blocks more while the backend holds AI read ahead (a host
#: catching up): 0.25 s of 10 ms blocks.
CATCH_UP_BLOCKS = 25
#: Ring mode: while the caller holds the drive and needs nothing before a later sample (a
#: lock-in window, a recording: `advance_to` ``held``), the ring holds what plays (the
#: prediction), and the last block kept its orbit and loads
#: under a third of the limits (`StreamMonitor.headroom`), a cycle reads up to this many blocks in
#: one backend read, and checks, records and publishes them as one. Through gRPC a read is a
#: round trip whatever its length: one a block was most of a paced daemon's CPU. Every sample is
#: still checked, at most this many blocks after it was taken: a trip's 0 V comes within the
#: 100 ms budget (`control.run.safety.SHUTDOWN_BUDGET_S`) on a board that drops its queue.
HELD_READ_BLOCKS = 5


class StreamMonitor(Protocol):
    """What the stream checks its blocks with: a sweep's `SafetyMonitor` (drive, slew, the
    limits on the AI, contact); a programme's levels need none of it
    (`control.run.programs.stream`)."""

    last_ao: np.ndarray | None
    #: the last AI block checked left room to read several at a time (`HELD_READ_BLOCKS`)
    headroom: bool

    def check_ao(self, block: np.ndarray, first_sample: int) -> None: ...

    def check_ao_after(self, block: np.ndarray, first_sample: int,
                       before: np.ndarray | None) -> None: ...

    def check_ai(self, eng: np.ndarray, first_sample: int) -> None: ...

    def contact(self, eng: np.ndarray, first_sample: int) -> tuple[int, str] | None: ...


@dataclass
class _SynthState:
    values: dict[str, object]


def _snapshot(s: SineSynthesizer) -> _SynthState:
    return _SynthState({k: (v.copy() if isinstance(v, np.ndarray) else v)
                        for k, v in vars(s).items()})


def _restore(s: SineSynthesizer, st: _SynthState) -> None:
    for k, v in st.values.items():
        setattr(s, k, v)


class DriveStream:
    """Block-wise AO/AI streaming with limit checks and a safe shutdown.

    Parameters
    ----------
    backend : DaqBackend
        Configured, not started.
    synth : SineSynthesizer
        The drive generator (its sample counter must be 0: it starts with the run).
    monitor : StreamMonitor
        Checks AO blocks before writing and AI blocks on arrival (a sweep's `SafetyMonitor`).
    listener : Listener
        Receives every block.
    block_samples : int
        Samples per read and per write.
    ahead_blocks : int
        Blocks written ahead of the generation (the prefill).
    keep_samples : int
        How many past samples `window` can reach, ending at the sample advanced to (a cycle
        that catches up may read `CATCH_UP_BLOCKS` beyond it: those are kept too).
    interrupt : callable, optional
        Called after every block (outside shutdown); may raise to stop the caller.
    """

    def __init__(
        self,
        backend: DaqBackend,
        synth: SineSynthesizer,
        monitor: StreamMonitor,
        listener: Listener,
        block_samples: int,
        ahead_blocks: int = 1,
        keep_samples: int = 0,
        interrupt: Callable[[], None] | None = None,
    ) -> None:
        if block_samples < 1:
            raise ValueError(f"block_samples must be >= 1, got {block_samples}")
        if ahead_blocks < 1:
            raise ValueError(f"ahead_blocks must be >= 1, got {ahead_blocks}")
        self.backend = backend
        self.cm = backend.channel_map
        self.synth = synth
        self.monitor = monitor
        self.listener = listener
        self.block = block_samples
        self.ahead_blocks = ahead_blocks
        # one cycle may read `CATCH_UP_BLOCKS` past the sample its caller advanced to: what
        # the caller keeps, ending there, must still be here
        self.keep = max(keep_samples, block_samples) + CATCH_UP_BLOCKS * block_samples
        self.interrupt = interrupt
        self.sample = 0  # next AI sample to be read (= samples read so far)
        self.check_limits = True
        #: called with (first_sample, ai, ao) for every block read, e.g. lock-in accumulators
        self.taps: list[Callable[[int, np.ndarray, np.ndarray], None]] = []
        self._fifo: deque[np.ndarray] = deque()  # AO blocks written, not yet read
        self._states: deque[_SynthState] = deque()  # the synthesiser before each of them
        self._hist: deque[tuple[int, np.ndarray, np.ndarray]] = deque()
        self._hist_len = 0
        self._started = False
        self.zero_sample: int | None = None  # first sample of the final all-zero output
        #: the end of the last samples a late host's ring played other than the present
        #: command's drive (an earlier command beyond the prediction): what was read before it
        #: answered another drive than the synthesiser's (-1: none)
        self.other_drive_end = -1
        #: the soft limit: called with every engineering block read while limits are checked;
        #: a non-empty answer (why) halves the drive at once and is kept in `guard_event`
        #: (first sample of the block, why) until the caller clears it
        self.guard: Callable[[np.ndarray], str] | None = None
        self.guard_event: tuple[int, str] | None = None
        #: the first journal-housing contact seen (sample, message), checked on every block
        self.contact_event: tuple[int, str] | None = None
        #: writes the AO (queued, or into the backend's ring) and measures how the host kept
        #: its lead
        self.writer = AoWriter(backend, block_samples, ahead_blocks * block_samples)
        # ring mode: a copy of the synthesiser running ahead of the lead, whose samples (the
        # current command's continuation) fill the ring up to a ring ahead of the generation,
        # so a late host hears the drive it would have written, not the drive of a ring ago
        self._pred: SineSynthesizer | None = None
        self._pred_end = 0
        self._pred_start = 0  # where the prediction was last restarted (a new command)
        self._pred_prev: np.ndarray | None = None  # the drive before the next predicted block
        # ring mode: what the ring may hold beyond the prediction (earlier commands' drives, or
        # zeros): at most `_ring_amp_v` per channel [V], at `_ring_freq_hz` (NaN: unknown).
        # A command that this does not stay under is predicted over the whole ring at once
        self._ring_amp_v = np.zeros(len(self.cm.ao))
        self._ring_freq_hz = 0.0
        # ring mode: after a prediction over the whole ring, the slots it could not reach (the
        # lead playing then, and the margin behind it): zeroed once played (absolute samples)
        self._wrap_clear: tuple[int, int] | None = None
        # whose drive the AO plays (`claim_drive`): change points (first sample, owner) in the
        # order they play; a claim waiting for its owner's first own command (owner, the
        # synthesiser's revision when claimed); whether the newest owner's drive has played
        self._owners: list[tuple[int, object]] = [(0, None)]
        self._claim: tuple[object, int] | None = None
        self._owner_heard = True

    # --- whose drive plays --------------------------------------------------------------------
    def claim_drive(self, owner: object) -> None:
        """The drive belongs to ``owner`` (a sweep's step) from its first own command on: the
        first command after this one that asks for a drive (a non-zero target). What plays
        before it (the drive before, its fade, zero drive while the orbit rings down) and, on a
        ring, what a late host hears of an earlier drive until ``owner``'s own plays, stays
        with the owner before (`owner_at`)."""
        self._claim = (owner, self.synth.revision)

    def owner_at(self, sample: int) -> object:
        """Whose drive the AO plays at ``sample`` (`claim_drive`; None before any claim)."""
        k = bisect.bisect_right(self._owners, sample, key=lambda c: c[0]) - 1
        return self._owners[max(k, 0)][1]

    def _take_claim(self) -> None:
        """Before a block is synthesised: a waiting claim takes effect at its owner's first
        own command."""
        if self._claim is None:
            return
        owner, revision = self._claim
        if self.synth.revision != revision and bool(np.any(self.synth.target_phasors != 0)):
            self._owners.append((self.synth.sample, owner))
            self._claim = None
            self._owner_heard = False

    def _played_block(self, first: int, as_meant: bool) -> None:
        """The block at ``first`` plays as synthesised (``as_meant``), or the ring plays an
        earlier drive there: before the newest owner's drive has played, that is still the
        owner before's drive, and the owner's drive starts after it."""
        if as_meant:
            self._owner_heard = True
        elif not self._owner_heard and self._owners[-1][0] <= first:
            self._owners[-1] = (first + self.block, self._owners[-1][1])

    def _drop_owners_after(self, sample: int) -> None:
        """The synthesiser was put back to ``sample``: what was claimed beyond it never
        played; its claim waits again."""
        while len(self._owners) > 1 and self._owners[-1][0] > sample:
            self._claim = (self._owners.pop()[1], self.synth.revision)

    @property
    def queued_blocks(self) -> int:
        """AO blocks written (or played by the ring) and not yet read."""
        return len(self._fifo)

    @property
    def min_ao_backlog(self) -> int | None:
        """The fewest AO samples written ahead of the generation before a write (ring mode:
        negative when the generation had passed them)."""
        return self.writer.min_backlog

    @property
    def min_ao_backlog_sample(self) -> int:
        """The AI sample at which `min_ao_backlog` was seen."""
        return self.writer.min_backlog_at

    # --- running ----------------------------------------------------------------------------
    def start(self) -> None:
        """Prefill the AO buffer (zeros from the synthesiser) and start the tasks."""
        blocks = []
        for _ in range(self.ahead_blocks):
            state = _snapshot(self.synth)
            ao = self.synth.next_block(self.block)
            self.monitor.check_ao(ao, self.synth.sample - ao.shape[1])
            self._fifo.append(ao)
            self._states.append(state)
            blocks.append(ao)
        self.writer.prefill(np.concatenate(blocks, axis=1))
        self.backend.start()
        self._started = True

    def _write(self, ao: np.ndarray, state: _SynthState, check: bool) -> None:
        """Write ``ao``, synthesised from ``state`` (kept until the block is read: a trip's
        fade starts from the synthesiser as it was at the first sample not generated)."""
        if check:
            self.monitor.check_ao(ao, self.synth.sample - ao.shape[1])
        if self._predicted(ao.shape[1]):
            self.writer.pos += ao.shape[1]  # the ring holds these samples already
        else:
            self.writer.write(ao)
        self._fifo.append(ao)
        self._states.append(state)

    def cycle(self, upto: int | None = None) -> None:
        """Write the next drive block(s), read the next AI block, publish and check it.

        Without a ring: one block. With one: first, if the host is late, skip the samples the
        ring plays (or is about to) and record what it plays there; then write while the lead
        is short (one block when on time; up to the whole lead after a skip). ``upto``: the
        caller needs nothing before that sample, so a held drive may be read several blocks at
        once up to it (`HELD_READ_BLOCKS`)."""
        self._catch_up()
        restarted = False
        while self.writer.wants_write():
            self._take_claim()
            state = _snapshot(self.synth)
            if self.writer.regenerating and not self._predicted(self.block):
                # a new command: its prediction starts with this block, in the same write
                # (through gRPC a write is two round trips; commands come every block)
                self._predict(with_block=True)
                restarted = True
            ao = self.synth.next_block(self.block)
            try:
                self._write(ao, state, check=True)
            except BaseException:
                _restore(self.synth, state)  # the fade must continue from what was written
                raise
            self._played_block(self.synth.sample - ao.shape[1], as_meant=True)
            if not self.writer.regenerating:
                break
        if self.writer.regenerating and not restarted:
            self._predict()  # extended once a command has lasted a cycle
        self._read_one(check=self.check_limits, blocks=self._held_blocks(upto))
        if self.interrupt is not None:
            self.interrupt()
        # a host behind the board (it read ahead, `ai_on_host`, or the ring's generation is
        # blocks past the reading: the board holds them) takes up to a quarter second of
        # blocks in this cycle: each block still checked, published and recorded, but the AO
        # and the caller's per-cycle work once (through gRPC a cycle costs round trips). One
        # block a cycle never caught up with a host that stalls as often as it reads (the AI
        # buffer overflowed, -200279), and the raises, slowed by the lag, took minutes
        extra = 0
        while extra < CATCH_UP_BLOCKS and len(self._fifo) > 1 and self._behind():
            self._read_one(check=self.check_limits)
            if self.interrupt is not None:
                self.interrupt()
            extra += 1

    def _behind(self) -> bool:
        """The host is behind the board: it read ahead (`ai_on_host`), or the ring's
        generation is blocks past the reading."""
        return (self.backend.ai_on_host() >= self.block
                or self.writer.generated - self.sample >= 2 * self.block)

    def _held_blocks(self, upto: int | None) -> int:
        """How many blocks the next read takes: one, or while the drive is held (the ring holds
        the next ones as predicted), the caller waits for a later sample ``upto`` and the last
        block left `StreamMonitor.headroom`, up to `HELD_READ_BLOCKS`. The blocks beyond the
        lead are queued first (the ring has them already: no write), so that the lead still
        holds when the longer read returns."""
        most = 1 if upto is None else min(HELD_READ_BLOCKS, (upto - self.sample) // self.block)
        if most <= 1 or not self.writer.regenerating or not self.check_limits or \
                not self.monitor.headroom or self.synth.is_ramping or self._behind():
            return 1  # (a host behind the board catches up as it always has: below)
        while len(self._fifo) < most + self.ahead_blocks and self._predicted(self.block):
            self._take_claim()
            state = _snapshot(self.synth)
            ao = self.synth.next_block(self.block)
            self._write(ao, state, check=True)
            self._played_block(self.synth.sample - ao.shape[1], as_meant=True)
        return max(1, min(most, len(self._fifo) - self.ahead_blocks))

    def _predicted(self, n: int) -> bool:
        """Whether the ring already holds the next ``n`` samples as the synthesiser will make
        them: the prediction started from its state with the same commands since."""
        return (self._pred is not None and self._pred.revision == self.synth.revision
                and self._pred_end >= self.writer.pos + n)

    def _predict(self, with_block: bool = False) -> None:
        """Ring mode: extend the prediction (the synthesiser's continuation without a new
        command) up to a ring ahead of the generation less a block and the margin: once the
        command has lasted `PREDICT_BLOCKS` blocks, over the rest of the ring at once, then
        `PREDICT_BLOCKS` blocks at a time. A new command restarts it from the position with
        `PREDICT_RESTART_BLOCKS` at once (one more ``with_block``: the block about to be
        written, which the prediction's write then carries); a predicted block
        over a drive limit ends it until the next command."""
        w = self.writer
        assert w.ring is not None
        self._clear_wrap()
        if self._pred is None or self._pred.revision != self.synth.revision or \
                self._pred_end < w.pos:
            if self._pred is not None and self._pred.revision == self.synth.revision and \
                    self._pred_end < 0:
                return  # over a limit: nothing more until the next command
            self._pred = SineSynthesizer(self.synth.n_channels, self.synth.fs)
            _restore(self._pred, _snapshot(self.synth))
            self._pred_end = self._pred_start = w.pos
            self._pred_prev = self.monitor.last_ao
            target_v = np.abs(self.synth.target_phasors)
            # a ramp's continuation holds the ramp too: its start, its end, or between
            amp_v = np.maximum(np.abs(self.synth.phasors), target_v)
            freq_hz = self.synth.target_freq_hz
            # what a late host hears past the restart's blocks is an earlier command: safe only
            # if it is at this frequency and no larger than this one's end (a raise); after a
            # lower drive or a new frequency the whole ring is the new command's (issue 21:
            # after a step to 20 Hz a 0.5 s stall played the 60 Hz step's 1.97 V of a ring ago
            # and the orbit tripped)
            stale_ok = (not np.any(self._ring_amp_v > 0)) or (
                freq_hz == self._ring_freq_hz and self.synth.freq_hz == freq_hz
                and bool(np.all(self._ring_amp_v <= target_v * (1 + 1e-9) + 1e-12)))
            most = PREDICT_RESTART_BLOCKS + with_block if stale_ok else w.ring // self.block
        else:
            if w.pos - self._pred_start < PREDICT_BLOCKS * self.block:
                return  # a command that may not last: the restart's blocks reach far enough
            most = PREDICT_BLOCKS
            amp_v, freq_hz, stale_ok = self._ring_amp_v, self._ring_freq_hz, True
        limit = w.generated + w.ring - self.block - w.margin
        if most == PREDICT_BLOCKS:
            if limit - self._pred_end < PREDICT_BLOCKS * self.block:
                return  # extended by whole chunks: one write per chunk, not one per block
            most = (limit - self._pred_end) // self.block  # the rest of the ring at once
        start = self._pred_end
        n = min(most, (limit - start) // self.block) * self.block
        if n > 0:
            chunk = self._pred.next_blocks(n // self.block, self.block)
            good = self._checked_length(chunk, start)
            if good:
                w.write_at(start, chunk[:, :good])
                self._pred_prev = chunk[:, good - 1:good]
            self._pred_end = start + good if good == n else -1
        whole = self._pred_end >= 0 and self._pred_end + self.block > limit
        if whole and not stale_ok:
            # the ring holds this command's continuation all round but for the slots of the
            # lead now playing and the margin behind it: zeros there once the lead has played
            self._ring_amp_v, self._ring_freq_hz = amp_v.copy(), freq_hz
            first, last = self._pred_end, start + w.ring
            if self._wrap_clear is not None:  # one still pending: both are zeroed (what a
                # newer prediction reached is skipped, `_clear_wrap`)
                first, last = min(first, self._wrap_clear[0]), max(last, self._wrap_clear[1])
            self._wrap_clear = (first, last)
        elif whole:
            self._ring_amp_v, self._ring_freq_hz = np.maximum(self._ring_amp_v, amp_v), freq_hz
        else:
            self._ring_amp_v = np.maximum(self._ring_amp_v, amp_v)
            self._ring_freq_hz = freq_hz if stale_ok else math.nan

    def _checked_length(self, chunk: np.ndarray, start: int) -> int:
        """How many samples of a predicted ``chunk`` (whole blocks, from ``start``) pass the
        drive limits, block by block as the stream writes them: all of it, or the blocks before
        the first one over a limit. Checked whole first (one check for the chunk, not one a
        block: the prediction is most of a paced daemon's CPU while a step is approached)."""
        try:
            self.monitor.check_ao_after(chunk, start, self._pred_prev)
            return chunk.shape[1]
        except LimitTrip:
            pass
        prev = self._pred_prev
        for k in range(0, chunk.shape[1], self.block):
            blk = chunk[:, k:k + self.block]
            try:
                self.monitor.check_ao_after(blk, start + k, prev)
            except LimitTrip:
                return k
            prev = blk[:, -1:]
        return chunk.shape[1]  # pragma: no cover - the whole chunk failed, so a block does

    def _clear_wrap(self) -> None:
        """Ring mode: zero what a prediction over the whole ring left of the drive before it
        (`_wrap_clear`) once the generation has passed it, beyond any newer prediction."""
        if self._wrap_clear is None:
            return
        first, last = self._wrap_clear
        w = self.writer
        assert w.ring is not None
        if w.generated + w.ring < last:
            return  # the lead written before the prediction is still to play
        if self._pred is not None and self._pred_end >= 0:
            first = max(first, self._pred_end)
        if first < last:
            w.write_at(first, np.zeros((len(self.cm.ao), last - first)))
        self._wrap_clear = None

    def _forget_prediction(self) -> None:
        self._pred = None

    def _catch_up(self) -> None:
        """Ring mode: read the generation; if it has come within the margin of the next
        position, move past it by whole blocks: the synthesiser is advanced over them (so the
        drive keeps its phase) and what the ring plays there is queued for the record."""
        skip = self.writer.late_skip(self.sample)
        if skip:
            self._skip(skip)
        if self.writer.regenerating:
            self.writer.clear_played()

    @property
    def read_lag(self) -> int:
        """How far the reading is behind the writing beyond the lead [samples]: 0 while the
        host keeps up; after a late host's skip, the backlog it still has to read (a command
        given now is seen that much later than the lead says)."""
        return max(self.writer.pos - self.sample - self.ahead_blocks * self.block, 0)

    def generation(self) -> int:
        """The sample the AO is generating now: on a ring the board's count (a late host's
        reads lag it), otherwise the next AI sample to read (the lead keeps them together).
        What a stop's event is stamped with: its 0 V is timed from here."""
        if self.writer.regenerating and self._started:
            try:
                return max(self.backend.ao_generated(), self.sample)
            except Exception:  # noqa: BLE001 - a stamp, never a reason to fail the stop
                log.exception("could not read the AO generation count")
        return self.sample

    def margin_report(self) -> str:
        """The AO lead and how it was kept (the underflow margin, or how often and how late
        the host was and what the ring repeated), in words."""
        return self.writer.report(self.cm.sample_rate_hz)

    def advance_to(self, sample: int, held: bool = False) -> None:
        """Cycle until every sample before ``sample`` has been read. ``held``: the caller holds
        the drive and needs nothing before ``sample`` (a lock-in window, a recording): the
        blocks may be read several at a time (`HELD_READ_BLOCKS`)."""
        while self.sample < sample:
            self.cycle(sample if held else None)

    def _read_one(self, check: bool, blocks: int = 1) -> None:
        """Read the next ``blocks`` blocks in one read; record, publish and check them as one
        (the soft limit block by block)."""
        n = blocks * self.block
        volts = self.backend.read_ai(n)
        eng = self.cm.to_engineering(volts)
        ao = self._fifo.popleft()
        if blocks > 1:
            ao = np.concatenate([ao, *(self._fifo.popleft() for _ in range(blocks - 1))], axis=1)
        for _ in range(min(blocks, len(self._states))):
            self._states.popleft()
        first = self.sample
        self.sample += n
        self._hist.append((first, eng, ao))
        self._hist_len += n
        while self._hist_len - self._hist[0][1].shape[1] >= self.keep:
            old = self._hist.popleft()
            self._hist_len -= old[1].shape[1]
        for tap in list(self.taps):
            tap(first, eng, ao)
        self.listener.on_block(first, eng, ao)
        if self.contact_event is None:
            # contact is a fault whenever it happens, also after a trip
            self.contact_event = self.monitor.contact(eng, first)
        if check:
            self.monitor.check_ai(eng, first)
            if self.guard is not None:
                for k in range(0, n, self.block):
                    why = self.guard(eng[:, k:k + self.block]) if self.guard_event is None else ""
                    if why:
                        self._halve()
                        self.guard_event = (first + k, why)
                        break

    def _halve(self) -> None:
        """The soft limit: halve both drives within a block, from what is generated next (the
        AO already written still plays): the trip level is not reached. A queue longer than the
        lead (a held drive read several blocks at a time) is dropped beyond the generation plus
        the margin first, so the halving plays as soon as it would have with one."""
        if self.writer.regenerating and len(self._fifo) > self.ahead_blocks + 1:
            self._catch_up()
            self._truncate_to_margin()
        self.synth.ramp_to(self.synth.phasors * GUARD_CUT, None,
                           self.block / self.cm.sample_rate_hz)

    @property
    def kept_samples(self) -> int:
        """Past samples held for `window` now (at most ``keep`` plus one block)."""
        return self._hist_len

    def window(self, first: int, last: int) -> tuple[np.ndarray, np.ndarray]:
        """AI (engineering units) and AO samples ``first <= k < last``, already read."""
        if last > self.sample:
            raise ValueError(f"window end {last} not read yet (read up to {self.sample})")
        if not self._hist or first < self._hist[0][0]:
            raise ValueError(f"window start {first} no longer kept")
        ai_parts, ao_parts = [], []
        for b0, eng, ao in self._hist:
            b1 = b0 + eng.shape[1]
            if b1 <= first or b0 >= last:
                continue
            lo, hi = max(first, b0) - b0, min(last, b1) - b0
            ai_parts.append(eng[:, lo:hi])
            ao_parts.append(ao[:, lo:hi])
        return np.concatenate(ai_parts, axis=1), np.concatenate(ao_parts, axis=1)

    # --- stopping ---------------------------------------------------------------------------
    def ramp_down(self, ramp_s: float) -> None:
        """Ramp both drives to zero (normal stop or pause) and keep streaming until they are.

        Ring mode: the whole ramp is written at once, from the generation plus the margin,
        followed by zeros over the rest of the ring, so a host late during the ramp cannot
        make the ring repeat the drive from before it."""
        if self.writer.regenerating:
            self._catch_up()
            self._truncate_to_margin()
        n = self.synth.fade_out(ramp_s)
        end = self.synth.sample + n + self.block * (self.ahead_blocks + 1)
        if self.writer.regenerating and n:
            self._write_fade(n)
        self.advance_to(end)

    def _write_fade(self, n: int) -> None:
        """Ring mode: the next ``n`` samples of the synthesiser (a fade) from the position
        (the generation plus the margin), then zeros over the ring, in one write."""
        ring = self.writer.ring
        assert ring is not None
        at = self.writer.pos
        m = self.block * math.ceil(n / self.block)
        if self.writer.generated + ring - at < m + self.block:
            return  # longer than the ring: written block by block as usual
        parts = []
        for _ in range(m // self.block):
            state = _snapshot(self.synth)
            ao = self.synth.next_block(self.block)
            self.monitor.check_ao(ao, self.synth.sample - self.block)
            self._fifo.append(ao)
            self._states.append(state)
            parts.append(ao)
        self.writer.fill_ring(at, np.concatenate(parts, axis=1))
        self.writer.pos = at + m

    def _truncate_to_margin(self) -> int:
        """Ring mode: drop what was written beyond the generation plus the margin (whole
        blocks), putting the synthesiser back to that sample; returns it."""
        w = self.writer
        at = self.block * math.ceil(max(w.generated + w.margin, self.sample) / self.block)
        index = (at - self.sample) // self.block
        self._forget_prediction()
        if index < len(self._fifo):
            _restore(self.synth, self._states[index])
            self._drop_owners_after(self.synth.sample)
            for _ in range(len(self._fifo) - index):
                self._fifo.pop()
                self._states.pop()
            w.pos = at
            # the slew check goes on from the last sample kept, not from the blocks dropped
            before = self._fifo[-1] if self._fifo else (self._hist[-1][2] if self._hist
                                                         else None)
            self.monitor.last_ao = before
        return w.pos

    def shutdown(self, fade_s: float, cut: bool = False) -> None:
        """Fade both drives to zero, write two blocks of zeros, read out the buffer, stop the tasks.

        ``cut`` (a trip): the AO already queued is not let play out first. The backend drops
        what it has not generated (`DaqBackend.cut_ao`) and the fade starts from the first
        sample dropped, or the drives are at 0 V from there (a board's AO task stopped);
        either way the motion after the trip is read out for as long as the queue and the
        fade would have lasted.

        Never raises: a failure on the way is logged, and the tasks are stopped regardless. If
        reading fails (a stalled acquisition), the fade and the zeros are still written. The
        first sample of the final zeros is kept in `zero_sample`.
        """
        reading = True
        try:
            if self._started:
                at, tail = self._tail(fade_s, cut)
                if not self.writer.regenerating:
                    for ao in tail:
                        self.backend.write_ao(ao)
                elif tail:  # the fade, then zeros over the rest of the ring, in one write
                    self.writer.fill_ring(at, np.concatenate(tail, axis=1), urgent=True)
                while reading and self._fifo:
                    try:
                        self._read_one(check=False)
                    except Exception:
                        log.exception("acquisition failed while ramping down; the fade is "
                                      "written")
                        reading = False
                    if tail and self.writer.regenerating:
                        # once the fade has played, zeros over it too: the whole ring is 0 V
                        # even if the host now stalls past a ring before the task stops
                        self.writer.generated = self.sample
                        self.writer.clear_played()
        except Exception:
            log.exception("error while ramping the drives down; stopping the tasks")
            try:
                if self.writer.regenerating:
                    assert self.writer.ring is not None
                    self.writer.write_at(self.backend.ao_generated() + self.writer.margin,
                                         np.zeros((len(self.cm.ao), self.writer.ring)))
                else:
                    self.backend.write_ao(np.zeros((len(self.cm.ao), self.block)))
            except Exception:
                log.exception("could not write zeros")
        finally:
            try:
                self.backend.stop()
            except Exception:
                log.exception("could not stop the tasks")
            self._started = False

    def _tail(self, fade_s: float, cut: bool) -> tuple[int, list[np.ndarray]]:
        """The end of the stream after a stop: where the AO still to write goes and what it is
        (the fade and the zeros; nothing when a cut stopped the generation), with the queue of
        blocks to read rebuilt to what the outputs will show. Ring mode: a normal stop starts
        from the generation plus the margin (not after the lead), a cut from the sample the
        backend names, past what the host wrote if it was late (the ring played that)."""
        fs = self.cm.sample_rate_hz
        at, resumes = self.synth.sample, True
        if cut:
            done = self.backend.cut_ao()
            if self.writer.regenerating and done.at > self.writer.pos:
                self._skip(done.at - self.writer.pos)  # the ring played it
            at, resumes = min(max(done.at, self.sample), self.synth.sample), done.resumes
            if at < self.synth.sample:
                self._rewind(at)
        elif self.writer.regenerating:  # the fade from the generation plus the margin
            self._catch_up()
            at = self._truncate_to_margin()
        queued = (np.concatenate(list(self._fifo), axis=1) if self._fifo
                  else np.zeros((len(self.cm.ao), 0)))
        kept = queued[:, :at - self.sample]
        new = []
        if resumes:
            n = self.synth.fade_out(fade_s)
            if n:
                new.append(self.synth.next_block(n))
        self.zero_sample = at + sum(a.shape[1] for a in new)
        # at least two blocks of zeros: the run file shows the drives at rest after the fade
        end = self.zero_sample + 2 * self.block
        if cut:  # read the motion out for as long as the queue and the fade would have taken
            end = max(end, self.sample + self.block * (self.ahead_blocks + 1)
                      + math.ceil(fade_s * fs))
        elif self.writer.regenerating:  # the file holds the whole 100 ms stop budget and more
            end = max(end, max(self.sample, self.writer.generated) + math.ceil(STOP_S * fs)
                      + self.block)
        end = self.sample + math.ceil((end - self.sample) / self.block) * self.block
        new.append(np.zeros((len(self.cm.ao), end - self.zero_sample)))
        self.synth.sample = end
        self.writer.pos = end
        tail = np.concatenate([kept, *new], axis=1)
        self._fifo = deque(tail[:, i:i + self.block] for i in range(0, tail.shape[1], self.block))
        self._states.clear()
        return at, (new if resumes else [])

    def _skip(self, n: int) -> None:
        """Move past at least ``n`` samples (whole blocks) the ring plays, as a late host does."""
        for _ in range(math.ceil(n / self.block)):
            self._take_claim()
            self._states.append(_snapshot(self.synth))
            meant = self.synth.next_block(self.block)
            played = self.writer.played(self.block)
            as_meant = bool(np.allclose(played, meant, rtol=0.0, atol=1e-9))
            self._played_block(self.synth.sample - self.block, as_meant)
            if not as_meant:
                self.other_drive_end = self.writer.pos
            self._fifo.append(played)
            # the next block written follows what the ring played, not what was last written
            # (at 150 Hz a 10 ms block is 1.5 cycles: that reference saw a jump of 2x the drive)
            self.monitor.last_ao = played
        self._follow_what_played(self._states[-1], self._fifo[-1])

    def _follow_what_played(self, before: _SynthState, played: np.ndarray) -> None:
        """After a skip: the drive goes on from what the ring played, not from where the
        command would be by now. Commands come every block while a step is approached, and each
        one's prediction reaches only a few blocks into the ring, so a host late past it hears an
        earlier command's drive (or the zeros of the ring-down before the step); jumping from
        there to the present command is a step in the drive (bench_lab_day on a loaded PC:
        3.5 V played, 8 V written next at 150 Hz, 'would slew at 4.5e4 V/s'). The last block
        played is fitted with the synthesiser's own phase over it; where it fits (the same
        frequency: an earlier command or zeros), the drive continues from those phasors and
        ramps to the present command again. Where it does not (a drive from another frequency,
        a ring ago), the synthesiser goes on from zero and the slew check decides."""
        phase = SineSynthesizer(self.synth.n_channels, self.synth.fs)
        unit = np.ones(self.synth.n_channels, dtype=np.complex128)
        basis_rows = []
        for p in (unit, -1j * unit):  # Re(e^{i theta}) = cos, Re(-i e^{i theta}) = sin
            _restore(phase, before)
            phase.ramp_to(p, None, 0.0)
            basis_rows.append(phase.next_block(played.shape[1])[0])
        # the envelope may be ramping within the block: phasors linear in time, evaluated at
        # the next sample (t = 1)
        t = np.arange(played.shape[1]) / played.shape[1]
        basis = np.stack([*basis_rows, basis_rows[0] * t, basis_rows[1] * t], axis=1)
        coef, *_ = np.linalg.lstsq(basis, played.T, rcond=None)
        fitted = (coef[0] + coef[2]) - 1j * (coef[1] + coef[3])
        residual = played.T - basis @ coef
        rms = float(np.sqrt(np.mean(played ** 2)))
        if float(np.sqrt(np.mean(residual ** 2))) > 0.02 * rms + 1e-3:
            log.warning("the ring played a drive at another frequency while the host was "
                        "late; the drive goes on from zero")
            fitted = np.zeros_like(fitted)
        self.synth.resume_from(fitted, self.block / self.cm.sample_rate_hz)

    def _rewind(self, at: int) -> None:
        """Put the synthesiser back to where it was at sample ``at`` (queued, not generated)."""
        self._forget_prediction()
        first = self.synth.sample - self.block * len(self._states)
        index = (at - first) // self.block
        _restore(self.synth, self._states[index])
        self._drop_owners_after(at)
        if at > self.synth.sample:
            self.synth.next_block(at - self.synth.sample)
