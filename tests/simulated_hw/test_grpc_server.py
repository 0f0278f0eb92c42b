"""The simulated NI-DAQmx gRPC device server, driven by the official nidaqmx client (and, for
the wire format, by the raw gRPC stub) over loopback."""

from __future__ import annotations

from collections.abc import Iterator

import grpc
import nidaqmx
import numpy as np
import pytest
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nidaqmx._stubs import nidaqmx_pb2_grpc as pb_grpc
from nidaqmx.constants import AcquisitionType, AOIdleOutputBehavior, Level, RegenerationMode
from nidaqmx.grpc_session_options import SessionInitializationBehavior
from nidaqmx.system.watchdog import WatchdogTask
from nidaqmx.types import DOExpirationState
from session_pb2 import Session

from daq.channels import default_channel_map
from simulated_hw import SimulatedBackend
from simulated_hw.grpc_server import SimulatedDeviceServer
from tests.simulated_hw.fake_clock import FakeClock as _Clock


@pytest.fixture
def server() -> Iterator[SimulatedDeviceServer]:
    with SimulatedDeviceServer(seed=3, fast=True) as srv:
        yield srv


@pytest.fixture
def channel(server: SimulatedDeviceServer) -> Iterator[grpc.Channel]:
    ch = grpc.insecure_channel(server.address)
    yield ch
    ch.close()


def _task(channel: grpc.Channel, name: str = "", behaviour: int = 0) -> nidaqmx.Task:
    options = nidaqmx.GrpcSessionOptions(
        channel, name, initialization_behavior=SessionInitializationBehavior(behaviour))
    return nidaqmx.Task(name, grpc_options=options)


def test_error_wire_format_is_nis(server: SimulatedDeviceServer, channel: grpc.Channel) -> None:
    """status UNKNOWN, trailing metadata ni-error and ni-samps-per-chan-read."""
    task = _task(channel, "wire")
    task.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    task.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                    samps_per_chan=100)
    stub = pb_grpc.NiDAQmxStub(channel)
    with pytest.raises(grpc.RpcError) as info:  # more than the finite acquisition holds
        stub.ReadAnalogF64(pb.ReadAnalogF64Request(
            task=Session(name="wire"), num_samps_per_chan=101, timeout=1.0,
            array_size_in_samps=101))
    err = info.value
    assert err.code() == grpc.StatusCode.UNKNOWN
    metadata = dict(err.trailing_metadata())
    assert metadata == {"ni-error": "-200278", "ni-samps-per-chan-read": "0"}
    assert "only 100 of the finite acquisition's 100 samples are left" in err.details()
    task.close()


def test_channel_names_and_the_attribute_heavy_read_path(channel: grpc.Channel) -> None:
    """Names as the client derives them; task.read() (channel type/measurement attributes)."""
    task = _task(channel, "names")
    task.ai_channels.add_ai_voltage_chan("Dev1/ai0:2", name_to_assign_to_channel="probe",
                                         min_val=-5.0, max_val=5.0)
    task.ai_channels.add_ai_voltage_chan("Dev1/ai15")
    assert task.channel_names == ["probe0", "probe1", "probe2", "Dev1/ai15"]
    assert task.name == "names"
    task.timing.cfg_samp_clk_timing(2_000.0, sample_mode=AcquisitionType.CONTINUOUS)
    assert task.timing.samp_clk_rate == 2_000.0
    task.start()
    data = np.array(task.read(number_of_samples_per_channel=200))
    assert data.shape == (4, 200)
    # ai0 carries the X load cell at rest (0 V + noise); ai15 is not wired: within 2 LSB of 0
    lsb = 20 / 2**16
    assert np.abs(data[3]).max() <= 4 * lsb
    assert np.abs(data[0]).max() < 0.01
    task.close()


def test_session_initialisation_behaviours(channel: grpc.Channel) -> None:
    first = _task(channel, "shared", behaviour=1)
    with pytest.raises(nidaqmx.errors.DaqError) as info:
        _task(channel, "shared", behaviour=1)  # INITIALIZE_SERVER_SESSION: must be new
    assert info.value.error_code == -200089
    attached = _task(channel, "shared", behaviour=0)  # AUTO attaches
    first.ai_channels.add_ai_voltage_chan("Dev1/ai1")
    assert attached.channel_names == ["Dev1/ai1"]
    with pytest.raises(nidaqmx.errors.DaqError) as info:
        _task(channel, "nobody", behaviour=2)  # ATTACH_TO_SERVER_SESSION: must exist
    assert info.value.error_code == -200088
    first.close()


