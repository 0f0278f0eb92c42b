"""DAQmxTaskControl and the trigger sync type on the simulated PXIe-6358 (issue 22: NI's
ai_multi_task_pxie_ref_clk example): a committed task holds its channels and the AI timing
engine until it is unreserved or cleared, as on the board; the sync type is kept."""

from __future__ import annotations

from collections.abc import Iterator

import grpc
import nidaqmx
import pytest
from nidaqmx.constants import AcquisitionType, SyncType, TaskMode
from nidaqmx.errors import DaqError

from simulated_hw.grpc_server import SimulatedDeviceServer
from tests.simulated_hw.fake_clock import FakeClock


@pytest.fixture
def channel() -> Iterator[grpc.Channel]:
    clock = FakeClock()
    with SimulatedDeviceServer(seed=4, clock=clock.now, sleep=clock.sleep) as srv:
        ch = grpc.insecure_channel(srv.address)
        yield ch
        ch.close()


def _ai(channel: grpc.Channel, physical: str) -> nidaqmx.Task:
    task = nidaqmx.Task(grpc_options=nidaqmx.GrpcSessionOptions(channel, ""))
    task.ai_channels.add_ai_voltage_chan(physical)
    task.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.CONTINUOUS)
    return task


def test_a_committed_task_holds_its_channel_and_the_ai_engine_until_unreserved(
        channel: grpc.Channel) -> None:
    with _ai(channel, "Dev1/ai0") as first, _ai(channel, "Dev1/ai0") as same, \
            _ai(channel, "Dev1/ai1") as other:
        first.control(TaskMode.TASK_COMMIT)
        with pytest.raises(DaqError) as err:
            same.start()
        assert err.value.error_code == -50103
        assert "['Dev1/ai0'] in use by reserved task" in str(err.value)
        with pytest.raises(DaqError) as err:  # another channel: the AI timing engine
            other.start()
        assert err.value.error_code == -50103 and "AI timing engine" in str(err.value)
        first.control(TaskMode.TASK_UNRESERVE)
        same.start()  # free again
        assert len(same.read(number_of_samples_per_channel=10)) == 10


def test_task_control_starts_stops_and_verifies(channel: grpc.Channel) -> None:
    with _ai(channel, "Dev1/ai2") as task:
        task.control(TaskMode.TASK_VERIFY)
        task.control(TaskMode.TASK_START)
        assert len(task.read(number_of_samples_per_channel=5)) == 5
        task.control(TaskMode.TASK_ABORT)
        assert task.is_task_done()


def test_the_sync_type_is_kept_and_reset(channel: grpc.Channel) -> None:
    with _ai(channel, "Dev1/ai3") as task:
        assert task.triggers.sync_type == SyncType.NONE
        task.triggers.sync_type = SyncType.MASTER
        assert task.triggers.sync_type == SyncType.MASTER
        del task.triggers.sync_type
        assert task.triggers.sync_type == SyncType.NONE
