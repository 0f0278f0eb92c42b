"""Every command that reads a channel map refuses one the software cannot use in one line naming
the file and the entry, exit 2, before it touches the board (the board's target here answers
nobody: a command that got that far would say so instead); every command that takes
``--grpc-target`` refuses one that is not HOST:PORT, or that nobody answers, in one line, exit 2
(never the "unexpected error" of a defect)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from daq.channels import KNOWN_INPUTS
from sfdrig.cli import main
from tests.conftest import REPO_ROOT

EXAMPLE = REPO_ROOT / "examples" / "channels_report_rig.toml"
DEAD = "127.0.0.1:1"  # nobody listens on port 1


@pytest.fixture(autouse=True)
def _own_locks(tmp_path, monkeypatch):
    monkeypatch.setenv("SFDRIG_RUNTIME_DIR", str(tmp_path / "locks"))


def _bad_map(tmp_path: Path) -> Path:
    path = tmp_path / "x3.toml"
    path.write_text(EXAMPLE.read_text().replace('name = "x2"', 'name = "x3"'))
    return path


def _x3_line(path: Path) -> str:
    return (f"{path}: ai[3] (x3): unknown input name 'x3' (did you mean 'x2'?); the software "
            f"knows {', '.join(KNOWN_INPUTS)}")


@pytest.mark.parametrize("command", [
    ["channels", "check", "{map}", "--grpc-target", DEAD],
    ["channels", "live", "{map}", "--grpc-target", DEAD, "--once"],
    ["channels", "write", "--from", "{map}"],
    ["commission", "{map}", "--backend", "nidaqmx", "--grpc-target", DEAD],
    ["commission", str(EXAMPLE), "--wiring", "{map}"],
    ["commission", "{map}"],
])
def test_a_map_with_an_unknown_name_is_one_line_in_process(tmp_path, capsys, command):
    path = _bad_map(tmp_path)
    argv = [a.replace("{map}", str(path)) for a in command]
    name = " ".join(argv[:2]) if argv[0] == "channels" else argv[0]
    assert main(argv) == 2
    out = capsys.readouterr()
    assert out.err.splitlines() == [f"{name}: {_x3_line(path)}"] and out.out == ""


@pytest.mark.parametrize("command", [
    ["daemon", "--runs-dir", "{tmp}/runs", "--backend", "nidaqmx", "--grpc-target", DEAD,
     "--channels", "{map}"],
    ["sim-server", "--port", "0", "--channels", "{map}"],
])
def test_a_map_with_an_unknown_name_is_one_line_from_the_servers(tmp_path, command):
    path = _bad_map(tmp_path)
    argv = [a.replace("{map}", str(path)).replace("{tmp}", str(tmp_path)) for a in command]
    out = subprocess.run([sys.executable, "-m", "sfdrig", *argv], capture_output=True,
                         text=True, timeout=120, cwd=REPO_ROOT)
    assert (out.returncode, out.stdout) == (2, ""), out
    assert out.stderr.splitlines() == [f"{argv[0]}: {_x3_line(path)}"]


BAD_TARGETS = [
    ("localhost", "not HOST:PORT: no port"),
    (":80", "not HOST:PORT: no host before the port"),
    ("host:notaport", "not HOST:PORT: the port 'notaport' is not a TCP port 1-65535"),
    ("host:70000", "not HOST:PORT: the port '70000' is not a TCP port 1-65535"),
    ("", "not HOST:PORT: no port"),
]


@pytest.mark.parametrize("target,problem", BAD_TARGETS)
@pytest.mark.parametrize("command", [
    ["channels", "check", str(EXAMPLE)],
    ["channels", "live", str(EXAMPLE), "--once"],
    ["commission", str(EXAMPLE), "--backend", "nidaqmx"],
])
def test_a_grpc_target_that_is_not_host_port_is_one_line(capsys, command, target, problem):
    name = " ".join(command[:2]) if command[0] == "channels" else command[0]
    assert main([*command, "--grpc-target", target]) == 2
    out = capsys.readouterr()
    assert out.err == f"{name}: --grpc-target {target!r}: {problem} (e.g. 127.0.0.1:31763)\n"


def test_the_daemon_refuses_a_grpc_target_that_is_not_host_port(tmp_path):
    out = subprocess.run([sys.executable, "-m", "sfdrig", "daemon", "--runs-dir",
                          str(tmp_path / "runs"), "--backend", "nidaqmx", "--grpc-target",
                          "host:notaport"], capture_output=True, text=True, timeout=120,
                         cwd=REPO_ROOT)
    assert (out.returncode, out.stdout) == (2, ""), out
    assert out.stderr == ("daemon: --grpc-target 'host:notaport': not HOST:PORT: the port "
                          "'notaport' is not a TCP port 1-65535 (e.g. 127.0.0.1:31763)\n")


def test_the_daemon_on_a_target_nobody_answers_does_not_ask_for_one(tmp_path):
    """It was given HOST:PORT: no hint to give one (the hint is for the local driver)."""
    out = subprocess.run([sys.executable, "-m", "sfdrig", "daemon", "--runs-dir",
                          str(tmp_path / "runs"), "--backend", "nidaqmx", "--grpc-target", DEAD,
                          "--watchdog-s", "0"], capture_output=True, text=True, timeout=120,
                         cwd=REPO_ROOT)
    assert (out.returncode, out.stdout) == (2, ""), out
    assert out.stderr == f"daemon: no NI gRPC device server answers at {DEAD} (waited 5 s)\n"
