"""NI's own nidaqmx examples (``../shared/reference/nidaqmx-python-examples``, unchanged) against
a real ``sfdrig sim-server`` process: each runs, or ends in the DaqError a PXIe-6358 (or the
driver) gives for what it asks, never gRPC UNIMPLEMENTED, INTERNAL or a server traceback.

Each example runs in a process of its own through `nidaqmx_example_runner.py`, which supplies
only the session and the device names (and the user's Ctrl+C / Enter). The table below is the
expected outcome of each, with what is checked of what it prints. They mostly wait on the paced
board, so they run in `LANES` lanes at once (`nidaqmx_example_lane.py`), each lane one example
after another on a sim-server of its own, all started with the module; each test judges its
example's output when it has ended.
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tests.conftest import SHARED

pytestmark = [pytest.mark.e2e, pytest.mark.paced, pytest.mark.needs_shared]

RUNNER = Path(__file__).with_name("nidaqmx_example_runner.py")
LANE = Path(__file__).with_name("nidaqmx_example_lane.py")
#: lanes of examples run at once: one after another on one server they took 99-150 s of the
#: paced tests' sequence (one worker), 41 s of it CPU (each example's Python and nidaqmx), the
#: rest waiting on the paced board; in three lanes 86 s against 99 s at load 7 (9 s more CPU:
#: two more servers)
LANES = 3
TEST = "test_nis_example_runs_or_is_refused_as_the_board_does"
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
    patience_s: float = 30.0  # how long the user waits for events before pressing Enter
    #: run in the server's working directory: a file the example has the server write (TDMS
    #: logging) is on the server's disk, relative to its directory, as with NI's gRPC server
    in_server_dir: bool = False
    enter_after_s: float = 0.0  # the user presses Enter after this, when no event calls back
    #: run from a copy in a directory of its own: the example writes files beside itself,
    #: which must not land in ../shared
    own_dir: bool = False


@dataclass(frozen=True)
class Refused:
    """The example ends in ``nidaqmx.errors.DaqError`` with ``code``; ``why`` is the board's
    reason. ``waits_s``: the example first waits this long on the board (a read's timeout):
    such examples are started together at the module's start, so their waits overlap."""

    code: int
    why: str = field(default="")
    waits_s: float = 0.0


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


#: a frequency or pulse measurement with nothing on the counter's input: the read waits its
#: timeout (10 s) and the board answers -200474 on demand, -200284 buffered
NO_EDGE_ON_DEMAND = Refused(-200474, "nothing drives the counter's input", waits_s=10.0)
NO_EDGE_BUFFERED = Refused(-200284, "nothing drives the counter's input (or its PFI clock)",
                           waits_s=10.0)


def _no_edges(result: dict, out: str) -> None:
    # polled three times, then Ctrl+C: nothing drives PFI8, so every count is the initial 0
    assert result["calls"] == 4, result
    assert out.count("Acquired count: 0") == 3, out[-500:]
    assert "Acquired 0 total counts." in out, out[-500:]


def _single_pulse(result: dict, out: str) -> None:
    # no initial delay, then 1.0 s high: wait_until_done returns when the pulse has ended
    assert 1.0 <= result["wall_s"] <= 5.0, result

#: a finite read of a task armed on a PFI line nothing drives: the board waits the read's
#: timeout (nidaqmx's default, 10 s) and answers -200284
UNTRIGGERED_READ = Refused(-200284, "nothing drives the PFI line: the trigger never comes",
                           waits_s=10.0)


def _untriggered_events(result: dict, out: str) -> None:
    """Armed on a PFI line nothing drives: no every-N event, nothing acquired, the user stops it
    (after 1 s of patience)."""
    assert result["events"] == 0 and result["calls"] == 0, result
    assert "Acquired 0 total samples." in out, out[-500:]
    assert 1.0 <= result["wall_s"] <= 10.0, result


UNTRIGGERED_EVENTS = Runs(_untriggered_events, patience_s=1.0)
NO_POWER = Refused(-200170, "a PXIe-6358 has no power channel (TS1Mod1/power -> Dev1/power)")


def _ai0_waveform(result: dict, out: str) -> None:
    # 50 samples of the fx load cell at rest (within +/-10 mV), its name, units and timing
    data = out[out.index("Acquired data: [") + 16: out.index("]")]
    values = [float(v) for v in data.split()]
    assert len(values) == 50 and all(abs(v) <= 0.01 for v in values), out[-800:]
    for text in ("Channel name: Dev1/ai0", "Units: Volts", "dt: 0:00:00.001000", "t0: 20"):
        assert text in out, out[-800:]


def _port0_waveform(result: dict, out: str) -> None:
    # the 8 lines of port0, each 50 samples of the pull-down (nothing drives them)
    lines = re.findall(r"^Dev1/port0/line(\d): \[([01 \n]*)\]", out, re.MULTILINE)
    assert sorted(int(n) for n, _ in lines) == list(range(8)), out[-800:]
    assert all(bits.split() == ["0"] * 50 for _, bits in lines), out[-800:]
    assert "Channel name: Dev1/port0" in out and "dt: 0:00:00.001000" in out, out[-800:]


def _finite_ao_waveform(result: dict, out: str) -> None:
    # 1,000 samples at 1 kHz: wait_until_done returns when the clock has generated them
    assert "Generating 1000 voltage samples." in out, out[-500:]
    assert 0.95 <= result["wall_s"] <= 5.0, result


def _logged(result: dict, out: str) -> None:
    # the server logged the read's 10 samples of ai0 (at rest: within +/-10 mV) to TestData.tdms
    # in its directory; the example read them back from there, then removed the file
    lines = [line for line in out.splitlines() if line.startswith("Read data from TDMS file")]
    assert len(lines) == 1, out[-800:]
    values = _floats(lines[0])
    assert len(values) == 10 and all(abs(v) <= 0.01 for v in values), out[-800:]


def _synchronized(result: dict, out: str) -> None:
    # 2.5 s of 1 kHz acquisition on ai0/ai1 and an edge count on the AI sample clock, logged by
    # the example to its own TDMS file (1,000 samples a block) and read back: at least one
    # block; the counter counted nothing (PFI0 is undriven); the fx and fy load cells show
    # what earlier examples left on the shakers (the rig keeps moving between tasks: up to
    # 0.31 V seen), each held steady over the 10 ms printed
    assert "Data saved to multi_task_data.tdms" in out, out[-800:]
    blocks = re.findall(r"First 10 samples from (\w+)/(\w+):\n\[([^\]]*)\]", out)
    names = [(g, c) for g, c, _ in blocks]
    assert names == [("AI_Task", "Channel01"), ("AI_Task", "Channel02"),
                     ("CI_Task", "Counter0")], out[-800:]
    ai0, ai1, counts = ([float(v) for v in values.split()] for _, _, values in blocks)
    assert counts == [0.0] * 10, out[-800:]
    for load_cell in (ai0, ai1):
        assert len(load_cell) == 10 and all(abs(v) <= 10.0 for v in load_cell), out[-800:]
        assert max(load_cell) - min(load_cell) <= 0.02, out[-800:]


def _celsius(result: dict, out: str) -> None:
    # ai0 (the fx load cell, at rest) read as a type K thermocouple: the 25 C cold junction
    # plus the load cell's noise (within +/-2 mV at rest, see voltage_acq_int_clk) over
    # 41 uV/C: within 25 +/- 49 C
    values = _floats(out)
    assert values and all(-24.0 <= v <= 74.0 for v in values), out[-500:]



EXPECTED: dict[str, Runs | Refused] = {
    "analog_in/ai_multi_task_pxie_ref_clk.py": Refused(-50103, "its two PXIe devices are "
                                                       "one board here: the committed master "
                                                       "task holds ai0, as a 6358 does"),
    "analog_in/ai_raw.py": Runs(_contains("N Channel N Samples Read Raw")),
    "analog_in/calculated_power_acq_int_clk.py": Refused(-200431, "no calculated power"),
    "analog_in/cont_calculated_power_acq_int_clk.py": Refused(-200431, "no calculated power"),
    "analog_in/cont_thrmcpl_samples_int_clk.py": Runs(_acquired(50), loops=1),
    "analog_in/cont_voltage_acq_int_clk.py": Runs(_acquired(3000)),
    "analog_in/cont_voltage_acq_int_clk_dig_start.py": UNTRIGGERED_EVENTS,
    "analog_in/cont_voltage_acq_int_clk_dig_start_retrig.py": UNTRIGGERED_EVENTS,
    "analog_in/cont_voltage_acq_int_clk_every_n_samples_event.py": Runs(
        _every_n("Acquired data: 1000 samples.")),
    "analog_in/thrmcpl_sample.py": Runs(_celsius),
    "analog_in/voltage_acq_int_clk.py": Runs(_volts(50, 0.01)),
    "analog_in/voltage_acq_int_clk_dig_ref.py": UNTRIGGERED_READ,
    "analog_in/voltage_acq_int_clk_dig_start_ref.py": UNTRIGGERED_READ,
    "analog_in/voltage_acq_int_clk_plot_data.py": Runs(),
    "analog_in/voltage_acq_int_clk_plot_wfm.py": Runs(),
    "analog_in/voltage_acq_int_clk_tdms_logging.py": Runs(_logged, in_server_dir=True),
    "analog_in/voltage_acq_int_clk_wfm.py": Runs(_ai0_waveform),
    "analog_in/voltage_sample.py": Runs(_volts(1, 0.01)),
    "analog_out/cont_gen_voltage_wfm_int_clk.py": Runs(),
    "analog_out/cont_gen_voltage_wfm_int_clk_every_n_samples_event.py": Runs(
        _every_n("Transferred data: 1000 samples.")),
    "analog_out/cont_gen_voltage_wfm_int_clk_non_regen.py": Runs(_non_regen, loops=15),
    "analog_out/gen_voltage_wfm_int_clk.py": Runs(_finite_ao_waveform),
    "analog_out/voltage_update.py": Runs(),
    "channel_properties.py": Runs(_properties),
    "counter_in/cnt_dig_event.py": Runs(_no_edges),
    "counter_in/cont_cnt_buff_event_ext_clk.py": NO_EDGE_BUFFERED,
    "counter_in/cont_read_buff_freq.py": NO_EDGE_BUFFERED,
    "counter_in/read_freq.py": NO_EDGE_ON_DEMAND,
    "counter_in/read_pulse_freq.py": NO_EDGE_ON_DEMAND,
    "counter_out/cont_gen_dig_pulse_train.py": Runs(),
    "counter_out/cont_gen_dig_pulse_train_buff_ext_clk.py": Runs(),
    "counter_out/cont_gen_dig_pulse_train_buff_implicit.py": Runs(),
    "counter_out/write_single_dig_pulse.py": Runs(_single_pulse),
    "digital_in/acq_dig_port_int_clk.py": Runs(),
    "digital_in/acq_dig_port_int_clk_wfm.py": Runs(_port0_waveform),
    "digital_in/cont_acq_dig_lines_int_clk.py": Runs(),
    "digital_in/read_dig_lines.py": Runs(),
    "digital_in/read_dig_port.py": Runs(),
    "digital_out/cont_gen_dig_port_int_clk.py": Runs(),
    "digital_out/cont_gen_dig_port_int_clk_wfm.py": Runs(_contains(
        "line  7: [0 0 0 0 0 0 0 1]")),
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
    "synchronization/multi_function/cont_ai_ci_tdms_sync.py": Runs(
        _synchronized, enter_after_s=2.5, own_dir=True),
    "synchronization/multi_function/cont_ai_di_acq.py": Runs(),
    "system_properties.py": Runs(_system),
}


def _start_server(cwd: Path = REPO_ROOT) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "7"],
        cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _address(server: subprocess.Popen[str]) -> str:
    first = server.stdout.readline().strip()  # type: ignore[union-attr]
    assert first.startswith("listening on "), first
    return first.removeprefix("listening on ")


