"""The simulated board behaves as a PXIe-6358 where generic nidaqmx programs rely on it (issue
22): the rig keeps moving between tasks, the AO FIFO, hardware-timed digital I/O, ports, events,
sample-rate coercion, and refusals as DaqError with the board's code."""

from __future__ import annotations

import threading

import grpc
import numpy as np
import pytest
from nidaqmx.constants import AcquisitionType, LineGrouping, RegenerationMode
from nidaqmx.errors import DaqError

from daq import default_channel_map
from rig_model import RigParams
from simulated_hw.grpc_server import SimulatedDeviceServer
from tests.simulated_hw.fake_clock import FakeClock as _Clock
from tests.simulated_hw.grpc_board import task_on

_task = task_on  # clock and paced: tests/simulated_hw/conftest.py


def _first_and_steady(channel: grpc.Channel, clock: _Clock, held_s: float) -> tuple[float, float]:
    """1 V held on ao0 (the X shaker) for ``held_s``, then an acquisition of the X probe (ai2):
    its first sample and the mean of its last half."""
    ao = _task(channel)
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
    ao.write(1.0, auto_start=True)
    clock.t += held_s
    ai = _task(channel)
    ai.ai_channels.add_ai_voltage_chan("Dev1/ai2")
    ai.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=2_000)
    data = np.asarray(ai.read(number_of_samples_per_channel=2_000))
    ai.close()
    ao.close()
    return float(data[0]), float(data[1_000:].mean())


def test_a_dc_level_held_between_tasks_reads_steady_in_the_first_sample(
        paced: grpc.Channel, clock: _Clock) -> None:
    # 1 V -> 50 N on X; the seal's 26 N of friction holds the housing anywhere within
    # (50 +/- 26 N) / 788 kN/m = 30.5..96.4 um -> 0.242..0.767 V on the X probe (7,953 V/m)
    first, steady = _first_and_steady(paced, clock, 1.0)
    assert 0.242 <= steady <= 0.767
    assert first == pytest.approx(steady, abs=0.005)  # the rig did not restart from rest
    # a second acquisition, reconfigured, still sees the same steady rig
    first, steady_again = _first_and_steady(paced, clock, 0.5)
    assert first == pytest.approx(steady_again, abs=0.005)
    assert steady_again == pytest.approx(steady, abs=0.005)


def test_a_pump_switched_on_between_tasks_pressurises_the_rig_before_the_next(
        paced: grpc.Channel, clock: _Clock) -> None:
    """The relay acts from the instant it is written, not from the next acquisition's start:
    3 s after the pump went on (inlet time constant 0.5 s) the first sample reads the supply
    pressure. Before, the rig between tasks kept the old relay over the gap: 0 Pa."""
    cm = default_channel_map()
    p_in = cm.ai_channel("p_in")
    do = _task(paced)
    do.do_channels.add_do_chan(cm.relay("pump").physical_channel)
    do.write(True)
    clock.t += 3.0
    ai = _task(paced)
    ai.ai_channels.add_ai_voltage_chan(p_in.physical_channel, min_val=p_in.range_v[0],
                                       max_val=p_in.range_v[1])
    ai.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=100)
    volts = np.asarray(ai.read(number_of_samples_per_channel=100))
    ai.close()
    do.close()
    pressure = (volts[:10].mean() - p_in.offset_v) / p_in.gain_v_per_unit
    supply = RigParams().oil.supply_pressure_pa
    assert pressure == pytest.approx(supply * (1 - np.exp(-3.0 / 0.5)), rel=0.02)


def test_non_regenerating_ao_streams_on_through_its_fifo(paced: grpc.Channel,
                                                         clock: _Clock) -> None:
    """NI's continuous non-regenerating example: the first write sizes the buffer (1,000), the
    board drains it into its 8,191-sample FIFO, so writes return early and never race."""
    ao = _task(paced)
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
    ao.out_stream.regen_mode = RegenerationMode.DONT_ALLOW_REGENERATION
    ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.CONTINUOUS)
    block = np.sin(np.arange(1_000) * 2 * np.pi * 17 / 1_000)
    ao.write(block)
    ao.start()
    t0 = clock.t
    for _ in range(20):
        ao.write(block)
    # 21,000 written; 9,191 (buffer + FIFO) may wait ahead of the generation
    assert clock.t - t0 == pytest.approx((21_000 - 9_191) / 1_000.0, abs=0.002)
    generated = ao.out_stream.total_samp_per_chan_generated
    assert 21_000 - 9_191 <= generated <= 21_000 - 9_191 + 1
    ao.close()


