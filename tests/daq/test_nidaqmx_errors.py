"""Errors through the real nidaqmx client: every DAQ error raised by the simulated device
server reaches the caller as our typed exception carrying the DAQmx code; bad input is
refused with a message naming what is wrong."""

from __future__ import annotations

import socket
import time

import nidaqmx
import numpy as np
import pytest

from daq.channels import default_channel_map
from daq.errors import (
    INPUT_BUFFER_OVERWRITTEN,
    OUTPUT_UNDERFLOW,
    READ_TIMEOUT,
    DaqBufferOverflowError,
    DaqConnectionError,
    DaqError,
    DaqTimeoutError,
    DaqUnderflowError,
)
from daq.nidaqmx_backend import NidaqmxBackend, translate_errors
from simulated_hw.grpc_server import SimulatedDeviceServer
from tests.daq.conftest import FakeClock, on_server, with_device

N_AO = 2


def _prefill_and_start(backend: NidaqmxBackend, n: int = 1_000) -> None:
    backend.write_ao(np.zeros((N_AO, n)))
    backend.start()


# --- errors raised by the device ------------------------------------------------------------
def test_read_timeout_is_typed_and_consumes_nothing(
    clocked_server: SimulatedDeviceServer, fake_clock: FakeClock,
    clocked_backend: NidaqmxBackend
) -> None:
    backend = clocked_backend
    backend.configure(on_server(clocked_server))
    _prefill_and_start(backend, 20_000)
    t0 = fake_clock.now()
    with pytest.raises(DaqTimeoutError) as info:
        backend.read_ai(10_000, timeout_s=0.25)  # needs 1 s at 10 kS/s
    assert info.value.code == READ_TIMEOUT == -200284
    assert "timed out after 0.25 s" in str(info.value)
    assert fake_clock.now() - t0 == pytest.approx(0.25)
    # nothing was consumed: the next read starts at sample 0 and leaves no gap
    block = backend.read_ai(10_000, timeout_s=5.0)
    assert block.shape == (14, 10_000)
    assert clocked_server.device.read_pos == 10_000


def test_reader_falling_behind_raises_overflow_not_a_gap(
    clocked_server: SimulatedDeviceServer, fake_clock: FakeClock
) -> None:
    backend = NidaqmxBackend(buffer_s=1.0, clock=fake_clock.now)  # 10,000 samples a channel
    try:
        backend.configure(on_server(clocked_server))
        _prefill_and_start(backend, 30_000)
        backend.read_ai(1_000)
        fake_clock.advance(1.5)  # the reader stalls for 1.5 s: 15,000 samples arrive
        with pytest.raises(DaqBufferOverflowError) as info:
            backend.read_ai(1_000)
        assert info.value.code == INPUT_BUFFER_OVERWRITTEN == -200279
        assert "input buffer holds 10000" in str(info.value)
        with pytest.raises(DaqBufferOverflowError):  # sticky until the task restarts
            backend.read_ai(1_000)
        backend.stop()
    finally:
        backend.close()


def test_ao_underflow_is_typed(fast_server: SimulatedDeviceServer,
                               backend: NidaqmxBackend) -> None:
    backend.configure(on_server(fast_server))
    _prefill_and_start(backend, 1_000)
    assert backend.ao_backlog() == 1_000
    backend.read_ai(1_000)
    assert backend.ao_backlog() == 0
    backend.read_ai(1_000)  # the generation runs past the last sample written
    with pytest.raises(DaqUnderflowError) as info:
        backend.write_ao(np.zeros((N_AO, 1_000)))
    assert info.value.code == OUTPUT_UNDERFLOW == -200290
    assert "reached sample 1000" in str(info.value)
    # stopping clears the error: the same tasks prefill and run again
    backend.stop()
    _prefill_and_start(backend, 1_000)
    backend.read_ai(1_000)
    backend.write_ao(np.zeros((N_AO, 1_000)))


