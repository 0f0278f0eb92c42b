"""The regenerating AO ring through the official nidaqmx client against the simulated PXIe-6358
(gRPC, in process, paced on a fake clock): the write position (out_stream.relative_to/offset),
the generation count, a late host, the ramped stop and the trip's cut, as on the board."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from control.run.listener import RecordingListener
from control.run.safety import SafetyLimits, SafetyMonitor
from control.run.stream import DriveStream
from control.signal.synthesis import SineSynthesizer
from daq.nidaqmx_backend import NidaqmxBackend
from simulated_hw.grpc_server import SimulatedDeviceServer

from .conftest import FakeClock, on_server

AMP = np.array([0.6, 0.6j])
FREQ = 20.0


class Generated:
    """What the board's AO terminals of the shaker drives showed, sample by sample (a spy on
    the simulated device's terminals, read as the acquisition runs)."""

    def __init__(self, server: SimulatedDeviceServer, rows: list[int]) -> None:
        self.parts: dict[int, np.ndarray] = {}
        device = server.device
        inner = device._terminals

        def spy(first: int, n: int) -> np.ndarray:
            out = inner(first, n)
            self.parts[first] = out[rows].copy()
            return out

        device._terminals = spy  # type: ignore[method-assign]

    def upto(self, n: int) -> np.ndarray:
        got = np.concatenate([self.parts[k] for k in sorted(self.parts)], axis=1)
        return got[:, :n]


@pytest.fixture
def ring_backend(fake_clock: FakeClock) -> Iterator[NidaqmxBackend]:
    """The host on the board's fake clock: its watchdog feeding (every quarter timeout),
    read-ahead and generation estimate count the same time as the board does."""
    b = NidaqmxBackend(connect_timeout_s=5.0, watchdog_timeout_s=0.8, ao_ring_s=1.0,
                       clock=fake_clock.now)
    yield b
    b.close()


def _stream(server, backend, clock_steps):
    cm = on_server(server)
    backend.configure(cm)
    rows = [server.device.spec.ao_channels().index(a.physical_channel) for a in cm.ao]
    spy = Generated(server, rows)
    fs = cm.sample_rate_hz
    synth = SineSynthesizer(len(cm.ao), fs)
    synth.ramp_to(AMP, FREQ, 0.0)
    listener = RecordingListener()
    stream = DriveStream(backend, synth, SafetyMonitor(SafetyLimits(), cm), listener,
                         int(0.01 * fs), ahead_blocks=3, keep_samples=int(0.04 * fs))
    stream.check_limits = False
    stream.taps.extend(clock_steps)
    return stream, listener, spy, fs


def _ideal(fs: float, n: int) -> np.ndarray:
    ref = SineSynthesizer(2, fs)
    ref.ramp_to(AMP, FREQ, 0.0)
    return ref.next_block(n)


class Stall:
    def __init__(self, clock: FakeClock, at: int, seconds: float) -> None:
        self.clock, self.at, self.seconds, self.done = clock, at, seconds, False

    def __call__(self, first: int, ai: np.ndarray, ao: np.ndarray) -> None:
        if not self.done and first >= self.at:
            self.done = True
            self.clock.advance(self.seconds)


def test_the_ring_is_set_up_on_the_board(clocked_server, ring_backend):
    ring_backend.configure(on_server(clocked_server))
    fs = ring_backend.sample_rate_hz
    assert ring_backend.ao_ring_samples == int(fs)
    task = ring_backend._ao
    from nidaqmx.constants import RegenerationMode, WriteRelativeTo
    assert task.out_stream.regen_mode == RegenerationMode.ALLOW_REGENERATION
    assert task.out_stream.relative_to == WriteRelativeTo.FIRST_SAMPLE
    assert task.out_stream.output_onbrd_buf_size == int(np.ceil(0.002 * fs))
    assert ring_backend.ao_min_lead == int(np.ceil(0.002 * fs)) + int(np.ceil(0.003 * fs))


def test_a_ring_needs_a_watchdog_shorter_than_it():
    with pytest.raises(ValueError, match="watchdog_timeout_s"):
        NidaqmxBackend(watchdog_timeout_s=1.0, ao_ring_s=1.0)
    with pytest.raises(ValueError, match="watchdog_timeout_s"):
        NidaqmxBackend(watchdog_timeout_s=None, ao_ring_s=2.0)


