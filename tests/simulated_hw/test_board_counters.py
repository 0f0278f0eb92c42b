"""The PXIe-6358's four counters on this rig (issue 22): nothing is wired to their inputs, so
edge counts stay at their initial count and frequency or pulse reads time out as the board's do;
pulses are generated on the counter timebase and end when the board's would."""

from __future__ import annotations

import threading

import grpc
import pytest
from nidaqmx.constants import READ_ALL_AVAILABLE, AcquisitionType, Level
from nidaqmx.errors import DaqError

from simulated_hw.board.counters import coerced
from tests.simulated_hw.fake_clock import FakeClock
from tests.simulated_hw.grpc_board import task_on

_task = task_on  # clock and paced: tests/simulated_hw/conftest.py


def test_an_edge_count_with_nothing_wired_stays_at_its_initial_count(
        paced: grpc.Channel, clock: FakeClock) -> None:
    ci = _task(paced)
    chan = ci.ci_channels.add_ci_count_edges_chan("Dev1/ctr1", initial_count=5)
    chan.ci_count_edges_term = "/Dev1/PFI8"
    assert chan.ci_count_edges_term == "/Dev1/PFI8"
    ci.start()
    first = ci.read()
    clock.t += 10.0
    assert (first, ci.read()) == (5.0, 5.0)
    ci.close()


def test_a_frequency_read_on_demand_times_out_as_the_board_does(
        paced: grpc.Channel, clock: FakeClock) -> None:
    ci = _task(paced)
    ci.ci_channels.add_ci_freq_chan("Dev1/ctr0", min_val=2.0, max_val=100_000.0)
    t0 = clock.t
    with pytest.raises(DaqError) as err:
        ci.read(timeout=3.0)
    assert err.value.error_code == -200474
    assert clock.t - t0 == pytest.approx(3.0)
    ci.close()


def test_a_buffered_pulse_measurement_times_out_and_has_nothing_available(
        paced: grpc.Channel, clock: FakeClock) -> None:
    ci = _task(paced)
    ci.ci_channels.add_ci_pulse_chan_freq("Dev1/ctr0", min_val=2.0, max_val=1e5)
    ci.timing.cfg_implicit_timing(sample_mode=AcquisitionType.CONTINUOUS)
    ci.start()
    assert ci.read(READ_ALL_AVAILABLE) == []
    t0 = clock.t
    with pytest.raises(DaqError) as err:
        ci.read(number_of_samples_per_channel=100, timeout=2.0)
    assert err.value.error_code == -200284
    assert clock.t - t0 == pytest.approx(2.0)
    ci.close()


def test_a_single_pulse_is_done_after_its_delay_and_high_time(
        paced: grpc.Channel, clock: FakeClock) -> None:
    co = _task(paced)
    co.co_channels.add_co_pulse_chan_time("Dev1/ctr0", idle_state=Level.LOW,
                                          initial_delay=0.25, low_time=0.5, high_time=1.0)
    co.start()
    assert not co.is_task_done()
    t0 = clock.t
    co.wait_until_done(timeout=10.0)
    assert clock.t - t0 == pytest.approx(1.25)
    assert co.is_task_done()
    co.close()


def test_a_finite_pulse_train_ends_with_its_last_pulse_and_tells_its_done_event(
        paced: grpc.Channel, clock: FakeClock) -> None:
    co = _task(paced)
    co.co_channels.add_co_pulse_chan_freq("Dev1/ctr2", freq=10.0, duty_cycle=0.25)
    co.timing.cfg_implicit_timing(sample_mode=AcquisitionType.FINITE, samps_per_chan=5)
    status: list[int] = []
    done = threading.Event()

    def on_done(task_handle, code, data):  # type: ignore[no-untyped-def]
        status.append(code)
        done.set()
        return 0

    co.register_done_event(on_done)
    co.start()
    clock.t += 0.424  # 4 periods of 0.1 s + 25 ms high = 0.425 s
    assert not co.is_task_done()
    clock.t += 0.002
    assert co.is_task_done()
    assert done.wait(10.0) and status == [0]
    co.close()


