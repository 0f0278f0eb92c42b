"""`sfdrig channels` end to end: real processes, `sfdrig sim-server` (wired as the shipped
example) behind the real nidaqmx package. Deliberately wrong maps are each named in one line
with the channel and its physical channel; correct maps pass with exit 0; bad files give one
line naming the file and the place, never a traceback; `live --once` shows the inputs at rest
in engineering units."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from daq.channels import default_channel_map, load_channel_map
from daq.config_files import to_toml
from tests.e2e.conftest import REPO_ROOT

pytestmark = pytest.mark.e2e

EXAMPLE = REPO_ROOT / "examples" / "channels_report_rig.toml"


def sfdrig(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sfdrig", *args], capture_output=True,
                          text=True, timeout=120, cwd=REPO_ROOT)


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    """`sfdrig sim-server --fast` wired as the shipped example; its address."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "3", "--fast",
         "--channels", str(EXAMPLE)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO_ROOT)
    first = proc.stdout.readline().strip()  # type: ignore[union-attr]
    try:
        assert first.startswith("listening on "), first
        yield first.removeprefix("listening on ")
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


def _map(tmp_path: Path, change: Callable[[dict[str, Any]], None]) -> Path:
    data = load_channel_map(EXAMPLE).model_dump(mode="json", exclude_none=True)
    change(data)
    path = tmp_path / "map.toml"
    path.write_text(to_toml(data))
    return path


def _x2(data: dict[str, Any], **update: Any) -> None:
    data["ai"][3].update(update)


@pytest.mark.parametrize("change,line", [
    # a physical channel the device lacks (the map claims a 32-input board)
    (lambda d: (d["device"].update(ai_count=32), _x2(d, physical_channel="Dev1/ai20")),
     "ai x2 (Dev1/ai20): Dev1 (PXIe-6358) has no such AI channel (its AI channels: Dev1/ai0 "
     "to Dev1/ai15)"),
    # a range the device does not have: DAQmx would measure on +/-5 V
    (lambda d: _x2(d, range_v=[-3.0, 3.0], offset_v=0.0),
     "ai x2 (Dev1/ai3): range_v (-3, 3) V is not an AI range of Dev1 (PXIe-6358) (+/-1, "
     "+/-2, +/-5, +/-10 V): DAQmx would measure on (-5, 5) V; write that"),
    (lambda d: d["ao"][1].update(range_v=[-7.0, 7.0]),
     "ao shaker_y (Dev1/ao1): range_v (-7, 7) V is not an AO range of Dev1 (PXIe-6358) "
     "(+/-5, +/-10 V): DAQmx would measure on (-10, 10) V; write that"),
    # a terminal configuration the device does not allow
    (lambda d: _x2(d, terminal_config="rse"),
     "ai x2 (Dev1/ai3): terminal_config 'rse' is not allowed on Dev1/ai3 (it allows "
     "differential)"),
    # the gap voltage outside the range: the probe reads clipped at rest
    (lambda d: _x2(d, range_v=[-5.0, 5.0]),
     "ai x2 (Dev1/ai3): offset_v -8.5 V (the sensor's output at zero) is outside range_v "
     "(-5, 5) V: the input reads clipped at rest"),
    # a digital line the device lacks
    (lambda d: d["estop"].update(physical_channel="Dev1/port1/line0") or d["device"].update(
        do_ports=2), "estop estop (Dev1/port1/line0): Dev1 (PXIe-6358) has no such digital "
                     "line (its digital lines: Dev1/port0/line0 to Dev1/port0/line7)"),
])
def test_check_names_each_mistake_in_one_line(server, tmp_path, change, line):
    path = _map(tmp_path, change)
    res = sfdrig("channels", "check", str(path), "--grpc-target", server)
    assert res.returncode == 1, res
    assert res.stdout.splitlines() == [line, f"{path}: 1 problem on Dev1 on {server}"]
    assert res.stderr == ""


def test_check_a_map_wired_twice_names_both_channels(server, tmp_path):
    path = _map(tmp_path, lambda d: (_x2(d, physical_channel="Dev1/ai2"),
                                     d["ai"][7].update(physical_channel="Dev1/ai6")))
    res = sfdrig("channels", "check", str(path), "--grpc-target", server)
    assert res.returncode == 2
    assert res.stderr.splitlines() == [
        f"channels check: {path}: ai[3] (x2): duplicate physical_channel 'Dev1/ai2' "
        "(also ai[2] (x1))",
        f"channels check: {path}: ai[7] (ay): duplicate physical_channel 'Dev1/ai6' "
        "(also ai[6] (ax))",
    ]


def test_check_a_device_that_is_not_there_names_every_channel(server, tmp_path):
    path = _map(tmp_path, lambda d: d.update(
        device={**d["device"], "name": "Dev2"},
        **{g: [{**c, "physical_channel": c["physical_channel"].replace("Dev1", "Dev2")}
               for c in d[g]] for g in ("ai", "ao", "do")},
        estop={**d["estop"], "physical_channel": "Dev2/port0/line1"}))
    res = sfdrig("channels", "check", str(path), "--grpc-target", server)
    assert res.returncode == 1
    lines = res.stdout.splitlines()
    assert len(lines) == 14 + 2 + 1 + 1 + 1
    assert lines[0] == f"ai fx (Dev2/ai0): no device 'Dev2' on {server} (it has Dev1)"
    assert lines[-2] == f"estop estop (Dev2/port0/line1): no device 'Dev2' on {server} " \
                        "(it has Dev1)"


