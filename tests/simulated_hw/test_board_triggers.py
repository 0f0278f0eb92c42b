"""Triggers and clocks on the board's PFI lines (issue 22): accepted as a PXIe-6358 accepts
them; nothing on the rig drives those lines, so an armed task waits, its reads time out with
the board's -200284 after their timeout, and nothing is generated."""

from __future__ import annotations

import grpc
import nidaqmx
import numpy as np
import pytest
from nidaqmx.constants import READ_ALL_AVAILABLE, AcquisitionType
from nidaqmx.errors import DaqError

from tests.simulated_hw.fake_clock import FakeClock
from tests.simulated_hw.grpc_board import task_on

_task = task_on  # clock and paced: tests/simulated_hw/conftest.py


def _ai(channel: grpc.Channel, mode: AcquisitionType = AcquisitionType.FINITE) -> nidaqmx.Task:
    ai = _task(channel)
    ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    ai.timing.cfg_samp_clk_timing(1_000.0, sample_mode=mode, samps_per_chan=100)
    return ai


@pytest.mark.parametrize("trigger", ["start", "reference", "clock"])
def test_a_read_armed_on_an_undriven_pfi_line_times_out_after_its_timeout(
        paced: grpc.Channel, clock: FakeClock, trigger: str) -> None:
    ai = _ai(paced)
    if trigger == "start":
        ai.triggers.start_trigger.cfg_dig_edge_start_trig("/Dev1/PFI0")
    elif trigger == "reference":
        ai.triggers.reference_trigger.cfg_dig_edge_ref_trig("/Dev1/PFI8", pretrigger_samples=50)
    else:
        ai.timing.cfg_samp_clk_timing(1_000.0, source="/Dev1/PFI9",
                                      sample_mode=AcquisitionType.FINITE, samps_per_chan=100)
    ai.start()
    t0 = clock.t
    with pytest.raises(DaqError) as err:
        ai.read(READ_ALL_AVAILABLE, timeout=2.5)
    assert err.value.error_code == -200284
    assert clock.t - t0 == pytest.approx(2.5)  # it waited the whole timeout
    assert "0 of 100 samples acquired" in str(err.value)
    assert "/Dev1/PFI" in str(err.value)
    assert not ai.is_task_done()
    with pytest.raises(DaqError) as err:
        ai.wait_until_done(timeout=1.0)
    assert err.value.error_code == -200560
    ai.close()


def test_an_armed_continuous_task_has_nothing_available_and_the_board_is_free_after_it(
        paced: grpc.Channel, clock: FakeClock) -> None:
    ai = _ai(paced, AcquisitionType.CONTINUOUS)
    ai.triggers.start_trigger.cfg_dig_edge_start_trig("/Dev1/PFI0")
    ai.triggers.start_trigger.retriggerable = True
    assert ai.triggers.start_trigger.retriggerable is True
    ai.start()
    clock.t += 5.0
    assert ai.in_stream.avail_samp_per_chan == 0
    assert ai.read(READ_ALL_AVAILABLE) == []
    ai.stop()
    # the trigger disabled, the same task acquires on its own clock
    ai.triggers.start_trigger.disable_start_trig()
    ai.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                  samps_per_chan=100)
    assert len(ai.read(READ_ALL_AVAILABLE)) == 100
    ai.close()


def test_ao_armed_on_a_pfi_line_generates_nothing(paced: grpc.Channel,
                                                  clock: FakeClock) -> None:
    ao = _task(paced)
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
    ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.CONTINUOUS)
    ao.triggers.start_trigger.cfg_dig_edge_start_trig("/Dev1/PFI1")
    ao.write(np.full(1_000, 1.0))
    ao.start()
    clock.t += 2.0
    assert ao.out_stream.total_samp_per_chan_generated == 0
    ao.close()


@pytest.mark.parametrize(("configure", "code"), [
    (lambda t: t.triggers.start_trigger.cfg_dig_edge_start_trig("/Dev1/PFI16"), -200040),
    (lambda t: t.triggers.start_trigger.cfg_dig_edge_start_trig("/Dev2/PFI0"), -200040),
    (lambda t: t.timing.cfg_samp_clk_timing(1_000.0, source="/Dev1/PFI99"), -200040),
])
def test_a_line_the_board_lacks_is_refused(paced: grpc.Channel, configure, code: int) -> None:
    ai = _ai(paced)
    with pytest.raises(DaqError) as err:
        configure(ai)
    assert err.value.error_code == code
    ai.close()


def test_a_reference_trigger_on_an_output_task_is_refused(paced: grpc.Channel) -> None:
    ao = _task(paced)
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
    with pytest.raises(DaqError) as err:
        ao.triggers.reference_trigger.cfg_dig_edge_ref_trig("/Dev1/PFI8", pretrigger_samples=2)
    assert err.value.error_code == -200452
    ao.close()