@pytest.mark.parametrize("stall_s", [0.05, 0.3])
def test_a_late_host_through_nidaqmx_plays_the_same_sine(clocked_server, fake_clock,
                                                        ring_backend, stall_s):
    stall = Stall(fake_clock, 0, stall_s)
    stream, listener, spy, fs = _stream(clocked_server, ring_backend, [stall])
    stall.at = int(1.3 * fs)
    stream.start()
    stream.advance_to(int((2.0 + stall_s) * fs))
    n = stream.sample
    recorded = np.concatenate([b[2] for b in listener.blocks], axis=1)
    generated = spy.upto(n)
    np.testing.assert_allclose(generated, _ideal(fs, n), atol=1e-9)
    np.testing.assert_array_equal(recorded, generated)
    assert stream.writer.late_events >= 1
    assert stream.writer.repeated >= stall_s * fs - 4 * stream.block
    stream.shutdown(0.04)


@pytest.mark.parametrize("stall_s", [0.0, 0.25])
def test_abort_through_nidaqmx_ramps_to_zero_within_100_ms(clocked_server, fake_clock,
                                                            ring_backend, stall_s):
    stream, listener, spy, fs = _stream(clocked_server, ring_backend, [])
    stream.start()
    stream.advance_to(int(1.2 * fs))
    if stall_s:
        stream.taps.append(Stall(fake_clock, stream.sample, stall_s))
    abort_at = ring_backend.ao_generated()
    stream.shutdown(0.04)
    generated = spy.upto(stream.sample)
    live = np.flatnonzero(np.any(generated != 0.0, axis=0))
    assert int(live[-1]) + 1 - abort_at <= 0.1 * fs
    sine_step = float(np.max(np.abs(np.diff(_ideal(fs, int(fs)), axis=1))))
    fade_step = 0.6 / (0.04 * fs)
    assert np.max(np.abs(np.diff(generated[:, abort_at - 10:], axis=1))) <= \
        sine_step + fade_step + 1e-12
    recorded = np.concatenate([b[2] for b in listener.blocks], axis=1)
    np.testing.assert_array_equal(recorded, generated)


def test_a_trip_through_nidaqmx_cuts_to_zero_at_the_end_of_its_block(clocked_server,
                                                                     ring_backend):
    stream, listener, spy, fs = _stream(clocked_server, ring_backend, [])
    stream.start()
    stream.advance_to(int(1.2 * fs))
    seen = stream.sample
    stream.shutdown(0.04, cut=True)
    generated = spy.upto(stream.sample)
    assert stream.zero_sample == seen
    assert np.any(generated[:, seen - 10:seen])
    assert not np.any(generated[:, seen:])
    recorded = np.concatenate([b[2] for b in listener.blocks], axis=1)
    np.testing.assert_array_equal(recorded, generated)


def test_a_hung_host_is_stopped_by_the_watchdog_not_by_the_ring(clocked_server, fake_clock,
                                                                ring_backend):
    """A ring repeats for as long as a hung host leaves it: the board's watchdog (0.8 s here,
    on the board's clock) sets the drives to 0 V, and the host learns it at its next call."""
    from daq.errors import DaqWatchdogExpiredError

    stream, listener, spy, fs = _stream(clocked_server, ring_backend, [])
    stream.start()
    stream.advance_to(int(1.2 * fs))
    fed_at = ring_backend.ao_generated()
    ring_backend.feed_watchdog()
    fake_clock.advance(1.5)  # hung for 1.5 s
    with pytest.raises(DaqWatchdogExpiredError):
        stream.advance_to(stream.sample + int(2.0 * fs))
    stream.shutdown(0.04)
    generated = spy.upto(fed_at + int(1.5 * fs))
    expiry = fed_at + int(0.8 * fs)
    assert np.any(generated[:, expiry - 100:expiry - 1])  # the ring played on until then
    assert not np.any(generated[:, expiry + 1:])  # 0 V from the expiry


@pytest.fixture
def clocked_ring(clocked_server: SimulatedDeviceServer,
                 fake_clock: FakeClock) -> Iterator[NidaqmxBackend]:
    """A ring backend configured on a sim-server paced by the fake clock, as a board is by
    its own; the host counts on the same clock (its watchdog feeding, read-ahead and
    generation estimate)."""
    be = NidaqmxBackend(watchdog_timeout_s=0.8, ao_ring_s=1.0, clock=fake_clock.now)
    try:
        be.configure(on_server(clocked_server))
        yield be
    finally:
        be.close()


