"""The README's "Using it" block and docs/run-files.md's commands, run as a user types them.

Each line of the block is read out of the page (so a page that drifts from the product fails
here) and run by bash in a fresh folder (the repository's `examples/` beside it, as in a clone's
root; the venv's `sfdrig` first on PATH); `sfdrig daemon &` starts the paced simulated daemon the
rest of the block talks to. Every line is then held to what its comment says, with numbers from
its output and the files it leaves. The run files the block makes are what docs/run-files.md's
commands then export, import back and read with h5py."""

from __future__ import annotations

import json
import os
import re
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io

from storage.reader import open_run

pytestmark = [pytest.mark.e2e, pytest.mark.paced]

REPO_ROOT = Path(__file__).resolve().parents[2]
VENV_BIN = Path(sys.executable).parent


def fenced_block(page: Path, heading: str, lang: str, nth: int = 0) -> list[str]:
    """The lines of the ``nth`` ```lang block under ``heading`` (up to the next heading of its
    level or higher)."""
    lines = page.read_text().splitlines()
    level = heading.split()[0]
    start = lines.index(heading)
    fenced = False  # a "# comment" inside a code block is no heading
    end = len(lines)
    for i in range(start + 1, len(lines)):
        fenced ^= lines[i].startswith("```")
        if not fenced and lines[i].startswith("#") and lines[i].split()[0] <= level \
                and set(lines[i].split()[0]) == {"#"}:
            end = i
            break
    blocks: list[list[str]] = []
    inside: list[str] | None = None
    for line in lines[start + 1:end]:
        if inside is None and line.strip() == f"```{lang}":
            inside = []
        elif inside is not None and line.strip() == "```":
            blocks.append(inside)
            inside = None
        elif inside is not None:
            inside.append(line)
    assert len(blocks) > nth, f"{page.name}: no ```{lang} block {nth} under {heading!r}"
    return blocks[nth]


def command_of(line: str) -> str:
    """The command of a block line: without its trailing comment (`  # ...`)."""
    return re.split(r"\s+#\s", line, maxsplit=1)[0].strip()