def _stop_server(server: subprocess.Popen[str]) -> None:
    server.send_signal(signal.SIGTERM)
    _, err = server.communicate(timeout=30)
    assert "Traceback" not in err, err[-3000:]


@pytest.fixture(scope="module")
def selected(request: pytest.FixtureRequest) -> list[str]:
    """The examples whose test this session runs (``-k`` may choose a few), sorted. None
    without ../shared (the tests then skip, or fail on CI, through ``shared_dir``)."""
    if not SHARED.is_dir():
        return []
    return sorted({item.callspec.params["example"] for item in request.session.items
                   if getattr(item, "originalname", None) == TEST})


def _example(shared_dir: Path, example: str) -> Path:
    return shared_dir / "reference" / "nidaqmx-python-examples" / example


def _argv(address: str, path: Path, expected: Runs | Refused) -> list[str]:
    loops = expected.loops if isinstance(expected, Runs) else 3
    patience = expected.patience_s if isinstance(expected, Runs) else 30.0
    enter_after = expected.enter_after_s if isinstance(expected, Runs) else 0.0
    return [sys.executable, str(RUNNER), address, str(path), "--loops", str(loops),
            "--patience", str(patience), "--enter-after", str(enter_after)]


def _waits(expected: Runs | Refused) -> bool:
    return isinstance(expected, Refused) and expected.waits_s > 0


