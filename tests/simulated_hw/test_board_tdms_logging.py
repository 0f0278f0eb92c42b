"""TDMS logging on the simulated board (issue 22): ``configure_logging`` writes the samples to a
TDMS file on the server's disk, as NI's gRPC Device Server does; LOG_AND_READ logs what the reads
return, LOG what the board acquired."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import grpc
import nidaqmx
import numpy as np
import pytest
from nidaqmx.constants import READ_ALL_AVAILABLE, AcquisitionType, LoggingMode, LoggingOperation
from nidaqmx.errors import DaqError
from nptdms import TdmsFile

from simulated_hw.grpc_server import SimulatedDeviceServer
from tests.simulated_hw.fake_clock import FakeClock


@pytest.fixture
def paced() -> Iterator[grpc.Channel]:
    clock = FakeClock()
    with SimulatedDeviceServer(seed=4, clock=clock.now, sleep=clock.sleep) as srv:
        ch = grpc.insecure_channel(srv.address)
        yield ch
        ch.close()


def _ai(channel: grpc.Channel, samples: int = 100) -> nidaqmx.Task:
    ai = nidaqmx.Task(grpc_options=nidaqmx.GrpcSessionOptions(channel, ""))
    ai.ai_channels.add_ai_voltage_chan("Dev1/ai2", "x_probe")
    ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    ai.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=samples)
    return ai


def test_log_and_read_logs_exactly_what_the_reads_returned(paced: grpc.Channel,
                                                           tmp_path: Path) -> None:
    path = tmp_path / "run.tdms"
    path.write_bytes(b"an older file, replaced")
    ai = _ai(paced)
    ai.in_stream.configure_logging(str(path), LoggingMode.LOG_AND_READ, group_name="rig",
                                   operation=LoggingOperation.CREATE_OR_REPLACE)
    ai.start()
    first = np.array(ai.read(number_of_samples_per_channel=40))
    rest = np.array(ai.read(READ_ALL_AVAILABLE))
    ai.close()
    read = np.hstack([first, rest])
    with TdmsFile.open(path) as tdms:
        group = tdms["rig"]
        assert [c.name for c in group.channels()] == ["x_probe", "Dev1/ai0"]
        assert np.array_equal(group["x_probe"][:], read[0])
        assert np.array_equal(group["Dev1/ai0"][:], read[1])
        assert group["x_probe"].properties["wf_increment"] == pytest.approx(1e-3)
        assert group["x_probe"].properties["unit_string"] == "Volts"


def test_log_only_refuses_reads_and_logs_the_whole_acquisition(paced: grpc.Channel,
                                                               tmp_path: Path) -> None:
    path = tmp_path / "logged.tdms"
    ai = _ai(paced, samples=250)
    ai.in_stream.configure_logging(str(path), LoggingMode.LOG)
    ai.start()
    with pytest.raises(DaqError) as err:
        ai.read(number_of_samples_per_channel=10)
    assert err.value.error_code == -201301
    ai.wait_until_done(timeout=5.0)
    ai.close()
    with TdmsFile.open(path) as tdms:
        (group,) = tdms.groups()
        assert [len(c[:]) for c in group.channels()] == [250, 250]


def test_open_needs_the_file_and_create_refuses_an_existing_one(paced: grpc.Channel,
                                                                 tmp_path: Path) -> None:
    ai = _ai(paced)
    ai.in_stream.configure_logging(str(tmp_path / "missing.tdms"), LoggingMode.LOG_AND_READ,
                                   operation=LoggingOperation.OPEN)
    with pytest.raises(DaqError) as err:
        ai.read(number_of_samples_per_channel=10)
    assert err.value.error_code == -201310
    ai.close()
    existing = tmp_path / "existing.tdms"
    existing.write_bytes(b"")
    ai = _ai(paced)
    ai.in_stream.configure_logging(str(existing), LoggingMode.LOG_AND_READ,
                                   operation=LoggingOperation.CREATE)
    with pytest.raises(DaqError) as err:
        ai.read(number_of_samples_per_channel=10)
    assert err.value.error_code == -201304
    ai.close()


def test_only_buffered_input_tasks_log(paced: grpc.Channel, tmp_path: Path) -> None:
    on_demand = nidaqmx.Task(grpc_options=nidaqmx.GrpcSessionOptions(paced, ""))
    on_demand.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    with pytest.raises(DaqError) as err:
        on_demand.in_stream.configure_logging(str(tmp_path / "a.tdms"), LoggingMode.LOG)
    assert err.value.error_code == -201299
    on_demand.close()
    ao = nidaqmx.Task(grpc_options=nidaqmx.GrpcSessionOptions(paced, ""))
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
    with pytest.raises(DaqError) as err:
        ao.in_stream.configure_logging(str(tmp_path / "a.tdms"), LoggingMode.LOG)
    assert err.value.error_code == -201332
    ao.close()