def test_relay_switches_at_the_sample_it_was_set(server: SimulatedDeviceServer) -> None:
    """Pump on after 3000 samples: the in-process backend doing the same gives the same
    samples, bit for bit, so the relay acted at the same sample index."""
    from daq.nidaqmx_backend import NidaqmxBackend

    def run(backend) -> np.ndarray:
        backend.configure(cm)
        backend.write_ao(np.zeros((2, 6_000)))
        backend.start()
        first = backend.read_ai(1_000), backend.read_ai(1_000), backend.read_ai(1_000)
        backend.set_do("pump", True)
        rest = backend.read_ai(1_000), backend.read_ai(1_000), backend.read_ai(1_000)
        backend.close()
        return np.hstack(first + rest)

    cm = default_channel_map()
    expected = run(SimulatedBackend(server.device.params, seed=3))
    cm = cm.model_copy(update={"grpc_target": server.address})
    got = run(NidaqmxBackend())
    np.testing.assert_array_equal(got, expected)
    p_in = cm.to_engineering(got)[cm.ai_index("p_in")]
    assert np.abs(p_in[:3_000]).max() < 200.0  # off: noise only (30 Pa rms)
    assert p_in[3_900:4_000].mean() > 2_000.0  # on: rising with tau 0.5 s


def test_paced_data_arrives_with_the_clock() -> None:
    clock = _Clock()
    with SimulatedDeviceServer(clock=clock.now, sleep=clock.sleep) as srv:
        ch = grpc.insecure_channel(srv.address)
        try:
            task = _task(ch, "paced")
            task.ai_channels.add_ai_voltage_chan("Dev1/ai0:1")
            task.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.CONTINUOUS)
            task.start()
            assert task.in_stream.avail_samp_per_chan == 0
            clock.t += 0.25
            assert task.in_stream.avail_samp_per_chan == 2_500
            t0 = clock.t
            task.read(number_of_samples_per_channel=5_000)  # waits 0.25 s more
            assert clock.t - t0 == pytest.approx(0.25)
            task.close()
        finally:
            ch.close()


def _options(channel: grpc.Channel) -> nidaqmx.GrpcSessionOptions:
    return nidaqmx.GrpcSessionOptions(channel, "")


def test_regenerating_ao_on_its_own_clock_is_sampled_by_ai(channel: grpc.Channel) -> None:
    """nidaqmx's defaults: regeneration allowed, AO on its own (onboard) clock. The AI reads
    the terminal back through the internal channel: the buffer plays in a loop; a 1 kS/s AO
    holds each sample for 10 AI samples at 10 kS/s."""
    opts = _options(channel)
    ramp = np.arange(7) / 10.0  # 7 samples: the loop is not a divisor of the read
    with nidaqmx.Task(grpc_options=opts) as ao, nidaqmx.Task(grpc_options=opts) as ai:
        ao.ao_channels.add_ao_voltage_chan("Dev1/ao0:1")
        ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.CONTINUOUS)
        ao.write(np.vstack([ramp, -ramp]))
        ao.start()
        ai.ai_channels.add_ai_voltage_chan("Dev1/_ao0_vs_aognd")
        ai.ai_channels.add_ai_voltage_chan("Dev1/_ao1_vs_aognd")
        ai.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.FINITE,
                                      samps_per_chan=1_400)
        x, y = np.array(ai.read(nidaqmx.constants.READ_ALL_AVAILABLE))
        assert ai.is_task_done()
        held = x.reshape(140, 10)  # AI sample k sees AO sample floor(k / 10)
        assert np.all(held == held[:, :1])
        np.testing.assert_array_equal(held[:, 0], np.tile(ramp, 20))
        np.testing.assert_array_equal(y, -x)
        assert ao.out_stream.total_samp_per_chan_generated == 141  # the AI end is sample 140
        assert not ao.is_task_done()  # continuous: runs until stopped