class _Lanes:
    """The examples dealt over lanes, each lane (`nidaqmx_example_lane.py`) running its share
    one after another on its own server; `result` reads the example's lane up to its line."""

    def __init__(self, lanes: list[subprocess.Popen[str]], lane_of: dict[str, int]) -> None:
        self.lanes, self.lane_of = lanes, lane_of
        self.ended: dict[str, dict] = {}

    def result(self, example: str) -> tuple[str, str]:
        """The example's stdout and stderr, once it has ended."""
        lane = self.lanes[self.lane_of[example]]
        while example not in self.ended:
            line = lane.stdout.readline()  # type: ignore[union-attr]
            assert line, f"lane {self.lane_of[example]} ended before {example} had run: " \
                         + lane.stderr.read()[-2000:]  # type: ignore[union-attr]
            said = json.loads(line)
            self.ended[said["name"]] = said
        said = self.ended[example]
        assert said["returncode"] is not None, f"{example} did not end within 120 s: " \
            + said["stdout"][-2000:] + said["stderr"][-2000:]
        return said["stdout"], said["stderr"]


@pytest.fixture(scope="module")
def example_lanes(selected: list[str], tmp_path_factory: pytest.TempPathFactory
                  ) -> Iterator[_Lanes]:
    """The selected examples that do not wait on the board, dealt in their sorted order over
    `LANES` lanes, so each lane keeps the table's order (the analog inputs read the rig at rest
    before an analog output moves it: the rig keeps moving between tasks). Each lane's server
    runs in a directory of its own (where a relative log file path lands)."""
    names = [n for n in selected if not _waits(EXPECTED[n])]
    shares = [names[i::LANES] for i in range(min(LANES, len(names)))]
    servers: list[subprocess.Popen[str]] = []
    lanes: list[subprocess.Popen[str]] = []
    try:
        server_dirs = [tmp_path_factory.mktemp("sim-server") for _ in shares]
        servers += [_start_server(d) for d in server_dirs]  # they start at once
        for share, server, server_dir in zip(shares, servers, server_dirs, strict=True):
            address = _address(server)
            jobs = []
            for name in share:
                expected, path = EXPECTED[name], _example(SHARED, name)
                if isinstance(expected, Runs) and expected.own_dir:  # unchanged, byte for byte
                    path = Path(shutil.copy(path, tmp_path_factory.mktemp("own") / path.name))
                in_server_dir = isinstance(expected, Runs) and expected.in_server_dir
                jobs.append({"name": name, "argv": _argv(address, path, expected),
                             "cwd": str(server_dir if in_server_dir else path.parent)})
            jobs_file = server_dir / "lane.json"
            jobs_file.write_text(json.dumps(jobs))
            lanes.append(subprocess.Popen([sys.executable, str(LANE), str(jobs_file), "--timeout",
                                           "120"], stdout=subprocess.PIPE,
                                          stderr=subprocess.PIPE, text=True))
        yield _Lanes(lanes, {n: i for i, share in enumerate(shares) for n in share})
    finally:
        for lane in lanes:  # a lane a failed test left running: stopped, its pipes closed
            if lane.poll() is None:
                lane.kill()
            lane.communicate()
        for server in servers:
            _stop_server(server)


