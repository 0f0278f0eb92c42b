"""The command line loads only the module of the command it runs."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from sfdrig.cli import COMMAND_MODULES, _module_of, build_parser, main


@pytest.mark.parametrize("module", COMMAND_MODULES)
def test_every_command_name_finds_its_module(module: str) -> None:
    name = importlib.import_module(f"sfdrig.commands.{module}").NAME
    assert _module_of([name, "--help"]) == module


def test_no_command_or_an_unknown_one_loads_every_command() -> None:
    assert _module_of([]) is None
    assert _module_of(["--help"]) is None
    assert _module_of(["bogus"]) is None
    names = set(build_parser()._subparsers._group_actions[0].choices)  # type: ignore[union-attr]
    assert len(names) == len(COMMAND_MODULES)


def test_the_web_command_does_not_load_the_simulator() -> None:
    # a fresh interpreter: what `sfdrig web` imports before it serves
    code = ("import sys; from sfdrig.cli import build_parser, _module_of; "
            "build_parser(_module_of(['web'])).parse_args(['web', '--port', '0']); "
            "print(sorted(m for m in ('numba', 'h5py', 'rig_model', 'simulated_hw', 'analysis') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


def run_into_a_closed_pipe(*args: str, **kwargs) -> subprocess.CompletedProcess[str]:
    """``sfdrig ARGS | head -0``: stdout is a pipe whose reader has already gone."""
    import os

    read, write = os.pipe()
    os.close(read)
    try:
        return subprocess.run([sys.executable, "-m", "sfdrig", *args], stdout=write,
                              stderr=subprocess.PIPE, text=True, timeout=120, **kwargs)
    finally:
        os.close(write)


@pytest.mark.parametrize("args", [["--help"], ["identify", "--help"]])
def test_help_into_a_closed_pipe_ends_quietly(args: list[str]) -> None:
    out = run_into_a_closed_pipe(*args)  # argparse swallows it; the exit flush must too
    assert out.returncode in (0, 141) and out.stderr == ""


def test_structure_into_a_closed_pipe_completes_its_tests_and_ends_quietly(tmp_path) -> None:
    """`sfdrig structure --unattended | head -0`: the test runs to its end and its file is
    closed, then exit 141 with nothing on stderr, as `export` (once "sfdrig structure: [Errno
    32] Broken pipe", exit 2, and the run file left "running")."""
    import h5py

    out = run_into_a_closed_pipe("structure", "--unattended", "--only", "impact", "--out",
                                 str(tmp_path))
    assert (out.returncode, out.stderr) == (141, "")
    (run,) = tmp_path.glob("*.h5")
    with h5py.File(run, "r") as f:
        assert f.attrs["status"] == "completed" and f.attrs["kind"] == "impact"


def test_default_outputs_go_where_git_ignores_them() -> None:
    """Issue 21: `sfdrig demo` and `sfdrig calibrate` wrote into the repository root, not
    ignored. Every command's default --out (and run directory) must be ignored by git."""
    import argparse
    import shutil
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    if shutil.which("git") is None or not (root / ".git").exists():
        pytest.skip("not a git checkout")
    defaults = {}
    for name, sub in build_parser()._subparsers._group_actions[0].choices.items():  # type: ignore[union-attr]
        assert isinstance(sub, argparse.ArgumentParser)
        for action in sub._actions:
            if action.dest in ("out", "runs_dir") and isinstance(action.default, Path):
                defaults[f"{name} --{action.dest}"] = action.default
    assert defaults["demo --out"] == Path("out/demo")
    assert defaults["calibrate --out"] == Path("out/calibration")
    for what, path in defaults.items():
        probe = path / "probe.json"  # a file the command would write there
        ignored = subprocess.run(["git", "check-ignore", "-q", str(probe)], cwd=root)
        assert ignored.returncode == 0, f"{what}: {path} is not ignored by .gitignore"


def test_an_error_no_command_answers_is_one_line_and_a_kept_traceback(monkeypatch, capsys
                                                                      ) -> None:
    """A defect that escapes a command (here `sfdrig runs` made to raise) ends in one line that
    names it and where its traceback is kept, exit 70, never a traceback on the terminal."""
    import sfdrig.commands.runs as runs

    def broken(args):
        raise KeyError("steps")

    monkeypatch.setattr(runs, "run", broken)
    assert main(["runs", "--runs-dir", "."]) == 70
    err = capsys.readouterr().err
    assert err.startswith("sfdrig runs: unexpected error: KeyError: 'steps' (a defect: please "
                          "report it with ")
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    kept = Path(err.strip().rsplit(" ", 1)[1].rstrip(")"))
    try:
        text = kept.read_text()
        assert "Traceback" in text and "raise KeyError" in text
    finally:
        kept.unlink()


@pytest.mark.parametrize("command, inner, argv", [
    ("calibrate", "_run", ["calibrate"]),
    ("identify", "_run", ["identify", "r.h5"]),
    ("diagnose", "_run", ["diagnose", "r.h5"]),
    ("export", "export_run", ["export", "r.h5", "--to", "csv", "--out", "o"]),
    ("import_data", "_import_one", ["import", "d.csv", "--out", "r.h5"]),
])
def test_a_closed_stdout_is_never_an_error_of_the_command(monkeypatch, capsys, command: str,
                                                          inner: str, argv: list[str]) -> None:
    """Commands that answer their own errors (OSError among them, or one line per file) let a
    closed stdout through to the CLI: quietly, 141 (once "error: r.h5: BrokenPipeError", 2)."""
    import importlib

    mod = importlib.import_module(f"sfdrig.commands.{command}")

    def reader_gone(*args, **kwargs):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(mod, inner, reader_gone)
    if command == "export":
        monkeypatch.setattr(mod, "_size", lambda path: 0)
    assert main(argv) == 141
    assert capsys.readouterr().err == ""
