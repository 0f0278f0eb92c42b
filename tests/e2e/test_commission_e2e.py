"""`sfdrig commission --backend nidaqmx` end to end: a real `sfdrig sim-server` process (fast),
wired by its own channel map, the journal out (`--journal out`, as the tool drives it), behind the
real nidaqmx package; the tool is given the shipped example map. The test is the operator: it
presses and releases the emergency stop (SIGUSR1 / SIGUSR2 to the server, the button's wires) when
the tool asks, and answers the tool's questions on its stdin. The correct wiring passes; a few of
the in-process matrix's mis-wirings (tests/control/commissioning) are each exactly their FAIL
line here, exit 1; the guide's rehearsal (docs/real-rig.md, section 6) runs as written."""

from __future__ import annotations

import copy
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daq.channels import load_channel_map
from daq.config_files import to_toml
from tests.e2e.conftest import REPO_ROOT

pytestmark = pytest.mark.e2e

EXAMPLE = REPO_ROOT / "examples" / "channels_report_rig.toml"


def _wiring(tmp_path: Path, change: Callable[[dict[str, Any]], None] | None) -> Path:
    data = copy.deepcopy(load_channel_map(EXAMPLE).model_dump(mode="json", exclude_none=True))
    if change is not None:
        change(data)
    path = tmp_path / "wiring.toml"
    path.write_text(to_toml(data))
    return path


def _swap_x1_y1(data: dict[str, Any]) -> None:
    data["ai"][2]["physical_channel"], data["ai"][4]["physical_channel"] = \
        data["ai"][4]["physical_channel"], data["ai"][2]["physical_channel"]


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Callable[..., tuple[str, int]]]:
    procs: list[subprocess.Popen[str]] = []

    def start(change: Callable[[dict[str, Any]], None] | None = None,
              journal: str = "out") -> tuple[str, int]:
        proc = subprocess.Popen(
            [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "5",
             "--fast", "--channels", str(_wiring(tmp_path, change)), "--journal", journal],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO_ROOT)
        procs.append(proc)
        first = proc.stdout.readline().strip()  # type: ignore[union-attr]
        assert first.startswith("listening on "), first
        return first.removeprefix("listening on "), proc.pid

    yield start
    for proc in procs:
        proc.terminate()
        proc.communicate(timeout=10)


def operate(proc: subprocess.Popen[str], server_pid: int,
            also: Callable[[str], None] = lambda line: None) -> tuple[list[str], str]:
    """Be the operator of a running `sfdrig commission`: the e-stop pressed and released when
    asked (SIGUSR1 / SIGUSR2 to the server), every question answered yes (with a stdin),
    ``also`` told every line. Its stdout lines and stderr, once it has ended."""
    assert proc.stdout is not None
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            if line.startswith("OPERATOR: Press the emergency stop"):
                os.kill(server_pid, signal.SIGUSR1)
            elif line.startswith("OPERATOR: Release the emergency stop"):
                os.kill(server_pid, signal.SIGUSR2)
            elif line.rstrip().endswith("[y/n]") and proc.stdin is not None:
                proc.stdin.write("y\n")
                proc.stdin.flush()
            also(line)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert "Traceback" not in err, err
    return lines, err