@pytest.fixture(scope="module")
def waiting_runs(selected: list[str]) -> Iterator[dict[str, subprocess.Popen[str]]]:
    """The selected examples that wait on the board (a read's timeout), all started with the
    module: they only wait, so overlapping them costs one wait, not one each. One board cannot
    run two that hold the same input (the examples of one folder use the same one: ai0, ctr0),
    so each server takes at most one example of each folder."""
    by_folder: dict[str, list[str]] = {}
    for name in selected:
        if _waits(EXPECTED[name]):
            by_folder.setdefault(name.split("/")[0], []).append(name)
    lanes = [[names[i] for names in by_folder.values() if i < len(names)]
             for i in range(max(map(len, by_folder.values()), default=0))]
    servers = [_start_server() for _ in lanes]
    try:
        runs = {}
        for lane, server in zip(lanes, servers, strict=True):
            address = _address(server)
            runs.update({name: subprocess.Popen(
                _argv(address, _example(SHARED, name), EXPECTED[name]),
                cwd=_example(SHARED, name).parent, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, text=True) for name in lane})
        yield runs
        for run in runs.values():  # those a failed test left: stopped, their pipes closed
            if run.stdout is not None and not run.stdout.closed:
                run.kill()
                run.communicate()
    finally:
        for server in servers:
            _stop_server(server)


