"""`sfdrig structure` through the daemon with a scripted operator typing at the terminal prompts
(a real pty, pexpect): wrong entries, a double hit, an overload, a rejected hit, an abort half
way, and the identified Tables 2, 3 and A1 from the run files the daemon wrote."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pexpect
import pytest

from analysis.structure import identify_impact, identify_probe_calibration, identify_static
from control.wire.client import CommandClient, CommandRefused
from storage import open_run
from tests.e2e.conftest import REPO_ROOT

pytestmark = pytest.mark.e2e

QUESTION = re.compile(r"\[([^\]\r\n]+)\] #(\d+)\r\n((?:  [^\r\n]*\r\n)+)> ")
REFUSED = re.compile(r"  ! ([^\r\n]*)\r\n> ")
DONE = re.compile(r"\r\n(\w+): (\d+) steps, (\w+)([^\r\n]*) -> ([^\r\n]+\.h5)\r\n")


class Terminal:
    """The scripted operator: reads the prompts the terminal shows and types answers."""

    def __init__(self, endpoint: str, *args: str) -> None:
        self.child = pexpect.spawn(
            sys.executable, ["-m", "sfdrig", "structure", "--command-endpoint", endpoint,
                             "--timeout", "20", *args],
            cwd=str(REPO_ROOT), encoding="utf-8", timeout=180, dimensions=(50, 400))
        self.seen: list[tuple[str, str]] = []

    def next(self) -> tuple[str, str] | None:
        """The next question (where, text), or None when the test has ended."""
        i = self.child.expect([QUESTION, DONE])
        if i == 1:
            self.done = self.child.match
            return None
        q = (self.child.match.group(1), self.child.match.group(3))
        self.seen.append(q)
        return q

    def type(self, line: str) -> None:
        self.child.sendline(line)

    def refused(self) -> str:
        self.child.expect(REFUSED)
        return self.child.match.group(1)

    def finish(self) -> tuple[str, str, Path, int, str]:
        """(status, reason, run file, exit code, everything after the last prompt)."""
        if getattr(self, "done", None) is None:
            self.child.expect(DONE)
            self.done = self.child.match
        _, _, status, reason, path = self.done.groups()
        self.child.expect(pexpect.EOF)
        rest = self.child.before
        self.child.close()
        return status, reason, Path(path), self.child.exitstatus, rest


def test_static_test_at_the_terminal_gives_table_2(daemon_factory) -> None:
    d = daemon_factory()
    t = Terminal(d.command, "--only", "static", "--set", 'static.axes=["x"]',
                 "--set", "static.repeats=2", "--runs-dir", str(d.runs_dir))
    where, text = t.next()
    assert where == "static setup" and "Take the journal out" in text
    assert "stand clear of the housing: the shakers will load it" in text
    t.type("maybe")
    assert t.refused() == "answer: #1: 'maybe' is not a choice here (ok, abort)"
    t.type("")
    repeated = False
    points = []
    while (q := t.next()) is not None:
        where, text = q
        assert "steady: accept this point?" in text
        assert re.search(r"load cell fx [-+]\d+\.\d\d N, probes x [-+]\d+\.\d\d um", text)
        points.append(where)
        if not repeated and where.startswith("static x +40 N pass 1"):
            repeated = True
            t.type("r")  # the same point again, the first reading is not kept
            continue
        t.type("")
    status, _, path, code, rest = t.finish()
    assert status == "completed" and code == 0 and "Traceback" not in rest
    assert points.count("static x +40 N pass 1, point 4/10") == 2 and len(points) == 11
    with open_run(d.runs_dir / path.name) as r:
        assert r.kind == "static" and r.attrs["status"] == "completed"
        assert len(r.steps) == 10
        fits = identify_static(r, [], 9.7, 0.01)
        ops = [e for e in r.events if e["kind"] == "operator"]
    (fit,) = fits
    assert abs(fit.k_n_per_m - 788e3) / 788e3 < 0.03  # Table 2, as the in-process acceptance
    assert 0.005 < fit.u_k_n_per_m / fit.k_n_per_m < 0.08
    # every entry is in the run's events with its time, the refused one too
    assert any("refused choice 'maybe': #1: 'maybe' is not a choice" in e["message"] for e in ops)
    assert any(e["message"].endswith(": repeat") for e in ops)
    assert all(re.match(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d", e["time"]) for e in ops)


def test_probe_calibration_at_the_terminal_gives_table_a1(daemon_factory) -> None:
    d = daemon_factory()
    t = Terminal(d.command, "--only", "probe_calibration", "--runs-dir", str(d.runs_dir))
    t.next()
    t.type("")
    wrong = iter(["abc", "5 kg", "0.5 in"])
    said = []
    while (q := t.next()) is not None:
        where, text = q
        reading = re.search(r"the simulated instrument shows: (\S+ in)", text).group(1)
        for bad in wrong:  # the first point: three wrong entries, then the reading
            t.type(bad)
            said.append(t.refused())
        t.type(reading)
    status, _, path, code, rest = t.finish()
    assert status == "completed" and code == 0 and "Traceback" not in rest
    assert said == [
        "answer: dial gauge x: 'abc' is not a number with a unit (e.g. '12.5 in'; units: m, "
        "mm, um, µm, in, mil)",
        "answer: dial gauge x: 'kg' is not a unit of length (use m, mm, um, µm, in, mil)",
        "answer: dial gauge x: 0.5 in is outside -0.0984252 in .. 0.0984252 in",
    ]
    with open_run(d.runs_dir / path.name) as r:
        assert len(r.steps) == 14
        gains = {g.channel: g for g in identify_probe_calibration(r, [])}
    # Table A1, read through the dial gauges at the prompts (as the in-process acceptance)
    assert gains["x1"].gain_mv_per_mil == pytest.approx(202.0, rel=0.01)
    assert gains["x2"].gain_mv_per_mil == pytest.approx(195.0, rel=0.01)
    assert gains["y1"].gain_mv_per_mil == pytest.approx(204.0, rel=0.015)


def test_impact_at_the_terminal_rejects_bad_hits_and_gives_table_3(daemon_factory) -> None:
    d = daemon_factory()
    t = Terminal(d.command, "--only", "impact", "--runs-dir", str(d.runs_dir))
    where, text = t.next()
    assert where == "impact setup" and "you will strike the housing" in text
    assert "stand clear" not in text
    t.type("")
    strikes = iter(["d", "o"])  # x: a double hit, then an overload, then clean hits
    reviews = iter(["n"])  # x: the operator rejects the first clean hit
    shown = []
    while (q := t.next()) is not None:
        where, text = q
        if "Strike the housing" in text:
            shown.append(text)
            t.type(next(strikes, ""))
        else:
            assert re.search(r"peak 29\d N, pulse 1\.9 ms", text)  # 2 ms half-sine above 10 %
            t.type(next(reviews, ""))
    status, _, path, code, rest = t.finish()
    assert status == "completed" and code == 0 and "Traceback" not in rest
    assert "armed: hammer rising through 10 N, 20 ms pre-trigger, 1 s record" in shown[0]
    assert "hit 1 rejected: double hit: a second pulse of" in shown[1]
    assert "hit 2 rejected: overload: hammer reached" in shown[2]
    assert "hit 3 rejected: rejected by the operator" in shown[3]
    with open_run(d.runs_dir / path.name) as r:
        steps = r.steps
        fits = {f.axis: f for f in identify_impact(r, [])}
        hammer = r.channel("hammer", steps[0]["first_sample"], steps[0]["last_sample"])
    assert [s["accepted"] for s in steps] == [False] * 3 + [True] * 6
    assert np.max(hammer) > 280  # the per-hit record is in the file
    assert fits["x"].n_impacts == 3 and fits["y"].n_impacts == 3
    # Table 3 within the in-process acceptance
    assert fits["x"].natural_freq_hz == pytest.approx(45.4, abs=0.5)
    assert fits["y"].k_n_per_m == pytest.approx(823e3, rel=0.03)


def test_abort_half_way_through_the_flow_test(daemon_factory) -> None:
    d = daemon_factory()
    t = Terminal(d.command, "--only", "flow", "--set", "flow.repeats=1",
                 "--set", "flow.supply_pressures_pa=[10000.0, 15500.0, 20000.0]",
                 "--runs-dir", str(d.runs_dir))
    where, text = t.next()
    assert "Set the supply pressure to 10 kPa" in text
    t.type("10 kg")
    assert t.refused() == "answer: supply pressure: 'kg' is not a unit of pressure (use Pa, " \
        "kPa, MPa, bar, psi)"
    t.type("10 kPa")
    where, text = t.next()
    assert "15.5 kPa" in text and where == "flow 15.5 kPa pass 1, point 2/3"
    # the test owns the pump while it runs: a client's switch, either way, is refused
    with CommandClient(d.command) as c:
        for on in (False, True):
            with pytest.raises(CommandRefused, match=r"pump: pump 'pump' cannot be switched by "
                                                   r"hand during the flow test .*: the test "
                                                   "switches it itself"):
                c.pump(on)
        assert c.status()["pump_on"] is True
    t.type("a")
    status, reason, path, code, rest = t.finish()
    assert status == "aborted" and code == 1 and "Traceback" not in rest
    assert "aborted by the operator" in reason
    with CommandClient(d.command) as c:
        st = c.status()
    assert st["state"] == "idle" and st["pump_on"] is False
    with open_run(d.runs_dir / path.name) as r:
        assert r.attrs["status"] == "aborted"
        assert len(r.steps) == 1 and r.steps[0]["supply_pressure_pa"] == 10e3
        assert np.all(r.channel("shaker_x")[-100:] == 0.0)
        assert [e["message"] for e in r.events if e["kind"] == "pump"] == ["pump on",
                                                                          "pump off"]


@pytest.mark.paced
def test_on_the_nidaqmx_backend_the_person_reads_the_instruments(tmp_path: Path) -> None:
    """The daemon on `--backend nidaqmx` (the real nidaqmx client against `sfdrig sim-server`,
    whose rig has the journal out): no simulated hands, so no prompt shows an instrument's
    reading and the person's typed dial-gauge reading is what the run keeps."""
    import subprocess

    from rig_model.params import RigParams
    from tests.e2e.conftest import start_daemon

    rig = RigParams()
    rig.seal.enabled = False  # the technician took the journal out
    (tmp_path / "rig.toml").write_text(rig.to_toml())
    server = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--fast", "--seed", "5",
         "--rig", str(tmp_path / "rig.toml")],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO_ROOT)
    d = None
    try:
        first = server.stdout.readline().strip()  # type: ignore[union-attr]
        assert first.startswith("listening on "), first
        d = start_daemon(tmp_path / "runs", "--backend", "nidaqmx", "--grpc-target",
                         first.removeprefix("listening on "), fast=False)
        t = Terminal(d.command, "--only", "probe_calibration", "--runs-dir", str(d.runs_dir),
                     "--set", 'probe_calibration.axes=["x"]',
                     "--set", "probe_calibration.forces_n=[-40.0, 0.0, 40.0]")
        where, text = t.next()
        assert where == "probe_calibration setup"
        t.type("")
        typed = iter(["-0.0020 in", "0 in", "51 um"])
        while (q := t.next()) is not None:
            assert "simulated instrument" not in q[1] and "read the dial gauge on x" in q[1]
            t.type(next(typed))
        status, _, path, code, rest = t.finish()
        assert status == "completed" and code == 0 and "Traceback" not in rest
        with open_run(d.runs_dir / path.name) as r:
            refs = [st["reference_m"] for st in r.steps]
            texts = [st["gauge_text"] for st in r.steps]
        assert refs == pytest.approx([-50.8e-6, 0.0, 51e-6], abs=1e-12)
        assert texts == ["-0.0020 in", "0 in", "51 um"]
    finally:
        if d is not None:
            d.terminate()
            d.proc.communicate(timeout=10)
        server.terminate()
        server.wait(10)
        server.stdout.close()  # type: ignore[union-attr]


