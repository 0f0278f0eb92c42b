"""The waveform API over gRPC (issue 22): ``read_waveform`` and ``write(AnalogWaveform |
DigitalWaveform)`` carry the same samples as the plain reads and writes, with the board's
timing (t0 on the wall clock, dt the sample clock's period) and channel names."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import grpc
import numpy as np
import pytest
from nidaqmx.constants import AcquisitionType, LineGrouping
from nidaqmx.errors import DaqError
from nitypes.waveform import AnalogWaveform, DigitalWaveform

from tests.simulated_hw.fake_clock import FakeClock
from tests.simulated_hw.grpc_board import task_on

_task = task_on  # clock and paced: tests/simulated_hw/conftest.py


def test_an_analog_waveform_written_is_what_the_terminal_then_reads(paced: grpc.Channel,
                                                                    clock: FakeClock) -> None:
    ao = _task(paced)
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao1")
    assert ao.write(AnalogWaveform.from_array_1d([0.5, 1.25], np.float64), auto_start=True) == 2
    ai = _task(paced)
    ai.ai_channels.add_ai_voltage_chan("Dev1/_ao1_vs_aognd", "readback")
    ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    ai.timing.cfg_samp_clk_timing(2_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=40)
    before = datetime.now(UTC)
    waves = ai.read_waveform(number_of_samples_per_channel=40)
    assert [w.channel_name for w in waves] == ["readback", "Dev1/ai0"]
    assert waves[0].units == "Volts"
    assert np.array_equal(waves[0].scaled_data, np.full(40, 1.25))  # the last sample written
    assert np.all(np.abs(waves[1].scaled_data) < 0.01)  # the fx load cell at rest
    assert waves[0].timing.sample_interval == timedelta(microseconds=500)
    # t0 is the first sample's wall-clock time: the read took 20 ms of the board's clock
    start = waves[0].timing.start_time
    assert before - timedelta(seconds=1) <= start <= datetime.now(UTC)
    ai.close()
    ao.close()


def test_a_finite_analog_waveform_is_generated_on_its_clock(paced: grpc.Channel,
                                                           clock: FakeClock) -> None:
    ao = _task(paced)
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
    ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=500)
    wave = AnalogWaveform.from_array_1d(np.linspace(0.0, 2.0, 500), np.float64)
    assert ao.write(wave, auto_start=True) == 500
    t0 = clock.t
    ao.wait_until_done(timeout=5.0)
    assert clock.t - t0 == pytest.approx(0.5, abs=0.002)
    assert ao.out_stream.total_samp_per_chan_generated == 500
    with pytest.raises(DaqError) as err:  # outside the channel's +/-10 V
        ao.write(AnalogWaveform.from_array_1d(np.full(500, 11.0), np.float64))
    assert err.value.error_code == -200561
    ao.close()


def test_a_digital_waveform_drives_its_lines_and_reads_back_line_by_line(
        paced: grpc.Channel) -> None:
    do = _task(paced)
    do.do_channels.add_do_chan("Dev1/port0/line0:3",
                               line_grouping=LineGrouping.CHAN_FOR_ALL_LINES)
    written = DigitalWaveform.from_port([0b1010], mask=0b1111)
    assert do.write(written, auto_start=True) == 1
    assert do.read() == 0b1010
    back = do.read_waveform(number_of_samples_per_channel=1)
    assert [int(s.data[0]) for s in back.signals] == [0, 1, 0, 1]
    assert [s.name for s in back.signals] == [f"Dev1/port0/line{i}" for i in range(4)]
    with pytest.raises(DaqError) as err:  # 8 signals for a channel of 4 lines
        do.write(DigitalWaveform.from_port([0xFF], mask=0xFF), auto_start=True)
    assert err.value.error_code == -200524
    do.close()


def test_a_di_waveform_reads_the_pull_down_on_the_di_clock(paced: grpc.Channel,
                                                           clock: FakeClock) -> None:
    di = _task(paced)
    di.di_channels.add_di_chan("Dev1/port0/line0:7",
                               line_grouping=LineGrouping.CHAN_FOR_ALL_LINES)
    di.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=50)
    t0 = clock.t
    wave = di.read_waveform(number_of_samples_per_channel=50)
    assert clock.t - t0 == pytest.approx(0.05, abs=0.002)
    assert wave.sample_count == 50 and wave.signal_count == 8
    assert not wave.data.any()  # nothing drives them: the pull-down
    assert wave.timing.sample_interval == timedelta(milliseconds=1)
    di.close()