def test_finite_ao_ends_in_its_idle_state(channel: grpc.Channel) -> None:
    opts = _options(channel)
    for idle, expect in ((AOIdleOutputBehavior.MAINTAIN_EXISTING_VALUE, 2.0),
                         (AOIdleOutputBehavior.ZERO_VOLTS, 0.0)):
        with nidaqmx.Task(grpc_options=opts) as ao:
            ao.ao_channels.add_ao_voltage_chan("Dev1/ao1")
            ao.ao_channels.all.ao_idle_output_behavior = idle
            assert ao.ao_channels.all.ao_idle_output_behavior == idle  # remembered
            ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                          samps_per_chan=300)
            ao.write(np.linspace(0.0, 2.0, 100), auto_start=False)  # looped 3 times
            ao.start()
            ao.wait_until_done(timeout=1.0)
            assert ao.is_task_done()
            assert ao.out_stream.total_samp_per_chan_generated == 300
            with nidaqmx.Task(grpc_options=opts) as ai:  # software-timed read
                ai.ai_channels.add_ai_voltage_chan("Dev1/_ao1_vs_aognd")
                assert ai.read() == expect


def test_non_regenerating_ao_on_its_own_clock_underflows_to_its_idle_state(
        channel: grpc.Channel) -> None:
    opts = _options(channel)
    with nidaqmx.Task(grpc_options=opts) as ao, nidaqmx.Task(grpc_options=opts) as ai:
        ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
        ao.ao_channels.all.ao_idle_output_behavior = AOIdleOutputBehavior.ZERO_VOLTS
        ao.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.CONTINUOUS)
        ao.out_stream.regen_mode = RegenerationMode.DONT_ALLOW_REGENERATION
        ao.write(np.full(500, 3.0))
        ao.start()
        ai.ai_channels.add_ai_voltage_chan("Dev1/_ao0_vs_aognd")
        ai.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.CONTINUOUS)
        ai.start()
        x = np.array(ai.read(1_000))
        np.testing.assert_array_equal(x[:500], 3.0)
        np.testing.assert_array_equal(x[500:], 0.0)  # ran dry at sample 500: 0 V
        with pytest.raises(nidaqmx.errors.DaqError) as info:
            ao.write(np.zeros(100))
        assert info.value.error_code == -200290


def test_what_the_board_refuses(channel: grpc.Channel) -> None:
    opts = _options(channel)
    with nidaqmx.Task(grpc_options=opts) as ao:
        ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
        ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                      samps_per_chan=10)
        with pytest.raises(nidaqmx.errors.DaqError) as info:
            ao.start()
        assert info.value.error_code == -200462  # nothing written
    with nidaqmx.Task(grpc_options=opts) as ai:
        ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
        ai.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.CONTINUOUS)
        ai.start()
        with nidaqmx.Task(grpc_options=opts) as other:  # one AI converter
            other.ai_channels.add_ai_voltage_chan("Dev1/ai1")
            with pytest.raises(nidaqmx.errors.DaqError) as info:
                other.read()
            assert info.value.error_code == -50103
        with pytest.raises(nidaqmx.errors.DaqError) as info:
            ai.wait_until_done(timeout=0.01)
        assert info.value.error_code == -200560  # continuous: never done


def test_a_plain_watchdog_task(server: SimulatedDeviceServer, channel: grpc.Channel) -> None:
    """nidaqmx.system.WatchdogTask as a user writes it; the server expires it on its own."""
    opts = _options(channel)
    with nidaqmx.Task(grpc_options=opts) as do:
        do.do_channels.add_do_chan("Dev1/port0/line0")
        do.write(True)
        with WatchdogTask("Dev1", "wdt", timeout=0.05, grpc_options=opts) as wdt:
            wdt.cfg_watchdog_do_expir_states([DOExpirationState("Dev1/port0/line0",
                                                                Level.LOW)])
            assert wdt.timeout == 0.05
            wdt.start()
            (watchdog,) = server.device.watchdogs()
            assert watchdog.expired_event.wait(timeout=5.0)
            assert wdt.expired
            assert do.read() is False  # the line was pulled low
            with pytest.raises(nidaqmx.errors.DaqError) as info:
                wdt.reset_timer()
            assert info.value.error_code == -200644
            with pytest.raises(nidaqmx.errors.DaqError) as info:
                do.write(True)
            assert info.value.error_code == -200678
            wdt.clear_expiration()
            do.write(True)
            assert do.read() is True
        with pytest.raises(nidaqmx.errors.DaqError) as info:
            WatchdogTask("Dev1", "bad", timeout=0.0, grpc_options=opts)
        assert info.value.error_code == -200668