def test_ao_underflow_in_real_time(clocked_server: SimulatedDeviceServer, fake_clock: FakeClock,
                                   clocked_backend: NidaqmxBackend) -> None:
    backend = clocked_backend
    backend.configure(on_server(clocked_server))
    _prefill_and_start(backend, 2_000)
    backend.read_ai(1_000)
    fake_clock.advance(0.5)  # the writer stalls: 5,000 samples generated, 2,000 written
    with pytest.raises(DaqUnderflowError):
        backend.write_ao(np.zeros((N_AO, 1_000)))


def test_ao_sample_outside_range_names_the_channel(fast_server: SimulatedDeviceServer,
                                                   backend: NidaqmxBackend) -> None:
    backend.configure(on_server(fast_server))
    block = np.zeros((N_AO, 100))
    block[0, 50] = 12.0
    with pytest.raises(DaqError) as info:
        backend.write_ao(block)
    assert info.value.code == -200561
    assert "shaker_x" in str(info.value) and "Dev1/ao0" in str(info.value)


# --- bad input ------------------------------------------------------------------------------
def test_wrong_physical_channel_is_refused(fast_server: SimulatedDeviceServer,
                                           backend: NidaqmxBackend) -> None:
    # the client believes in a 32-channel board; the server's Dev1 has 16
    cm = with_device(default_channel_map(), ai_count=32)
    data = cm.model_dump(mode="json")
    data["ai"][3]["physical_channel"] = "Dev1/ai20"
    cm = on_server(fast_server, type(cm).model_validate(data))
    with pytest.raises(DaqError) as info:
        backend.configure(cm)
    assert info.value.code == -200170
    msg = str(info.value)
    assert "x2" in msg and "Dev1/ai20" in msg and "ai0..ai15" in msg
    assert fast_server.servicer.tasks == {}  # the half-made AI task was cleared


def test_unknown_device_is_refused(fast_server: SimulatedDeviceServer,
                                   backend: NidaqmxBackend) -> None:
    cm = on_server(fast_server, with_device(default_channel_map(), name="Dev2"))
    with pytest.raises(DaqError) as info:
        backend.configure(cm)
    assert info.value.code == -200220
    assert "'Dev2'" in str(info.value)


@pytest.mark.parametrize(("rate_hz", "spec", "code", "words"), [
    (2e6, {"max_rate_hz": 5e6}, -200332, "above the PXIe-6358 maximum of 1.25e+06"),
    (5.0, {"min_rate_hz": 1.0}, -200331, "below the PXIe-6358 minimum of 10"),
])
def test_unsupported_rate_is_refused(fast_server: SimulatedDeviceServer, backend: NidaqmxBackend,
                                     rate_hz: float, spec: dict, code: int, words: str) -> None:
    cm = with_device(default_channel_map(), **spec).model_copy(
        update={"sample_rate_hz": rate_hz})
    with pytest.raises(DaqError) as info:
        backend.configure(on_server(fast_server, cm))
    assert info.value.code == code
    assert words in str(info.value) and "AI sample clock" in str(info.value)


def test_bad_block_shapes_and_counts(fast_server: SimulatedDeviceServer,
                                     backend: NidaqmxBackend) -> None:
    backend.configure(on_server(fast_server))
    with pytest.raises(ValueError, match=r"shape \(2, n>0\)"):
        backend.write_ao(np.zeros((3, 10)))
    with pytest.raises(ValueError, match="n must be positive"):
        backend.read_ai(0)
    with pytest.raises(KeyError, match="no relay named 'fan'"):
        backend.set_do("fan", True)


@pytest.mark.paced
def test_no_server_is_a_connection_error() -> None:
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    backend = NidaqmxBackend(connect_timeout_s=0.3)
    cm = default_channel_map().model_copy(update={"grpc_target": f"127.0.0.1:{port}"})
    t0 = time.monotonic()
    expected = f"no NI gRPC device server answers at 127.0.0.1:{port}"
    with pytest.raises(DaqConnectionError, match=expected):
        backend.configure(cm)
    assert time.monotonic() - t0 < 3.0
    backend.close()


