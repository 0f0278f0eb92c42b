"""Contract: `NidaqmxBackend`, through the real nidaqmx client and a real loopback socket, reads
back from the simulated NI-DAQmx device server the same rig response as the in-process
`SimulatedBackend` fed the same drive (same RigParams, same seed)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daq.backend import DaqBackend
from daq.channels import ChannelMap, default_channel_map
from daq.nidaqmx_backend import NidaqmxBackend
from rig_model import RigParams
from simulated_hw import SimulatedBackend
from simulated_hw.grpc_server import SimulatedDeviceServer
from tests.daq.conftest import FakeClock, on_server

FS_HZ = 10_000.0
DRIVE_HZ = 25.0  # 400 samples per cycle
DRIVE_V = 2.0  # 100 N at 50 N/V
BLOCK = 1_000
PREFILL_BLOCKS = 20  # 2 s of AO ahead of the generation: margin for a loaded test machine
SEED = 11


def drive_block(k: int, n_ao: int) -> np.ndarray:
    """Block ``k`` of the drive: a sine on shaker_x (row 0), zero elsewhere [V]."""
    t = (np.arange(BLOCK) + k * BLOCK) / FS_HZ
    block = np.zeros((n_ao, BLOCK))
    block[0] = DRIVE_V * np.sin(2 * math.pi * DRIVE_HZ * t)
    return block


def run_sine(backend: DaqBackend, cm: ChannelMap, n_blocks: int) -> np.ndarray:
    """Pump on, prefill, start, then read a block / write a block; returns AI volts."""
    backend.configure(cm)
    backend.set_do("pump", True)
    for k in range(PREFILL_BLOCKS):
        backend.write_ao(drive_block(k, len(cm.ao)))
    backend.start()
    blocks = []
    for k in range(n_blocks):
        blocks.append(backend.read_ai(BLOCK))
        backend.write_ao(drive_block(k + PREFILL_BLOCKS, len(cm.ao)))
    backend.stop()
    backend.close()
    return np.hstack(blocks)


def lockin(x: np.ndarray, first: int, last: int) -> complex:
    """Complex amplitude at DRIVE_HZ over samples [first, last) (whole cycles), eq. 12-13
    convention: x = Re(Z e^{iwt}), t = sample / fs from sample 0."""
    assert ((last - first) * DRIVE_HZ / FS_HZ).is_integer()
    t = np.arange(first, last) / FS_HZ
    return complex(2 * np.mean(x[first:last] * np.exp(-2j * math.pi * DRIVE_HZ * t)))


def lockin_sigma_v(cm: ChannelMap, name: str, params: RigParams, n: int) -> float:
    """Standard deviation of one component of the lock-in estimate from sensor noise and
    16-bit quantisation: white noise of variance s^2 gives 2 s^2 / n per component."""
    ch = cm.ai_channel(name)
    sigma_v = getattr(params.noise, ch.kind.value) * ch.gain_v_per_unit
    lsb = 2 * cm.device.ai_range_v / 2**cm.device.ai_bits
    return math.sqrt(2 * (sigma_v**2 + lsb**2 / 12) / n)


def test_grpc_backend_matches_in_process_simulation_paced() -> None:
    """Paced server (10 kS/s on its clock: a fake clock the host counts on too, moved on as
    the reads wait for their samples), 14 AI channels, 3 s.

    Tolerance: the server's rig runs in chunks set by its clock, so its noise draws differ
    from the in-process run (the physics does not: with the noise switched off the two agree
    sample for sample). Each lock-in estimate then carries independent noise of s per
    component (`lockin_sigma_v`); their difference has sqrt(2) s per component, and we allow
    5 x that on |Z| and on the phase times |Z| (a false alarm once in ~10^6 per check).
    """
    params = RigParams()
    n_blocks = 30
    cm = default_channel_map()
    assert len(cm.ai) >= 13 and cm.sample_rate_hz == FS_HZ
    expected = run_sine(SimulatedBackend(params, seed=SEED), cm, n_blocks)
    clock = FakeClock()
    with SimulatedDeviceServer(params=params, seed=SEED, clock=clock.now,
                               sleep=clock.sleep) as server:
        got = run_sine(NidaqmxBackend(clock=clock.now), on_server(server, cm), n_blocks)
    assert got.shape == expected.shape == (14, n_blocks * BLOCK)

    first, last = int(FS_HZ), n_blocks * BLOCK  # after the first second: 50 whole cycles
    assert_same_response(cm, params, expected, got, ("fx", "x1", "x2", "ax"), first, last)

    # the response is the rig's answer to our drive: 100 N on fx (20 mV/N; shaker corner 1 kHz)
    fx = lockin(got[cm.ai_index("fx")], first, last)
    gain = 1 / math.sqrt(1 + (DRIVE_HZ / params.shaker.bandwidth_hz) ** 2)
    assert abs(fx) == pytest.approx(DRIVE_V * params.shaker.force_per_volt_n * 0.02 * gain,
                                    rel=1e-3)
    x_m = lockin(cm.to_engineering(got)[cm.ai_index("x1")], first, last)
    assert 10e-6 < abs(x_m) < 127e-6  # a real orbit, inside the clearance

    # the pump relay: inlet pressure rises from 0 to the supply pressure (tau 0.5 s)
    p_in = cm.to_engineering(got)[cm.ai_index("p_in")]
    assert abs(p_in[:10].mean()) < 1_000.0
    assert p_in[-1000:].mean() == pytest.approx(params.oil.supply_pressure_pa, rel=0.02)


def assert_same_response(cm: ChannelMap, params: RigParams, expected: np.ndarray,
                         got: np.ndarray, names: tuple[str, ...], first: int, last: int) -> None:
    """The channels ``names`` carry the same response at DRIVE_HZ over samples [first, last):
    amplitude and phase within 5 x the difference of two noisy lock-in estimates."""
    for name in names:
        i = cm.ai_index(name)
        z_exp, z_got = lockin(expected[i], first, last), lockin(got[i], first, last)
        tol = 5 * math.sqrt(2) * lockin_sigma_v(cm, name, params, last - first)
        assert abs(abs(z_got) - abs(z_exp)) < tol, (name, abs(z_got), abs(z_exp), tol)
        phase_diff = math.remainder(np.angle(z_got) - np.angle(z_exp), 2 * math.pi)
        assert abs(phase_diff) * abs(z_exp) < tol, (name, phase_diff, tol / abs(z_exp))


def test_a_host_behind_the_board_catches_up_in_few_reads_and_loses_no_sample() -> None:
    """Issue 21: through gRPC a lab-day daemon read 100 samples a call (and the e-stop with
    each); beside 3 busy loops it fell 10 s behind and the board overflowed (-200279) in every
    run. A host that is late now takes what the board holds in a few calls: after a 0.6 s
    stall, 60 blocks of 100 are 6 gRPC reads or fewer, and the samples are those a host on time
    reads (the rig's response matches the in-process rig's on the same drive). The board and
    the host count on one fake clock: the stall is the clock moved on, not a sleep."""
    params = RigParams()
    cm = default_channel_map()
    expected = run_sine(SimulatedBackend(params, seed=SEED), cm, 30)
    small, n_small = 100, 300  # 30 blocks of 1000 in blocks of 100
    clock = FakeClock()
    with SimulatedDeviceServer(params=params, seed=SEED, clock=clock.now,
                               sleep=clock.sleep) as server:
        be = NidaqmxBackend(clock=clock.now)
        be.configure(on_server(server, cm))
        be.set_do("pump", True)
        for k in range(PREFILL_BLOCKS):
            be.write_ao(drive_block(k, len(cm.ao)))
        be.start()
        calls = []
        read = be._reader.read_many_sample
        be._reader.read_many_sample = lambda out, **kw: calls.append(kw) or read(out, **kw)
        blocks, after_stall = [], None
        for k in range(n_small):
            if k == 100:
                be.feed_watchdog()
                clock.advance(0.6)  # the host stalls (the condition under test)
                after_stall = len(calls)
            blocks.append(be.read_ai(small))
            if k == 159:
                stall_calls = len(calls) - after_stall
            if k % 10 == 9:  # the drive goes on a block of 1000 at a time
                be.write_ao(drive_block(k // 10 + PREFILL_BLOCKS, len(cm.ao)))
        be.stop()
        be.close()
    got = np.hstack(blocks)
    assert got.shape == expected.shape
    assert stall_calls <= 6, stall_calls  # 60 reads of 100 after the stall
    first, last = int(FS_HZ), got.shape[1]
    assert_same_response(cm, params, expected, got, ("fx", "x1"), first, last)


def test_grpc_path_is_lossless_in_fast_mode(fast_server: SimulatedDeviceServer) -> None:
    """Fast mode runs the rig in the same 1000-sample blocks as the in-process backend, so the
    same seed gives the same noise: every AI sample must come back bit for bit (float64 on the
    wire, channel order, AO sample k at AI sample k, relay timing)."""
    cm = default_channel_map()
    expected = run_sine(SimulatedBackend(fast_server.device.params, seed=7), cm, 8)
    got = run_sine(NidaqmxBackend(), on_server(fast_server, cm), 8)
    np.testing.assert_array_equal(got, expected)