def test_ctrl_c_at_a_prompt_aborts_the_test_without_a_traceback(daemon_factory) -> None:
    d = daemon_factory()
    t = Terminal(d.command, "--only", "impact", "--runs-dir", str(d.runs_dir))
    where, text = t.next()
    assert where == "impact setup" and "you will strike the housing" in text
    assert "stand clear" not in text
    t.type("")
    where, text = t.next()
    assert "Strike the housing along x" in text
    t.child.sendintr()  # Ctrl-C at the strike prompt
    t.child.expect(pexpect.EOF)
    out = t.child.before
    t.child.close()
    assert t.child.exitstatus == 130 and "Traceback" not in out
    assert "impact: abort sent (drives ramp to zero)" in out
    with CommandClient(d.command) as c:
        deadline = 600  # status replies, not sleeps: the abort reaches idle within a block
        while (st := c.status())["state"] != "idle" and deadline:
            deadline -= 1
    assert st["last_run"]["status"] == "aborted"
    assert "operator pressed Ctrl-C in `sfdrig structure` (impact)" in st["last_run"]["reason"]
    with open_run(Path(st["last_run"]["path"])) as r:
        assert r.attrs["status"] == "aborted" and r.steps == []
        assert r.channel("shaker_x")[-1] == 0.0


def test_static_by_hand_at_the_terminal_gives_table_2(daemon_factory) -> None:
    """`--load-by hand`: the operator pushes with the force gauge and types its reading at each
    load (a wrong unit refused, one reading repeated); the shakers stay at 0 V."""
    d = daemon_factory()
    t = Terminal(d.command, "--only", "static", "--load-by", "hand", "--set", 'static.axes=["x"]',
                 "--set", "static.repeats=2", "--runs-dir", str(d.runs_dir))
    where, text = t.next()
    assert where == "static setup" and "you will push the housing" in text
    assert "stand clear" not in text
    t.type("")
    typed, refused, pushes = [], [], 0
    repeated = False
    while (q := t.next()) is not None:
        where, text = q
        if "Push the housing along" in text or "take the force gauge off" in text:
            pushes += "Push the housing along" in text
            t.type("")
            continue
        assert "Probes steady: keep pushing, read the force gauge on x" in text
        assert re.search(r"probes x [-+]\d+\.\d\d um over 0\.5 s", text)
        reading = re.search(r"the simulated instrument shows: (\S+) lbf", text).group(1)
        if not refused:
            t.type(f"{reading} kg")
            refused.append(t.refused())
        if not repeated and where.startswith("static x +40 N by hand pass 1"):
            repeated = True
            t.type("r")  # read again: the push, the steady wait and the reading are redone
            continue
        entry = f"{reading} lbf" if len(typed) % 2 else f"{float(reading) * 4.4482216:.2f} N"
        t.type(entry)
        typed.append((where, entry))
    status, _, path, code, rest = t.finish()
    assert status == "completed" and code == 0 and "Traceback" not in rest
    assert refused == ["answer: force gauge x: 'kg' is not a unit of force (use N, kN, lbf, lb)"]
    assert repeated and pushes == 8 + 1 and len(typed) == 10
    with open_run(d.runs_dir / path.name) as r:
        steps = r.steps
        assert np.all(r.channel("shaker_x") == 0.0) and np.all(r.channel("shaker_y") == 0.0)
        fits = identify_static(r, [], 9.7, 0.01)
        ops = [e["message"] for e in r.events if e["kind"] == "operator"]
    answers = [m for m in ops if m.startswith("answer #")]
    assert [s["gauge_text"] for s in steps] == [e for _, e in typed]
    # every typed reading is in the run's events, as typed and in the gauge's unit
    for where, entry in typed:
        assert sum(f"({where}): ok {entry!r} = " in m and m.endswith(" lbf") for m in answers) == 1
    assert sum(m.startswith("refused entry '") and "is not a unit of force" in m
               for m in ops) == 1
    (fit,) = fits
    assert abs(fit.k_n_per_m - 788e3) / 788e3 < 0.03  # Table 2, as the shaker-loaded test