def commission(address: str, server_pid: int, out: Path,
               tool_map: Path = EXAMPLE) -> tuple[int, list[str], str]:
    """Run the tool as the operator would (`operate`). Its exit code, stdout lines and
    stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "commission", str(tool_map), "--backend", "nidaqmx",
         "--grpc-target", address, "--out", str(out)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=REPO_ROOT)
    lines, err = operate(proc, server_pid)
    return proc.returncode, lines, err


def fails(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("FAIL")]


def test_the_correct_wiring_passes_through_nidaqmx(server: Any, tmp_path: Path) -> None:
    address, pid = server()
    code, lines, _ = commission(address, pid, tmp_path / "out")
    assert code == 0, "\n".join(lines)
    assert lines[-1] == (f"commissioning passed on the simulated nidaqmx device Dev1 via gRPC "
                         f"{address}: {EXAMPLE}")
    assert "OK   estop (Dev1/port0/line1): read pressed when pressed and released when " \
           "released" in lines
    assert any(line.startswith("OK   watchdog: expired after 1.5 s unfed (timeout 1 s): the "
                               "pump relay off") for line in lines)
    for name, pattern in (("fx", r"2 N at [+-][0-3] deg"), ("x1", r"3\.1\d um at [+-][0-3] deg"),
                          ("fy", r"2 N at [+-][0-3] deg"), ("y2", r"2\.9\d um at [+-][0-3] deg")):
        (line,) = [s for s in lines if s.startswith(f"OK   {name} (") and "drive" in s]
        assert re.search(pattern, line), line
    assert len(list((tmp_path / "out").glob("commission-*.h5"))) == 1
    assert not list((tmp_path / "out").glob("*-proposed.toml"))


def _relay_on_line2(data: dict[str, Any]) -> None:
    data["do"][0]["physical_channel"] = "Dev1/port0/line2"


def _drives_swapped(data: dict[str, Any]) -> None:
    data["ao"][0]["physical_channel"], data["ao"][1]["physical_channel"] = \
        data["ao"][1]["physical_channel"], data["ao"][0]["physical_channel"]


@pytest.mark.parametrize("fault,change,journal,pattern", [
    ("e-stop wired open", lambda d: d.pop("estop"), "out",
     r"FAIL estop \(Dev1/port0/line1\): reads pressed \(low\) before anyone pressed it"),
    ("drives swapped", _drives_swapped, "out",
     r"FAIL shaker_x \(Dev1/ao0\) and shaker_y \(Dev1/ao1\): the drives are swapped: "
     r"shaker_x moved every y sensor"),
    ("pump relay on another line", _relay_on_line2, "out",
     r"FAIL pump \(Dev1/port0/line0\): switched on, nothing followed within 2 s: p_in "),
    ("held housing (the journal in)", None, "in",
     r"FAIL housing: held: the load cells read the drives \(fx 2 N, fy 2 N\) and none of the 6 "
     r"motion sensors moved"),
])
def test_a_miswired_rig_is_named_through_nidaqmx(server: Any, tmp_path: Path, fault: str,
                                                  change: Any, journal: str,
                                                  pattern: str) -> None:
    code, lines, _ = commission(*server(change, journal=journal), tmp_path / "out")
    print(f"{fault}: {fails(lines)}")
    assert code == 1, "\n".join(lines)
    assert len(fails(lines)) == 1, "\n".join(lines)
    assert re.match(pattern, fails(lines)[0]), fails(lines)[0]
    assert lines[-1].startswith("commissioning 1 problem")


def test_a_terminal_configuration_the_board_lacks_is_one_line_before_anything(
        server: Any, tmp_path: Path) -> None:
    """x1 read RSE on a PXIe-6358 (differential only): the board refuses it at configure, one
    line naming the channel and the property, exit 2; no record, nothing driven."""
    text = EXAMPLE.read_text().replace(
        'gain_v_per_unit = 7952.755905511811\noffset_v = -8.5\nrange_v = [-10.0, 10.0]\n'
        'terminal_config = "differential"',
        'gain_v_per_unit = 7952.755905511811\noffset_v = -8.5\nrange_v = [-10.0, 10.0]\n'
        'terminal_config = "rse"')
    assert text.count('"rse"') == 1
    tool = tmp_path / "rse.toml"
    tool.write_text(text)
    code, lines, err = commission(*server(), tmp_path / "out", tool)
    assert code == 2, "\n".join(lines) + err
    (line,) = err.strip().splitlines()
    assert re.match(r"commission: .*AI\.TermCfg, requested value: RSE.*Dev1/ai2", line), line
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").glob("*.h5"))


def test_ctrl_c_during_a_drive_ramps_it_down_and_keeps_the_record(tmp_path: Path) -> None:
    """A paced sim-server (the drive takes 2.1 s of wall time); SIGINT once the X drive is at
    its level: the drive fades to 0 V (recorded), the record closes aborted, exit 130."""
    from storage import open_run

    server = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--seed", "5",
         "--channels", str(EXAMPLE), "--journal", "out"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO_ROOT)
    try:
        first = server.stdout.readline().strip()  # type: ignore[union-attr]
        assert first.startswith("listening on "), first
        out = tmp_path / "out"
        proc = subprocess.Popen(
            [sys.executable, "-m", "sfdrig", "commission", str(EXAMPLE), "--backend",
             "nidaqmx", "--grpc-target", first.removeprefix("listening on "), "--watchdog-s",
             "0", "--pump-s", "0.5", "--yes", "--out", str(out)],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, cwd=REPO_ROOT)

        def interrupt(line: str) -> None:
            if line.startswith("drive x: at 2 N"):  # 1.8 s of drive left
                proc.send_signal(signal.SIGINT)

        lines, err = operate(proc, server.pid, interrupt)
    finally:
        server.terminate()
        server.communicate(timeout=10)
    assert proc.returncode == 130, "\n".join(lines) + err
    assert "Traceback" not in err
    assert re.search(r"commission: drive x: interrupted; the drive ramped down to 0 V; record ",
                     err), err
    (record,) = out.glob("commission-*.h5")
    with open_run(record) as run:
        assert run.status == "aborted"
        drive = run.channel("shaker_x")
        fx = run.channel("fx")
    assert float(np.max(np.abs(drive))) > 0.03  # the drive had begun (0.04 V for 2 N)
    tail = int(0.02 * 10_000)  # the last block recorded: the fade is over
    assert float(np.max(np.abs(drive[-tail:]))) == 0.0
    assert float(np.max(np.abs(np.diff(drive)))) < 0.04 * 2 * np.pi * 20 / 10_000 * 1.5 + 1e-4
    assert float(np.max(np.abs(fx[-tail:]))) < 0.3  # the load cell: noise, no drive


def _guide_rehearsal() -> tuple[list[str], list[str], str]:
    """The guide's rehearsal (docs/real-rig.md, section 6): the sim-server's and commission's
    argument lists as written, and the paragraph that tells the operator what to do."""
    text = (REPO_ROOT / "docs" / "real-rig.md").read_text()
    at = text.index("Rehearse it first on the simulated board")
    block = text[text.index("```bash", at):]
    block = block[len("```bash"):block.index("```", len("```bash"))]
    commands = [line.strip() for line in block.splitlines() if line.strip()]
    server, tool = commands
    assert server.startswith("sfdrig sim-server ") and server.endswith(" &"), server
    assert tool.startswith("sfdrig commission "), tool
    after = text[text.index("```", text.index("```bash", at) + 7) + 3:]
    return (shlex.split(server.removesuffix("&"))[1:], shlex.split(tool)[1:],
            after[:after.index("Nothing is driven")])


@pytest.mark.paced  # the guide starts the server in real time: the AO leads the wall clock
def test_the_guides_rehearsal_runs_as_written_and_passes(tmp_path: Path) -> None:
    """The two commands of the guide, as written (real time, as the guide starts the server),
    from a directory holding the example map; the operator does what the guide says (the
    e-stop by SIGUSR1 / SIGUSR2 to the server, y to every question). Passed, exit 0, the
    verdict and the report naming the simulated device."""
    server_args, tool_args, says = _guide_rehearsal()
    assert "kill -USR1 %1" in says and "kill -USR2 %1" in says and "answer `y`" in says
    (tmp_path / "examples").mkdir()
    shutil.copy(EXAMPLE, tmp_path / "examples" / EXAMPLE.name)
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    server = subprocess.Popen([sys.executable, "-m", "sfdrig", *server_args],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                              cwd=tmp_path, env=env)
    try:
        first = server.stdout.readline().strip()  # type: ignore[union-attr]
        assert first.startswith("listening on 127.0.0.1:"), first
        port = first.rsplit(":", 1)[1]
        args = [a.replace("127.0.0.1:PORT", f"127.0.0.1:{port}") for a in tool_args]
        proc = subprocess.Popen([sys.executable, "-m", "sfdrig", *args], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=tmp_path, env=env)
        lines, err = operate(proc, server.pid)
    finally:
        server.terminate()
        server.communicate(timeout=10)
    assert proc.returncode == 0, "\n".join(lines) + err
    board = f"simulated nidaqmx device Dev1 via gRPC 127.0.0.1:{port}"
    assert lines[-1] == f"commissioning passed on the {board}: examples/channels_report_rig.toml"
    assert not fails(lines)
    (report,) = (tmp_path / "out" / "commission").glob("commission-*.md")
    assert report.read_text().startswith(
        f"# Commissioning of examples/channels_report_rig.toml on the {board}: PASSED\n")
