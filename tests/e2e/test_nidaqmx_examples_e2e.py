"""NI's own nidaqmx examples (``../shared/reference/nidaqmx-python-examples``, unchanged) against
a real ``sfdrig sim-server`` process: each runs, or ends in the DaqError a PXIe-6358 (or the
driver) gives for what it asks, never gRPC UNIMPLEMENTED, INTERNAL or a server traceback.

Each example runs in a process of its own through `nidaqmx_example_runner.py`, which supplies
only the session and the device names (and the user's Ctrl+C / Enter). The table below is the
expected outcome of each, with what is checked of what it prints.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.paced, pytest.mark.needs_shared]

RUNNER = Path(__file__).with_name("nidaqmx_example_runner.py")
REPO_ROOT = Path(__file__).resolve().parents[2]
NUMBER = re.compile(r"-?\d+\.\d+(?:e[-+]?\d+)?")


def _floats(out: str) -> list[float]:
    return [float(x) for x in NUMBER.findall(out)]


def _volts(n: int, within_v: float) -> Callable[[dict, str], None]:
    """The example printed ``n`` readings, each within ``within_v`` of 0 V (an unwired or
    resting input: the fx load cell on ai0 reads noise around 0 V, 305 uV a count)."""

    def check(result: dict, out: str) -> None:
        values = _floats(out)
        assert len(values) == n, out[-500:]
        assert all(abs(v) <= within_v for v in values), out[-500:]

    return check


@dataclass(frozen=True)
class Runs:
    """The example runs to its end; ``check(result, stdout)`` looks at what it printed."""

    check: Callable[[dict, str], None] | None = None
    loops: int = 3  # reads/writes/events before the simulated user stops it


@dataclass(frozen=True)
class Refused:
    """The example ends in ``nidaqmx.errors.DaqError`` with ``code``; ``why`` is the board's
    reason."""

    code: int
    why: str = field(default="")


def _contains(*texts: str) -> Callable[[dict, str], None]:
    def check(result: dict, out: str) -> None:
        for text in texts:
            assert text in out, out[-800:]

    return check


def _acquired(total: int) -> Callable[[dict, str], None]:
    return _contains(f"Acquired {total} total samples.")


def _every_n(text: str) -> Callable[[dict, str], None]:
    """At least 3 events came (the user waits for them), each handling N samples."""

    def check(result: dict, out: str) -> None:
        assert result["events"] >= 3, result
        assert out.count(text) >= 2, out[-800:]

    return check


def _paced_do(result: dict, out: str) -> None:
    # 1,000 samples at 1 kHz, finite: wait_until_done returns when the clock has generated them
    assert "Generating 1000 voltage samples." in out
    assert 0.95 <= result["wall_s"] <= 5.0, result


def _non_regen(result: dict, out: str) -> None:
    # 16 writes of 1,000 samples at 1 kHz without an underflow: the FIFO and the buffer hold
    # 9,191 samples, so the last writes wait for the clock (about 6-7 s in all)
    assert result["calls"] == 16 and 5.5 <= result["wall_s"] <= 12.0, result


def _properties(result: dict, out: str) -> None:
    assert out.split()[:9] == ["0.1", "-0.1", "5.0", "-0.1", "10.0", "-10.0", "5.0", "-0.1",
                               "Dev1/ai2"], out


def _system(result: dict, out: str) -> None:
    assert "DAQmx 24.8.0" in out
    assert "Device Name: Dev1, Product Category: ProductCategory.X_SERIES_DAQ, Product Type: " \
           "PXIe-6358" in out


NO_COUNTERS = Refused(-201380, "the simulated board has no counters")
NO_WAVEFORMS = Refused(-201380, "the waveform API is not simulated")
PFI = Refused(-200040, "nothing drives the PFI lines: a trigger there is an invalid routing")
NO_POWER = Refused(-200170, "a PXIe-6358 has no power channel (TS1Mod1/power -> Dev1/power)")


def _celsius(result: dict, out: str) -> None:
    # ai0 (the fx load cell, at rest) read as a type K thermocouple: the 25 C cold junction
    # plus the load cell's noise (within +/-2 mV at rest, see voltage_acq_int_clk) over
    # 41 uV/C: within 25 +/- 49 C
    values = _floats(out)
    assert values and all(-24.0 <= v <= 74.0 for v in values), out[-500:]



EXPECTED: dict[str, Runs | Refused] = {
    "analog_in/ai_multi_task_pxie_ref_clk.py": Refused(-200197, "sync_type (a PXIe chassis "
                                                       "sync pulse) is not simulated"),
    "analog_in/ai_raw.py": Runs(_contains("N Channel N Samples Read Raw")),
    "analog_in/calculated_power_acq_int_clk.py": Refused(-200431, "no calculated power"),
    "analog_in/cont_calculated_power_acq_int_clk.py": Refused(-200431, "no calculated power"),
    "analog_in/cont_thrmcpl_samples_int_clk.py": Runs(_acquired(50), loops=1),
    "analog_in/cont_voltage_acq_int_clk.py": Runs(_acquired(3000)),
    "analog_in/cont_voltage_acq_int_clk_dig_start.py": PFI,
    "analog_in/cont_voltage_acq_int_clk_dig_start_retrig.py": PFI,
    "analog_in/cont_voltage_acq_int_clk_every_n_samples_event.py": Runs(
        _every_n("Acquired data: 1000 samples.")),
    "analog_in/thrmcpl_sample.py": Runs(_celsius),
    "analog_in/voltage_acq_int_clk.py": Runs(_volts(50, 0.01)),
    "analog_in/voltage_acq_int_clk_dig_ref.py": PFI,
    "analog_in/voltage_acq_int_clk_dig_start_ref.py": PFI,
    "analog_in/voltage_acq_int_clk_plot_data.py": Runs(),
    "analog_in/voltage_acq_int_clk_plot_wfm.py": NO_WAVEFORMS,
    "analog_in/voltage_acq_int_clk_tdms_logging.py": Refused(-201380, "no TDMS logging"),
    "analog_in/voltage_acq_int_clk_wfm.py": NO_WAVEFORMS,
    "analog_in/voltage_sample.py": Runs(_volts(1, 0.01)),
    "analog_out/cont_gen_voltage_wfm_int_clk.py": Runs(),
    "analog_out/cont_gen_voltage_wfm_int_clk_every_n_samples_event.py": Runs(
        _every_n("Transferred data: 1000 samples.")),
    "analog_out/cont_gen_voltage_wfm_int_clk_non_regen.py": Runs(_non_regen, loops=15),
    "analog_out/gen_voltage_wfm_int_clk.py": NO_WAVEFORMS,
    "analog_out/voltage_update.py": Runs(),
    "channel_properties.py": Runs(_properties),
    "counter_in/cnt_dig_event.py": NO_COUNTERS,
    "counter_in/cont_cnt_buff_event_ext_clk.py": NO_COUNTERS,
    "counter_in/cont_read_buff_freq.py": NO_COUNTERS,
    "counter_in/read_freq.py": NO_COUNTERS,
    "counter_in/read_pulse_freq.py": NO_COUNTERS,
    "counter_out/cont_gen_dig_pulse_train.py": NO_COUNTERS,
    "counter_out/cont_gen_dig_pulse_train_buff_ext_clk.py": NO_COUNTERS,
    "counter_out/cont_gen_dig_pulse_train_buff_implicit.py": NO_COUNTERS,
    "counter_out/write_single_dig_pulse.py": NO_COUNTERS,
    "digital_in/acq_dig_port_int_clk.py": Runs(),
    "digital_in/acq_dig_port_int_clk_wfm.py": NO_WAVEFORMS,
    "digital_in/cont_acq_dig_lines_int_clk.py": Runs(),
    "digital_in/read_dig_lines.py": Runs(),
    "digital_in/read_dig_port.py": Runs(),
    "digital_out/cont_gen_dig_port_int_clk.py": Runs(),
    "digital_out/cont_gen_dig_port_int_clk_wfm.py": NO_WAVEFORMS,
    "digital_out/gen_dig_line_int_clk.py": Runs(_paced_do),
    "digital_out/write_dig_lines.py": Runs(),
    "digital_out/write_dig_port.py": Runs(),
    "every_n_samples_event.py": Runs(_every_n("Every N Samples callback invoked.")),
    "nidaqmx_warnings.py": Runs(),
    "playrec.py": Refused(-200220, "Dev2: the server has one board"),
    "pwr_hw_timed.py": NO_POWER,
    "pwr_hw_timed_stream.py": NO_POWER,
    "pwr_sw_timed.py": NO_POWER,
    "synchronization/multi_function/ai_ao_sync.py": Runs(
        _every_n("Acquired data: 1000 samples.")),
    "synchronization/multi_function/cont_ai_ci_tdms_sync.py": NO_COUNTERS,
    "synchronization/multi_function/cont_ai_di_acq.py": Runs(),
    "system_properties.py": Runs(_system),
}


@pytest.fixture(scope="module")
def sim_server() -> Iterator[str]:
    server = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "7"],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = server.stdout.readline().strip()  # type: ignore[union-attr]
        assert first.startswith("listening on "), first
        yield first.removeprefix("listening on ")
    finally:
        server.send_signal(signal.SIGTERM)
        _, err = server.communicate(timeout=30)
    assert "Traceback" not in err, err[-3000:]


def test_the_table_covers_every_example(shared_dir: Path) -> None:
    examples = shared_dir / "reference" / "nidaqmx-python-examples"
    found = {str(p.relative_to(examples)) for p in examples.rglob("*.py")}
    assert found == set(EXPECTED)


@pytest.mark.parametrize("example", sorted(EXPECTED))
def test_nis_example_runs_or_is_refused_as_the_board_does(
        example: str, sim_server: str, shared_dir: Path) -> None:
    path = shared_dir / "reference" / "nidaqmx-python-examples" / example
    expected = EXPECTED[example]
    loops = expected.loops if isinstance(expected, Runs) else 3
    run = subprocess.run([sys.executable, str(RUNNER), sim_server, str(path), "--loops",
                          str(loops)], cwd=path.parent, capture_output=True, text=True,
                         timeout=120)
    lines = [line for line in run.stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, run.stdout[-2000:] + run.stderr[-2000:]
    result = json.loads(lines[-1].removeprefix("RESULT "))
    out = run.stdout[: run.stdout.rfind("RESULT ")]
    assert "UNIMPLEMENTED" not in run.stdout + run.stderr
    if isinstance(expected, Refused):
        assert (result["status"], result.get("code")) == ("daqerror", expected.code), result
    else:
        assert result["status"] == "ok", result
        if expected.check is not None:
            expected.check(result, out)
