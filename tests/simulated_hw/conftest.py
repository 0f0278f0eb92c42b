"""The gRPC board on a fake clock, for the tests that talk to it through nidaqmx."""

from __future__ import annotations

from collections.abc import Iterator

import grpc
import pytest

from simulated_hw.grpc_server import SimulatedDeviceServer
from tests.simulated_hw.fake_clock import FakeClock


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def paced(clock: FakeClock) -> Iterator[grpc.Channel]:
    """A paced board on a clock the test moves (a read or a wait moves it)."""
    with SimulatedDeviceServer(seed=4, clock=clock.now, sleep=clock.sleep) as srv:
        ch = grpc.insecure_channel(srv.address)
        yield ch
        ch.close()