def test_call_the_server_lacks_is_a_connection_error() -> None:
    """An RPC a server does not implement surfaces in nidaqmx as RpcError, not DaqError. The
    simulated board answers every RPC (with the board's DAQmx error where it refuses), so the
    server here is a gRPC server without the NI-DAQmx service: everything is UNIMPLEMENTED."""
    from concurrent import futures

    import grpc

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=1))
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    channel = grpc.insecure_channel(f"127.0.0.1:{port}")
    try:
        unsupported = "not supported by the NI gRPC Device Server"
        with pytest.raises(DaqConnectionError, match=unsupported), translate_errors("creating"):
            nidaqmx.Task("probe", grpc_options=nidaqmx.GrpcSessionOptions(channel, ""))
    finally:
        channel.close()
        server.stop(0).wait()


def test_server_gone_mid_run_is_a_connection_error(backend: NidaqmxBackend) -> None:
    server = SimulatedDeviceServer(fast=True).start()
    try:
        backend.configure(on_server(server))
        _prefill_and_start(backend)
    finally:
        server.stop(grace_s=0)
    with pytest.raises(DaqConnectionError, match="reading 100 AI samples"):
        backend.read_ai(100)
    backend.close()  # nothing left to release: logs, does not raise


# --- life cycle -----------------------------------------------------------------------------
def test_close_is_idempotent_and_clears_every_task(fast_server: SimulatedDeviceServer) -> None:
    backend = NidaqmxBackend()
    backend.configure(on_server(fast_server))
    names = sorted(fast_server.servicer.tasks)
    assert [n.split("-")[1] for n in names] == ["ai", "ao", "do", "watchdog"]
    _prefill_and_start(backend)
    backend.read_ai(500)
    backend.close()
    assert fast_server.servicer.tasks == {}
    backend.close()
    with pytest.raises(DaqError, match="closed"):
        backend.read_ai(10)


def test_stale_server_task_is_never_reattached(fast_server: SimulatedDeviceServer) -> None:
    crashed, fresh = NidaqmxBackend(), NidaqmxBackend()
    try:
        crashed.configure(on_server(fast_server))
        _prefill_and_start(crashed)  # ... and its process dies: tasks stay on the server
        fresh.configure(on_server(fast_server))
        assert len(fast_server.servicer.tasks) == 8  # unique names: no task shared
        fresh.write_ao(np.zeros((N_AO, 1_000)))
        with pytest.raises(DaqError) as info:
            fresh.start()
        assert info.value.code == -50103 and "in use by" in str(info.value)
        # the operator resets the device, as after a crash; then a clean start works
        nidaqmx_reset(fast_server.address)
        assert fast_server.servicer.tasks == {}
        fresh.configure(on_server(fast_server))
        _prefill_and_start(fresh)
        assert fresh.read_ai(1_000).shape == (14, 1_000)
    finally:
        fresh.close()
        crashed.close()


def nidaqmx_reset(address: str) -> None:
    """DAQmxResetDevice through the client, as an operator would."""
    import grpc
    from nidaqmx._grpc_interpreter import GrpcStubInterpreter

    channel = grpc.insecure_channel(address)
    try:
        GrpcStubInterpreter(nidaqmx.GrpcSessionOptions(channel, "")).reset_device("Dev1")
    finally:
        channel.close()


def test_local_driver_missing_is_a_connection_error() -> None:
    """Without grpc_target the backend uses the local NI-DAQmx driver; none is installed here."""
    try:
        nidaqmx.system.System.local().driver_version  # noqa: B018
    except nidaqmx.errors.DaqNotFoundError:
        pass
    else:
        pytest.skip("an NI-DAQmx driver is installed on this machine")
    backend = NidaqmxBackend()
    with pytest.raises(DaqConnectionError, match="NI-DAQmx driver not available"):
        backend.configure(default_channel_map())
    backend.close()
