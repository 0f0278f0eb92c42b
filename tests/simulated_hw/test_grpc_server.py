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
from nidaqmx.constants import AcquisitionType
from nidaqmx.grpc_session_options import SessionInitializationBehavior
from session_pb2 import Session

from daq.channels import default_channel_map
from simulated_hw import SimulatedBackend
from simulated_hw.grpc_server import SimulatedDeviceServer


class _Clock:
    def __init__(self) -> None:
        self.t = 50.0

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += max(dt, 0.0)


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
    stub = pb_grpc.NiDAQmxStub(channel)
    with pytest.raises(grpc.RpcError) as info:
        stub.ReadAnalogF64(pb.ReadAnalogF64Request(
            task=Session(name="wire"), num_samps_per_chan=10, timeout=1.0,
            array_size_in_samps=10))
    err = info.value
    assert err.code() == grpc.StatusCode.UNKNOWN
    metadata = dict(err.trailing_metadata())
    assert metadata == {"ni-error": "-200475", "ni-samps-per-chan-read": "0"}
    assert "not running" in err.details()
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


def test_ao_needs_the_ai_clock_and_no_regeneration(channel: grpc.Channel) -> None:
    task = _task(channel, "ao-own-clock")
    task.ao_channels.add_ao_voltage_chan("Dev1/ao0")
    task.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.CONTINUOUS)
    task.write(np.zeros(100))
    with pytest.raises(nidaqmx.errors.DaqError, match="only on /Dev1/ai/SampleClock"):
        task.start()
    task.close()


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
