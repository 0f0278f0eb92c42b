"""Fixtures for the nidaqmx backend tests: a simulated NI-DAQmx gRPC device server on loopback
(in this process, port 0), a fake clock for deterministic paced timing, and channel maps."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from daq.channels import ChannelMap, DeviceSpec, default_channel_map
from daq.nidaqmx_backend import NidaqmxBackend
from simulated_hw.grpc_server import SimulatedDeviceServer


class FakeClock:
    """A monotonic clock that only moves when told to (or when the server sleeps on it)."""

    def __init__(self) -> None:
        self._t = 1000.0
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def sleep(self, dt: float) -> None:
        self.advance(max(dt, 0.0))

    def advance(self, dt: float) -> None:
        with self._lock:
            self._t += dt


def on_server(server: SimulatedDeviceServer, cm: ChannelMap | None = None) -> ChannelMap:
    """``cm`` (default: the report's map) pointed at ``server``."""
    return (cm or default_channel_map()).model_copy(update={"grpc_target": server.address})


def with_device(cm: ChannelMap, **spec: object) -> ChannelMap:
    """``cm`` re-validated with a different device description (channels renamed with it)."""
    data = cm.model_dump(mode="json")
    old = cm.device.name
    data["device"] = DeviceSpec(**{**cm.device.model_dump(), **spec}).model_dump(mode="json")
    new = data["device"]["name"]
    for group in ("ai", "ao", "do"):
        for ch in data[group]:
            ch["physical_channel"] = ch["physical_channel"].replace(f"{old}/", f"{new}/", 1)
    return ChannelMap.model_validate(data)


@pytest.fixture
def fast_server() -> Iterator[SimulatedDeviceServer]:
    with SimulatedDeviceServer(seed=7, fast=True) as server:
        yield server


@pytest.fixture
def fake_clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def clocked_server(fake_clock: FakeClock) -> Iterator[SimulatedDeviceServer]:
    """A paced server on the fake clock: time passes only when the test (or a wait) says."""
    with SimulatedDeviceServer(seed=7, clock=fake_clock.now, sleep=fake_clock.sleep) as server:
        yield server


@pytest.fixture
def backend() -> Iterator[NidaqmxBackend]:
    b = NidaqmxBackend(connect_timeout_s=5.0)
    yield b
    b.close()


@pytest.fixture
def clocked_backend(fake_clock: FakeClock) -> Iterator[NidaqmxBackend]:
    """The host for `clocked_server`: it counts on the same fake clock (its read-ahead, AO
    generation estimate), as a host and a board count the same seconds. No watchdog: a test's
    blocking read of a second of samples would let a 1 s watchdog expire, as on a board."""
    b = NidaqmxBackend(connect_timeout_s=5.0, watchdog_timeout_s=None, clock=fake_clock.now)
    yield b
    b.close()