def test_the_table_covers_every_example(shared_dir: Path) -> None:
    examples = shared_dir / "reference" / "nidaqmx-python-examples"
    found = {str(p.relative_to(examples)) for p in examples.rglob("*.py")}
    assert found == set(EXPECTED)


@pytest.mark.parametrize("example", sorted(EXPECTED))
def test_nis_example_runs_or_is_refused_as_the_board_does(
        example: str, shared_dir: Path, waiting_runs: dict[str, subprocess.Popen[str]],
        example_lanes: _Lanes) -> None:
    expected = EXPECTED[example]
    if example in waiting_runs:
        stdout, stderr = waiting_runs[example].communicate(timeout=120)
    else:
        stdout, stderr = example_lanes.result(example)
    lines = [line for line in stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, stdout[-2000:] + stderr[-2000:]
    result = json.loads(lines[-1].removeprefix("RESULT "))
    out = stdout[: stdout.rfind("RESULT ")]
    assert "UNIMPLEMENTED" not in stdout + stderr
    if isinstance(expected, Refused):
        assert (result["status"], result.get("code")) == ("daqerror", expected.code), result
        if expected.waits_s:  # the board answered after the read's timeout, not before
            assert result["wall_s"] >= expected.waits_s, result
    else:
        assert result["status"] == "ok", result
        if expected.check is not None:
            expected.check(result, out)