def test_hardware_timed_do_is_paced_by_its_clock_and_done(paced: grpc.Channel,
                                                          clock: _Clock) -> None:
    do = _task(paced)
    do.do_channels.add_do_chan("Dev1/port0/line0", line_grouping=LineGrouping.CHAN_PER_LINE)
    do.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=1_000)
    assert do.write([bool(i % 2) for i in range(1_000)]) == 1_000  # before the start
    do.start()
    assert not do.is_task_done()
    t0 = clock.t
    do.wait_until_done(timeout=5.0)
    assert clock.t - t0 == pytest.approx(1.0, abs=0.002)
    assert do.is_task_done()
    assert do.read() is True  # the line holds the last sample generated (1)
    do.close()


def test_hardware_timed_di_reads_at_its_clock(paced: grpc.Channel, clock: _Clock) -> None:
    di = _task(paced)
    di.di_channels.add_di_chan("Dev1/port0", line_grouping=LineGrouping.CHAN_FOR_ALL_LINES)
    di.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=500)
    t0 = clock.t
    assert di.read(number_of_samples_per_channel=500) == [0] * 500
    assert clock.t - t0 == pytest.approx(0.5, abs=0.002)
    di.close()


def test_ports_as_uint32_and_a_di_line_reads_its_own_state(paced: grpc.Channel) -> None:
    do = _task(paced)
    chan = do.do_channels.add_do_chan("Dev1/port0/line0:7",
                                      line_grouping=LineGrouping.CHAN_FOR_ALL_LINES)
    assert chan.name == "Dev1/port0/line0..." and chan.do_num_lines == 8
    do.write(0xA5)
    assert do.read() == 0xA5  # a DO task reads back what it drives
    do.close()
    di = _task(paced)
    di.di_channels.add_di_chan("/Dev1/port0")  # a leading slash names the same port
    assert di.read() == 0  # tristated: nothing drives it but the pull-down
    di.close()


def test_every_n_samples_and_done_events() -> None:
    with SimulatedDeviceServer(seed=5) as srv:  # the wall clock: the events follow it
        ch = grpc.insecure_channel(srv.address)
        try:
            ai = _task(ch)
            ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
            ai.timing.cfg_samp_clk_timing(10_000.0, sample_mode=AcquisitionType.FINITE,
                                          samps_per_chan=1_000)
            got: list[int] = []
            all_five = threading.Event()
            done = threading.Event()
            status: list[int] = []

            def every_n(task_handle, event_type, n, data):  # type: ignore[no-untyped-def]
                got.append(len(ai.read(number_of_samples_per_channel=n)))
                if len(got) == 5:
                    all_five.set()
                return 0

            def on_done(task_handle, code, data):  # type: ignore[no-untyped-def]
                status.append(code)
                done.set()
                return 0

            ai.register_every_n_samples_acquired_into_buffer_event(200, every_n)
            ai.register_done_event(on_done)
            ai.start()
            assert all_five.wait(10.0) and done.wait(10.0)
            ai.wait_until_done(timeout=10.0)
            ai.close()
            assert got == [200] * 5 and status == [0]
        finally:
            ch.close()


def test_rates_are_coerced_on_the_100_mhz_timebase(paced: grpc.Channel) -> None:
    ai = _task(paced)
    ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    ai.timing.cfg_samp_clk_timing(96_000.0)
    assert ai.timing.samp_clk_rate == pytest.approx(100e6 / 1_041)  # 96,061.48 S/s
    ai.timing.cfg_samp_clk_timing(62_500.0)
    assert ai.timing.samp_clk_rate == 62_500.0
    ai.close()


@pytest.mark.parametrize(("add", "code"), [
    (lambda t: t.ci_channels.add_ci_ang_encoder_chan("Dev1/ctr0"), -201380),  # not simulated
    (lambda t: t.ai_channels.add_ai_strain_gage_chan("Dev1/ai0"), -200431),
    (lambda t: t.ai_channels.add_ai_voltage_chan("Dev1/power"), -200170),
    (lambda t: t.ai_channels.add_ai_voltage_chan("Dev9/ai0"), -200220),
])
def test_what_the_board_lacks_is_a_daq_error_with_its_code(paced: grpc.Channel, add,
                                                           code: int) -> None:
    task = _task(paced)
    with pytest.raises(DaqError) as err:
        add(task)
    assert err.value.error_code == code
    task.close()


def test_thermocouple_on_the_oil_input_reads_the_oil_temperature(paced: grpc.Channel) -> None:
    task = _task(paced)
    task.ai_channels.add_ai_thrmcpl_chan("Dev1/ai12")
    value = task.read()
    # the rig's oil starts at its initial temperature; 10 mV/C through a 16-bit +/-1 V range
    # reads within a count (30.5 uV = 0.003 C) plus the sensor's noise
    from rig_model.params import RigParams
    assert value == pytest.approx(RigParams().oil.initial_temperature_c, abs=0.5)
    task.close()