@dataclass
class Shell:
    """A fresh folder with the clone's examples beside it, and the venv's sfdrig on PATH."""

    cwd: Path
    env: dict[str, str] = field(default_factory=dict)
    daemon: subprocess.Popen[str] | None = None

    def run(self, line: str, timeout_s: float = 300) -> tuple[subprocess.CompletedProcess[str],
                                                                float]:
        started = time.monotonic()
        out = subprocess.run(["bash", "-c", line], cwd=self.cwd, env=self.env, text=True,
                             capture_output=True, timeout=timeout_s)
        assert "Traceback" not in out.stderr, (line, out.stderr)
        return out, time.monotonic() - started

    def start_background(self, line: str, timeout_s: float = 120) -> str:
        """Run ``line`` (ending in ``&``) as the background process it asks for; its first stdout
        line (the daemon's endpoints), read with a poll timeout."""
        cmd = command_of(line)
        assert cmd.endswith("&"), line
        stderr = open(self.cwd / "daemon.stderr", "w")  # noqa: SIM115
        self.daemon = subprocess.Popen(["bash", "-c", f"exec {cmd[:-1].strip()}"], cwd=self.cwd,
                                       env={**self.env, "PYTHONUNBUFFERED": "1"}, text=True,
                                       stdout=subprocess.PIPE, stderr=stderr)
        stderr.close()
        sel = selectors.DefaultSelector()
        sel.register(self.daemon.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
        try:
            assert sel.select(timeout_s), f"{cmd}: no endpoints within {timeout_s} s"
            return self.daemon.stdout.readline()  # type: ignore[union-attr]
        finally:
            sel.close()

    def stop_daemon(self) -> int | None:
        if self.daemon is None:
            return None
        if self.daemon.poll() is None:
            self.daemon.send_signal(signal.SIGTERM)
        try:
            return self.daemon.wait(60)
        finally:
            if self.daemon.poll() is None:
                self.daemon.kill()
                self.daemon.wait(10)
            self.daemon.communicate(timeout=10)


def fresh_shell(folder: Path) -> Shell:
    folder.mkdir(parents=True)
    (folder / "examples").symlink_to(REPO_ROOT / "examples")
    env = {k: v for k, v in os.environ.items() if not k.startswith("SFDRIG_")}
    env["PATH"] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    return Shell(folder, env)


def run_rows(shell: Shell) -> list[dict]:
    out, _ = shell.run("sfdrig runs --json")
    assert out.returncode == 0, out.stdout + out.stderr
    return json.loads(out.stdout)


#: the README block's commands, in order: what the test holds each one to is below
README_COMMANDS = [
    "sfdrig daemon &",
    "sfdrig status",
    "sfdrig pump on",
    "sfdrig sweep examples/lubricated_x.toml --set amplitude_m=[25e-6]",
    "sfdrig pump off --wait",
    "sfdrig sweep --set motion=circular_forward --set load_n=[40.0] "
    "--set freq_hz=[20.0,80.0,100.0]",
    "sfdrig sweep examples/dry_circular.toml --no-follow",
    "sfdrig watch --count 3",
    "sfdrig abort",
    "sfdrig runs",
    "sfdrig identify runs/*.h5 --report out/report --json out/report.json",
    "sfdrig export runs/*.h5 --to mat --out out/export",
]


def sweep_lines(out: subprocess.CompletedProcess[str]) -> tuple[str, list[str], str, str]:
    """(run id, the step result lines, the peak line, the last line) of `sfdrig sweep`."""
    assert out.returncode == 0, out.stdout + out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("run ") and lines[0].endswith(".h5"), lines[0]
    steps = [ln for ln in lines if re.match(r"step \d+/\d+ ", ln)]
    peaks = [ln for ln in lines if ln.startswith("peak orbit ")]
    assert len(peaks) == 1, out.stdout
    return lines[0].split()[1], steps, peaks[0], lines[-1]


@pytest.fixture(scope="module")
def readme_session(tmp_path_factory) -> Iterator[Shell]:
    """The README's block, run and checked line by line; the folder it leaves."""
    block = fenced_block(REPO_ROOT / "README.md", "## Using it", "bash")
    assert [command_of(ln) for ln in block] == README_COMMANDS, \
        "the README's 'Using it' block changed: hold each new line to its comment here"
    shell = fresh_shell(tmp_path_factory.mktemp("readme") / "clone")
    try:
        _run_the_readme_block(shell, block)
        yield shell
    finally:
        code = shell.stop_daemon()
    # Ctrl-C or SIGTERM on the daemon: the safe way out (the README's promise below the block)
    assert code == 0, (shell.cwd / "daemon.stderr").read_text()
    assert not (shell.cwd / "runs" / "daemon.json").exists()


def _run_the_readme_block(shell: Shell, block: list[str]) -> None:  # noqa: PLR0915
    it = iter(block)
    # the simulated rig, paced to the wall clock, on loopback; prints its endpoints
    endpoints = shell.start_background(next(it))
    assert re.fullmatch(r"command=tcp://127\.0\.0\.1:\d+ data=tcp://127\.0\.0\.1:\d+ "
                        r"board='simulated rig \(in process\)'\n", endpoints), endpoints
    # state, pump, last run, found through runs/daemon.json
    out, _ = shell.run(next(it))
    assert out.returncode == 0, out.stdout + out.stderr
    assert "state      idle" in out.stdout and "pump       off" in out.stdout
    assert "board      simulated rig (in process)" in out.stdout
    assert "endpoints  " + endpoints.split(" board=")[0] in out.stdout
    # pump on
    out, _ = shell.run(next(it))
    assert (out.returncode, out.stdout.strip()) == (0, "pump on"), out.stdout + out.stderr
    # the report's X programme at 25 um: a line per step, then the run's peaks
    out, wall_s = shell.run(next(it))
    lub_id, steps, peak, last = sweep_lines(out)
    assert [float(s.split()[2]) for s in steps] == [20.0, 30.0, 40.0, 50.0, 60.0], steps
    for s in steps:
        achieved = float(s.split("achieved x")[1].split()[0])
        assert abs(achieved - 25.0) <= 0.25 and s.endswith("converged"), s  # the 1 % band
    assert peak.startswith("peak orbit ") and "no journal-housing contact" in peak, peak
    assert last == f"run {lub_id} completed (5 steps)"
    with open_run(shell.cwd / "runs" / f"{lub_id}.h5") as run:
        assert run.attrs["lubricated"]
        recorded_s = run.n_samples / run.sample_rate_hz
    assert wall_s >= recorded_s > 5.0, (wall_s, recorded_s)  # paced: no faster than the clock
    # the film drains (30 s): a dry sweep is refused until it has
    line = next(it)
    out, wall_s = shell.run(line)
    assert out.returncode == 0, out.stdout + out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "pump off" and lines[-1].startswith("film drained ("), lines
    drains_s = float(lines[1].split()[3])
    assert 28.0 <= drains_s <= 30.0 and wall_s >= drains_s - 0.5, (lines, wall_s)
    status, _ = shell.run("sfdrig status --json")
    assert json.loads(status.stdout)["film_drains_for_s"] == 0
    # a dry circular 40 N sweep, no file needed
    out, _ = shell.run(next(it))
    dry_id, steps, peak, last = sweep_lines(out)
    assert [float(s.split()[2]) for s in steps] == [20.0, 80.0, 100.0], out.stdout
    for s in steps:
        fx, fy = (float(s.split(f"{k} ")[1].split()[0]) for k in ("  fx", "  fy"))
        assert abs(fx - 40.0) <= 0.4 and abs(fy - 40.0) <= 0.4, s
    assert last == f"run {dry_id} completed (3 steps)"
    with open_run(shell.cwd / "runs" / f"{dry_id}.h5") as run:
        assert not run.attrs["lubricated"]
    # start a sweep and return to the prompt
    out, wall_s = shell.run(next(it))
    assert out.returncode == 0, out.stdout + out.stderr
    started = out.stdout.splitlines()
    assert len(started) == 1 and started[0].startswith("run "), started
    aborted_id = started[0].split()[1]
    # live per-channel amplitudes and the current step
    out, _ = shell.run(next(it))
    assert out.returncode == 0, out.stdout + out.stderr
    tables = [ln for ln in out.stdout.splitlines() if ln.startswith("state ")]
    assert len(tables) == 3 and all(f"state running  run {aborted_id}" in t for t in tables)
    planned = {20.0, 70.0, 80.0, 90.0, 100.0, 120.0, 140.0, 160.0, 180.0, 200.0}  # the file's
    for t in tables:  # "sweep [bar] 2/20 steps done | step 3:   80.0 Hz updates ..."
        m = re.search(r" \d+/(\d+) steps done \| step (\d+): +([\d.]+) Hz", t)
        assert m and m[1] == "20" and 1 <= int(m[2]) <= 20 and float(m[3]) in planned, t
    rows = [ln.split()[0] for ln in out.stdout.splitlines() if ln.startswith("  ")]
    assert rows.count("fx") == 3 and rows.count("x1") == 3, out.stdout
    # the drives ramp to zero within 100 ms; the run is marked aborted
    out, _ = shell.run(next(it))
    assert out.returncode == 0 and out.stdout.startswith("abort sent"), out.stdout + out.stderr
    deadline = time.monotonic() + 30  # the ramp and the file's close: the daemon says when done
    while json.loads(shell.run("sfdrig status --json")[0].stdout)["state"] != "idle":
        assert time.monotonic() < deadline, "the daemon did not end the aborted run within 30 s"
    # the catalog: id, date, kind, steps, status, file
    out, _ = shell.run(next(it))
    assert out.returncode == 0, out.stdout + out.stderr
    catalog = {ln.split()[0]: ln.split() for ln in out.stdout.splitlines()[1:]}
    assert out.stdout.splitlines()[0].split() == ["id", "date", "kind", "steps", "status",
                                                  "duration", "conditions", "file"]
    assert [catalog[i][5] for i in (lub_id, dry_id, aborted_id)] == [  # the date is 2 words
        "completed", "completed", "aborted"], out.stdout
    with open_run(shell.cwd / "runs" / f"{aborted_id}.h5") as run:
        abort_at = next(e["sample"] for e in run.events if e["kind"] == "abort")
        fs = run.sample_rate_hz
    with h5py.File(shell.cwd / "runs" / f"{aborted_id}.h5", "r") as f:
        for name in f["drive"]:
            moving = np.flatnonzero(f["drive"][name][abort_at:])
            ramp_ms = 1e3 * (moving[-1] + 1) / fs if moving.size else 0.0
            assert ramp_ms <= 100.0, (name, ramp_ms)
    # the report's coefficients: dry seal and film
    out, _ = shell.run(next(it))
    assert out.returncode == 0, out.stdout + out.stderr
    report = json.loads((shell.cwd / "out" / "report.json").read_text())
    assert (shell.cwd / "out" / "report" / "index.html").is_file()
    truth = report["simulated_reference"]
    film = report["lubricated"]["sfd_damping_by_amplitude"][0]
    assert film["n_points"] == 5 and abs(film["amplitude_m"] - 25e-6) < 0.25e-6, film
    simulated = report["lubricated"]["predictions"]["by_amplitude"][0]
    c_sfd = film["stick_slip"]["C_sfd_mean_Ns_per_m"]
    assert abs(c_sfd / simulated["simulated_energy_equivalent_Ns_per_m"] - 1) < 0.05, film
    assert report["dry"] is not None, report["skipped"]
    seal = report["dry"]["table4"]["identified"]
    assert abs(seal["F_mu_N"] - truth["F_mu_N"]) < 0.05 * truth["F_mu_N"], seal
    # one RUN.mat each
    out, _ = shell.run(next(it))
    assert out.returncode == 0, out.stdout + out.stderr
    for run_id in (lub_id, dry_id, aborted_id):
        mat = scipy.io.loadmat(shell.cwd / "out" / "export" / f"{run_id}.mat")
        with open_run(shell.cwd / "runs" / f"{run_id}.h5") as run:
            assert float(mat["Fs"].squeeze()) == run.sample_rate_hz
            assert mat["time_s"].size == run.n_samples
    assert next(it, None) is None


def test_the_readme_block_runs_and_each_line_does_what_it_says(readme_session):
    """The fixture runs and checks the block; here the daemon is still up and idle after it."""
    status, _ = readme_session.run("sfdrig status --json")
    assert json.loads(status.stdout)["state"] == "idle"


RUN_FILES_COMMANDS = [
    "sfdrig export runs/*.h5 --to csv --out out/csv",
    "sfdrig export runs/*.h5 --to tdms --channels fx,x1 --out out/tdms",
    "mkdir -p imported",
    "sfdrig import out/export/*.mat --out imported/",
    "sfdrig runs --runs-dir imported",
]


def test_the_run_files_page_commands_run_on_the_readme_runs(readme_session):
    """docs/run-files.md's commands, on the runs the README's block left; then its h5py example
    on the lubricated one (copied to the name the page reads)."""
    shell = readme_session
    page = REPO_ROOT / "docs" / "run-files.md"
    block = fenced_block(page, "## Try it", "bash")
    assert [command_of(ln) for ln in block] == RUN_FILES_COMMANDS
    made = {r["id"]: r for r in run_rows(shell)}
    for line in block:
        out, _ = shell.run(line)
        assert out.returncode == 0, (line, out.stdout + out.stderr)
    for run_id, row in made.items():
        with (shell.cwd / "out" / "csv" / f"{run_id}.csv").open() as csv:
            header = csv.readline().strip()
        assert header.split(",")[:3] == ["time_s", "step", "freq_hz"], header
        assert (shell.cwd / "out" / "tdms" / f"{run_id}.tdms").is_file()
        assert row["status"] in ("completed", "aborted")
    back = {r["id"]: r for r in json.loads(shell.run("sfdrig runs --runs-dir imported --json")[0]
                                             .stdout)}
    assert len(back) == len(made), back
    assert sorted(r["steps"] for r in back.values()) == sorted(r["steps"] for r in made.values())

    lub = next(r for r in made.values() if r["steps"] == 5)
    (shell.cwd / "runs" / "lub.h5").write_bytes(Path(shell.cwd / lub["file"]).read_bytes())
    script = "\n".join(fenced_block(page, "## h5py", "python"))
    out = subprocess.run([sys.executable, "-c", script], cwd=shell.cwd, text=True,
                         capture_output=True, timeout=120)
    assert out.returncode == 0, out.stderr
    fitted, stored, units = out.stdout.split()[-3:]  # after the step's motion and target
    # "the two amplitudes agree": the same least squares but for 2X..5X, which a record of whole
    # cycles (to the sample: 333.3 samples a cycle at 30 Hz) leaves all but orthogonal to the 1X
    assert units == "m" and abs(float(fitted) / float(stored) - 1) < 1e-4, out.stdout
    assert abs(float(stored) - 25e-6) < 0.25e-6


def test_pump_off_wait_returns_once_the_film_has_drained(daemon_factory):
    """`sfdrig pump off --wait` (the README's drain step) against a daemon whose film drains in
    2 s: it returns once the status says 0 s are left, not before; `--wait` with `on` is bad
    input."""
    d = daemon_factory("--film-drain-s", "2")
    conn = ["--runs-dir", str(d.runs_dir)]

    def sfdrig(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "sfdrig", *args, *conn], text=True,
                              capture_output=True, timeout=60)

    out = sfdrig("pump", "on", "--wait")
    assert (out.returncode, out.stdout.strip()) == (
        2, "pump: --wait goes with `off` (it waits for the film to drain)"), out.stdout
    assert sfdrig("pump", "on").returncode == 0
    started = time.monotonic()
    out = sfdrig("pump", "off", "--wait")
    waited = time.monotonic() - started
    assert out.returncode == 0, out.stdout + out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "pump off" and lines[1].startswith("film drains for "), lines
    assert lines[2].startswith("film drained (") and lines[2].endswith("a dry sweep may start")
    assert waited >= 1.9, waited
    status = json.loads(sfdrig("status", "--json").stdout)
    assert (status["pump_on"], status["film_drains_for_s"]) == (False, 0)