def test_correct_maps_pass(server, tmp_path):
    written = tmp_path / "default.toml"
    res = sfdrig("channels", "write", str(written))
    assert res.returncode == 0 and res.stdout == \
        f"wrote {written}: 14 inputs, 2 drives, 1 relay\n"
    assert load_channel_map(written) == default_channel_map()
    for path, tail in ((written, "14 inputs, 2 drives, 1 relay"),
                       (EXAMPLE, "14 inputs, 2 drives, 1 relay, an emergency stop")):
        res = sfdrig("channels", "check", str(path), "--grpc-target", server)
        assert (res.returncode, res.stderr) == (0, ""), res
        assert res.stdout == f"{path}: fits Dev1 on {server}: {tail}\n"


def test_write_refuses_to_overwrite_and_writes_the_example_in_full(tmp_path):
    out = tmp_path / "m.toml"
    out.write_text("keep")
    res = sfdrig("channels", "write", str(out))
    assert res.returncode == 2 and out.read_text() == "keep"
    assert res.stderr == f"channels write: {out} exists; give --force to overwrite it\n"
    res = sfdrig("channels", "write", "--from", str(EXAMPLE), str(out), "--force")
    assert res.returncode == 0
    assert load_channel_map(out) == load_channel_map(EXAMPLE)


@pytest.mark.parametrize("content,line", [
    (None, "{path}: cannot read: No such file or directory"),
    ("sample_rate_hz = = 3\n", "{path}: not valid TOML: Invalid value (at line 1, column 18)"),
    ("UNKNOWN", "{path}: ai.3.bogus = 1: Extra inputs are not permitted"),
])
@pytest.mark.parametrize("action", ["check", "live"])
def test_bad_files_give_one_line_with_the_file_and_the_place(tmp_path, content, line, action):
    path = tmp_path / "map.toml"
    if content == "UNKNOWN":
        path = _map(tmp_path, lambda d: _x2(d, bogus=1))
    elif content is not None:
        path.write_text(content)
    res = sfdrig("channels", action, str(path), "--grpc-target", "127.0.0.1:9")
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr == f"channels {action}: {line.format(path=path)}\n"


def _table(stdout: str) -> dict[str, list[str]]:
    rows = [r.split() for r in stdout.splitlines()[1:-1]]
    return {r[0]: r[1:] for r in rows}


def test_live_once_shows_the_inputs_at_rest_in_engineering_units(server):
    res = sfdrig("channels", "live", str(EXAMPLE), "--grpc-target", server, "--once")
    assert (res.returncode, res.stderr) == (0, ""), res
    lines = res.stdout.splitlines()
    assert lines[0].split() == ["input", "physical", "mean", "std", "unit", "volts",
                                "range", "[V]"]
    assert lines[-1].startswith("1000 samples per input at 10000 S/s")
    rows = _table(res.stdout)
    assert list(rows) == [c.name for c in load_channel_map(EXAMPLE).ai]
    # probes: the -8.5 V gap voltage is the map's offset_v, so at rest they read 0 um
    for probe in ("x1", "x2", "y1", "y2"):
        phys, mean, std, unit, volts = rows[probe][:5]
        assert unit == "um" and abs(float(mean)) < 0.02 and float(std) < 0.1
        assert float(volts) == pytest.approx(-8.5, abs=1e-3)
    assert rows["t_oil"][3] == "degC" and float(rows["t_oil"][1]) == pytest.approx(24.0, abs=0.05)
    assert rows["p_in"][3] == "kPa" and abs(float(rows["p_in"][1])) < 0.05
    assert float(rows["p_in"][4]) == pytest.approx(1.0, abs=1e-3)  # 4 mA across 250 ohm
    assert rows["fx"][3] == "N" and abs(float(rows["fx"][1])) < 0.01 \
        and float(rows["fx"][2]) < 0.1
    assert "AT" not in res.stdout


def test_live_once_with_the_gap_voltage_left_out_reads_a_millimetre(server, tmp_path):
    """The default map (offset_v 0) on probes that sit at -8.5 V: -8.5 V / 7.95 V/mm."""
    path = _map(tmp_path, lambda d: [c.update(offset_v=0.0) for c in d["ai"][2:6]])
    res = sfdrig("channels", "live", str(path), "--grpc-target", server, "--once")
    assert res.returncode == 0, res
    x1 = _table(res.stdout)["x1"]
    # -1068.8 um, shown to 4 digits
    assert float(x1[1]) == pytest.approx(-8.5 / (0.202 / 25.4e-6) * 1e6, abs=0.6)


def test_live_once_flags_an_input_at_its_range_limit(server, tmp_path):
    path = _map(tmp_path, lambda d: _x2(d, range_v=[-5.0, 5.0]))
    res = sfdrig("channels", "live", str(path), "--grpc-target", server, "--once")
    assert res.returncode == 0, res
    flagged = [r.split()[0] for r in res.stdout.splitlines() if r.endswith("AT RANGE LIMIT")]
    assert flagged == ["x2"]
    assert float(_table(res.stdout)["x2"][4]) == pytest.approx(-5.0, abs=1e-3)


def test_live_refreshes_until_ctrl_c_and_ends_cleanly(server):
    proc = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "channels", "live", str(EXAMPLE), "--grpc-target",
         server, "--period-s", "0.1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT)
    tables = 0
    for line in proc.stdout:  # type: ignore[union-attr]
        tables += line.startswith("1000 samples per input")
        if tables == 2:  # a second table: it refreshes
            break
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert tables == 2
    assert proc.returncode == 0
    assert err == "channels live: stopped\n"
