"""A plain nidaqmx program, written as for a real multifunction board: no sfdrig code at all.

Run it against an NI gRPC Device Server, e.g. the simulated rig::

    sfdrig sim-server --port 0            # prints "listening on 127.0.0.1:PORT"
    python examples/plain_nidaqmx.py 127.0.0.1:PORT

It generates a 50 Hz sine on ao0 with a regenerating AO task on its own sample clock (nidaqmx's
defaults), acquires a finite block of AI with the AO read back through the board's internal
channel ``_ao0_vs_aognd``, runs a finite AO ramp on ao1, reads on demand (software-timed), and
tries three things the board refuses. It prints one JSON object with what it measured.
"""

from __future__ import annotations

import json
import sys

import grpc
import nidaqmx
import numpy as np
from nidaqmx.constants import READ_ALL_AVAILABLE, AcquisitionType
from nidaqmx.errors import DaqError

FS = 10_000.0  # S/s
F_HZ = 50.0
AMPLITUDE_V = 1.0


def amplitude_at(x: np.ndarray, f_hz: float, fs: float) -> float:
    """Amplitude of the ``f_hz`` component of ``x`` (a whole number of cycles)."""
    t = np.arange(x.size) / fs
    return float(abs(2 * np.mean(x * np.exp(-2j * np.pi * f_hz * t))))


def error_code(action) -> int:
    try:
        action()
    except DaqError as err:
        return err.error_code
    return 0


def main(address: str) -> dict:
    channel = grpc.insecure_channel(address)
    board = nidaqmx.GrpcSessionOptions(channel, "")
    out: dict = {}

    # 1. a sine on ao0: regenerating, on the AO's own clock; AI reads it back and the load cell
    with nidaqmx.Task(grpc_options=board) as ao, nidaqmx.Task(grpc_options=board) as ai:
        ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
        period = int(FS / F_HZ)
        ao.timing.cfg_samp_clk_timing(FS, sample_mode=AcquisitionType.CONTINUOUS,
                                      samps_per_chan=period)
        ao.write(AMPLITUDE_V * np.sin(2 * np.pi * np.arange(period) / period))
        ao.start()
        ai.ai_channels.add_ai_voltage_chan("Dev1/_ao0_vs_aognd")
        ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")  # the x load cell
        ai.timing.cfg_samp_clk_timing(FS, sample_mode=AcquisitionType.FINITE,
                                      samps_per_chan=20 * period)
        loopback, load_cell = np.array(ai.read(READ_ALL_AVAILABLE))
        out["loopback_amplitude_v"] = amplitude_at(loopback, F_HZ, FS)
        out["loopback_peak_v"] = float(np.abs(loopback).max())
        out["load_cell_amplitude_v"] = amplitude_at(load_cell[10 * period:], F_HZ, FS)
        out["ai_done"] = ai.is_task_done()
        out["ao_generated"] = ao.out_stream.total_samp_per_chan_generated

    # 2. a finite ramp on ao1, then an on-demand (software-timed) read of where it stopped
    with nidaqmx.Task(grpc_options=board) as ao:
        ao.ao_channels.add_ao_voltage_chan("Dev1/ao1")
        ao.timing.cfg_samp_clk_timing(1_000.0, sample_mode=AcquisitionType.FINITE,
                                      samps_per_chan=500)
        ao.write(np.linspace(0.0, 2.0, 500))
        ao.start()
        ao.wait_until_done(timeout=5.0)
        out["finite_ao_done"] = ao.is_task_done()
        out["finite_ao_generated"] = ao.out_stream.total_samp_per_chan_generated
    with nidaqmx.Task(grpc_options=board) as ai:
        ai.ai_channels.add_ai_voltage_chan("Dev1/_ao1_vs_aognd")
        out["on_demand_ao1_v"] = ai.read()

    # 3. what the board refuses, with DAQmx's own codes
    with nidaqmx.Task(grpc_options=board) as ao:
        ao.ao_channels.add_ao_voltage_chan("Dev1/ao0")
        ao.timing.cfg_samp_clk_timing(FS, sample_mode=AcquisitionType.CONTINUOUS)
        out["start_with_empty_buffer"] = error_code(ao.start)
    with nidaqmx.Task(grpc_options=board) as ai:
        out["missing_channel"] = error_code(
            lambda: ai.ai_channels.add_ai_voltage_chan("Dev1/ai99"))
        ai.ai_channels.add_ai_voltage_chan("Dev1/ai0")
        out["rate_too_high"] = error_code(lambda: ai.timing.cfg_samp_clk_timing(1e8))
    channel.close()
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: plain_nidaqmx.py HOST:PORT")
    print(json.dumps(main(sys.argv[1])))
