"""End to end: `sfdrig sim-server` as a real process, driven by a plain nidaqmx program
(`examples/plain_nidaqmx.py`, no sfdrig code) in a process of its own, as a user would run it
against a real board."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "plain_nidaqmx.py"
LSB_V = 20.0 / 2**16  # one count of the 16-bit +/-10 V AI


@pytest.mark.paced
def test_a_plain_nidaqmx_program_runs_against_the_sim_server() -> None:
    server = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        first = server.stdout.readline().strip()  # blocks until the server is listening
        assert first.startswith("listening on 127.0.0.1:"), (first, server.stderr.read())
        user = subprocess.run([sys.executable, str(EXAMPLE), first.removeprefix("listening on ")],
                              capture_output=True, text=True, timeout=120)
        assert user.returncode == 0, user.stderr
        got = json.loads(user.stdout)
    finally:
        server.send_signal(signal.SIGTERM)
        server.communicate(timeout=10)
    # the regenerating sine on ao0 (own clock), read back through _ao0_vs_aognd
    assert got["loopback_amplitude_v"] == pytest.approx(1.0, abs=LSB_V)
    assert got["loopback_peak_v"] == pytest.approx(1.0, abs=LSB_V)
    # 1 V -> 50 N through the shaker -> 0.02 V/N on the x load cell
    assert got["load_cell_amplitude_v"] == pytest.approx(1.0, rel=0.01)
    assert got["ai_done"] is True and got["ao_generated"] >= 4_000
    # the finite ramp ended at 2 V and stayed there (idle behaviour: maintain, DAQmx's default)
    assert got["finite_ao_done"] is True and got["finite_ao_generated"] == 500
    assert got["on_demand_ao1_v"] == pytest.approx(2.0, abs=LSB_V)
    # refusals, with the codes of nidaqmx.error_codes.DAQmxErrors
    assert got["start_with_empty_buffer"] == -200462  # OUTPUT_BUFFER_EMPTY
    assert got["missing_channel"] == -200170  # PHYSICAL_CHAN_DOES_NOT_EXIST
    assert got["rate_too_high"] == -200332  # SAMP_RATE_TOO_HIGH