def test_do_write_through_task_write(server: SimulatedDeviceServer,
                                     channel: grpc.Channel) -> None:
    task = _task(channel, "relay")
    task.do_channels.add_do_chan("Dev1/port0/line0")
    task.write(True)  # auto-starts a software-timed task
    assert server.device.lines == {"Dev1/port0/line0": True}
    task.write(False)
    assert server.device.lines == {"Dev1/port0/line0": False}
    task.close()


def test_reset_device_clears_tasks(server: SimulatedDeviceServer, channel: grpc.Channel) -> None:
    task = _task(channel, "left-behind")
    task.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    assert "left-behind" in server.servicer.tasks
    nidaqmx.system.Device("Dev1", grpc_options=nidaqmx.GrpcSessionOptions(channel, "")) \
        .reset_device()
    assert server.servicer.tasks == {}
    with pytest.raises(nidaqmx.errors.DaqError) as info:
        task.close()
    assert info.value.error_code == -200088


def test_regenerating_writes_at_the_write_position(channel: grpc.Channel) -> None:
    """out_stream.relative_to FIRST_SAMPLE + offset place a write in a running regenerating
    buffer (as sfdrig's AO ring does); the on-board buffer size can be shrunk; bad values are
    -200077 and attributes the board lacks still -200197."""
    from nidaqmx.constants import WriteRelativeTo
    from nidaqmx.errors import DaqError

    opts = _options(channel)
    loop = np.zeros((2, 10))
    with nidaqmx.Task(grpc_options=opts) as ao, nidaqmx.Task(grpc_options=opts) as ai:
        ao.ao_channels.add_ao_voltage_chan("Dev1/ao0:1")
        ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.CONTINUOUS)
        out = ao.out_stream
        assert out.regen_mode == RegenerationMode.ALLOW_REGENERATION
        assert out.output_onbrd_buf_size == 8191 // 2
        out.output_onbrd_buf_size = 20
        assert out.output_onbrd_buf_size == 20
        with pytest.raises(DaqError) as err:
            out.output_onbrd_buf_size = 9000
        assert err.value.error_code == -200077
        out.relative_to = WriteRelativeTo.FIRST_SAMPLE
        out.offset = 0
        ao.write(loop)
        ao.start()
        out.offset = 7
        ao.write(np.array([[1.0, 2.0, 3.0, 4.0, 5.0], [-1.0, -2.0, -3.0, -4.0, -5.0]]))
        assert out.relative_to == WriteRelativeTo.FIRST_SAMPLE and out.offset == 7
        with pytest.raises(DaqError) as err:
            out._interpreter.set_write_attribute_int32(out._handle, 0x190C, 12345)
        assert err.value.error_code == -200077
        with pytest.raises(DaqError) as err:
            _ = out.wait_mode  # a write attribute the simulated board does not have
        assert err.value.error_code == -200197
        out.offset = 10  # outside the 10-sample buffer
        with pytest.raises(DaqError) as err:
            ao.write(loop)
        assert err.value.error_code == -200077
        ai.ai_channels.add_ai_voltage_chan("Dev1/_ao0_vs_aognd")
        ai.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                      samps_per_chan=30)
        x = np.array(ai.read(nidaqmx.constants.READ_ALL_AVAILABLE))
        generated = ao.out_stream.total_samp_per_chan_generated
    # positions 7, 8, 9, 0, 1 of the loop now hold 1..5 (the write wrapped); AO sample k plays
    # position k mod 10
    loop_now = np.array([4.0, 5.0, 0, 0, 0, 0, 0, 1.0, 2.0, 3.0])
    first = generated - 31  # the count is one past the last AO sample the AI saw (above)
    # (the AI's first sample sees the AO sample generated before the AI started: skip it)
    np.testing.assert_array_equal(x[1:], loop_now[np.arange(first + 1, first + 30) % 10])