def test_a_continuous_train_runs_until_stopped(paced: grpc.Channel, clock: FakeClock) -> None:
    co = _task(paced)
    co.co_channels.add_co_pulse_chan_freq("Dev1/ctr0", freq=1.0, duty_cycle=0.5)
    co.timing.cfg_implicit_timing(sample_mode=AcquisitionType.CONTINUOUS)
    co.start()
    clock.t += 100.0
    assert not co.is_task_done()
    with pytest.raises(DaqError) as err:
        co.wait_until_done(timeout=1.0)
    assert err.value.error_code == -200560
    co.stop()
    assert co.is_task_done()
    co.close()


def test_pulse_times_are_whole_ticks_of_the_fastest_timebase_that_holds_them() -> None:
    assert coerced(1 / 6, "t", "here") == 16_666_667 / 100e6  # 100 MHz
    assert coerced(60.0, "t", "here") == 60.0  # 6e9 ticks of 100 MHz overflow 32 bits: 20 MHz
    assert coerced(1e-7 + 3e-9, "t", "here") == 10 / 100e6
    with pytest.raises(Exception, match="outside what the counter makes"):
        coerced(10e-9, "t", "here")  # 1 tick: the counter needs 2
    with pytest.raises(Exception, match="outside what the counter makes"):
        coerced(1e5, "t", "here")  # 1e10 ticks of 100 kHz
    with pytest.raises(Exception, match="outside what the counter makes"):
        coerced(float("nan"), "t", "here")


@pytest.mark.parametrize(("make", "code"), [
    (lambda t: t.ci_channels.add_ci_count_edges_chan("Dev1/ctr4"), -200170),
    (lambda t: t.ci_channels.add_ci_count_edges_chan("Dev2/ctr0"), -200220),
    (lambda t: t.ci_channels.add_ci_ang_encoder_chan("Dev1/ctr0"), -201380),
    (lambda t: t.co_channels.add_co_pulse_chan_freq("Dev1/ctr0", freq=10.0, duty_cycle=1.0),
     -200077),
    (lambda t: t.co_channels.add_co_pulse_chan_freq("Dev1/ctr0", freq=0.0), -200077),
    (lambda t: t.ci_channels.add_ci_freq_chan("Dev1/ctr0", min_val=10.0, max_val=1.0), -200077),
])
def test_what_the_counters_do_not_do_is_refused_with_the_boards_code(
        paced: grpc.Channel, make, code: int) -> None:
    task = _task(paced)
    with pytest.raises(DaqError) as err:
        make(task)
    assert err.value.error_code == code
    task.close()


def test_a_counter_is_one_task_s_at_a_time_and_not_on_the_onboard_clock(
        paced: grpc.Channel) -> None:
    a, b = _task(paced), _task(paced)
    a.ci_channels.add_ci_count_edges_chan("Dev1/ctr0")
    b.co_channels.add_co_pulse_chan_freq("Dev1/ctr0", freq=10.0)
    a.start()
    with pytest.raises(DaqError) as err:
        b.start()
    assert err.value.error_code == -50103
    a.stop()
    a.timing.cfg_samp_clk_timing(1_000.0)
    with pytest.raises(DaqError) as err:
        a.start()
    assert err.value.error_code == -201380
    a.close()
    b.close()


def test_an_edge_count_on_the_ai_sample_clock_waits_for_it_and_counts_nothing(
        paced: grpc.Channel, clock: FakeClock) -> None:
    ci = _task(paced)
    ci.ci_channels.add_ci_count_edges_chan("Dev1/ctr0", initial_count=0)
    ci.timing.cfg_samp_clk_timing(1_000.0, source="/Dev1/ai/SampleClock",
                                  sample_mode=AcquisitionType.CONTINUOUS)
    ci.start()
    t0 = clock.t
    with pytest.raises(DaqError) as err:  # the AI clock has not started
        ci.read(number_of_samples_per_channel=10, timeout=1.0)
    assert err.value.error_code == -200284
    assert clock.t - t0 == pytest.approx(1.0)
    ai = _task(paced)
    ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    ai.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.CONTINUOUS)
    ai.start()
    t0 = clock.t
    assert ci.read(number_of_samples_per_channel=100) == [0.0] * 100
    assert clock.t - t0 == pytest.approx(0.1, abs=0.002)  # paced by the AI sample clock
    assert len(ai.read(number_of_samples_per_channel=100)) == 100
    ai.close()
    ci.close()