def test_the_generation_count_is_asked_at_most_every_50_ms_and_never_runs_behind(clocked_ring,
                                                                                 monkeypatch):
    """Through gRPC every question is a round trip; asked every 10 ms block it was a sixth of
    a lab-day daemon's time (py-spy). Between answers the count comes from the host's clock
    and the board's answers of the last second: never below the board's own count read just
    before (a write would land too close), at most 5 ms beyond the one read just after."""
    be = clocked_ring
    fs = be.channel_map.sample_rate_hz
    be.write_ao(np.zeros((len(be.channel_map.ao), int(fs))), at=0)
    be.start()
    out = be._ao.out_stream
    real = type(out).total_samp_per_chan_generated.fget
    asked = [0]

    def counted(stream):
        asked[0] += 1
        return real(stream)

    monkeypatch.setattr(type(out), "total_samp_per_chan_generated", property(counted))
    for k in range(150):  # 1.5 s of 10 ms blocks, a question each, as a stream asks
        before = real(out)
        generated = be.ao_generated()
        after = real(out)
        assert before <= generated <= after + int(0.005 * fs), (k, before, generated, after)
        be.read_ai(100)
        be.feed_watchdog()
    # the first 0.2 s ask every block; then at most every 50 ms: 51 of 150
    assert asked[0] <= 20 + 30 + 1, asked[0]
    be.stop()


def _stalled_stream(be: NidaqmxBackend, fake_clock: FakeClock
                    ) -> tuple[DriveStream, RecordingListener, int, float]:
    """A sine stream on ``be`` (keeping 4 blocks), run 0.3 s, then the host stalls 0.6 s (the
    backend's reads run ahead of the stream): (stream, listener, block, sample rate)."""
    cm = be.channel_map
    fs = cm.sample_rate_hz
    block = int(0.01 * fs)
    synth = SineSynthesizer(len(cm.ao), fs)
    synth.ramp_to(AMP, FREQ, 0.0)
    listener = RecordingListener()
    stream = DriveStream(be, synth, SafetyMonitor(SafetyLimits(), cm), listener,
                         block, ahead_blocks=3, keep_samples=4 * block)
    stream.check_limits = False
    stream.start()
    stream.advance_to(int(0.3 * fs))
    be.feed_watchdog()
    fake_clock.advance(0.6)  # the host stalls (the condition under test)
    return stream, listener, block, fs


def test_a_stream_behind_the_board_catches_up_in_few_cycles(clocked_ring, fake_clock):
    """Issue 21: a lab-day daemon on the nidaqmx path fell 10 s behind the acquisition and
    overflowed (-200279): every 10 ms block cost a cycle of round trips. After a 0.6 s stall the
    stream now takes the blocks the backend read ahead several to a cycle (each one still read,
    checked and recorded in order): the 60 blocks behind in at most 20 cycles."""
    stream, listener, block, fs = _stalled_stream(clocked_ring, fake_clock)
    start, cycles = stream.sample, 0
    while stream.sample < start + int(0.6 * fs):  # the blocks the stall left behind
        stream.cycle()
        cycles += 1
    assert cycles <= 20, cycles  # 60 blocks: 60 cycles before
    stream.advance_to(stream.sample + int(0.6 * fs))
    # every block in order, none lost or doubled
    firsts = [b[0] for b in listener.blocks]
    assert firsts == list(range(0, stream.sample, block))
    stream.shutdown(0.04)


def test_a_window_of_what_was_asked_for_is_kept_however_far_a_catch_up_reads(clocked_ring,
                                                                             fake_clock):
    """Issue 21: on a loaded PC a cycle that catches up reads up to `CATCH_UP_BLOCKS` blocks at
    once, past the sample the caller advanced to; the dwell's lock-in then asked for a window
    ending there and got "window start ... no longer kept" (bench_lab_day, nidaqmx path at load
    12-15: the run failed). What the caller keeps (``keep_samples``) ending at the sample it
    advanced to stays readable."""
    stream, _, block, _ = _stalled_stream(clocked_ring, fake_clock)  # cycles read many blocks
    target = stream.sample + block
    stream.advance_to(target)
    assert stream.sample - target >= 10 * block  # one cycle read well past the target
    ai, _ = stream.window(target - 4 * block, target)
    assert ai.shape[1] == 4 * block
    stream.shutdown(0.04)
