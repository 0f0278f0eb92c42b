"""`sfdrig commission` on the in-process simulated rig, deliberately mis-wired: the rig is wired
one way (`SimulatedBackend(wiring=...)`, or a sensor's polarity reversed in the rig file) and
the tool is given the shipped example map, which says another. Each fault is found and named in
one FAIL line with its numbers; the correct map passes. The clock is simulated: the watchdog's
1.5 s and the e-stop's wait pass without sleeping."""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from control.commissioning.procedure import (
    CommissionError,
    Commissioning,
    CommissionInterrupted,
    CommissionResult,
    CommissionSpec,
)
from daq.channels import ChannelMap, channel_map_from_dict, load_channel_map
from rig_model.params import RigParams
from sfdrig.simulated_operator import SimulatedCommissioner
from simulated_hw.backend import SimulatedBackend
from storage import open_run
from storage.records import StepRecord
from tests.conftest import REPO_ROOT
from tests.simulated_hw.fake_clock import FakeClock

EXAMPLE = load_channel_map(REPO_ROOT / "examples" / "channels_report_rig.toml")
WATCHDOG_S = 1.0


def changed(change: Callable[[dict[str, Any]], None], cm: ChannelMap = EXAMPLE) -> ChannelMap:
    data = copy.deepcopy(cm.model_dump(mode="json", exclude_none=True))
    change(data)
    return channel_map_from_dict(data, "test map")


def _ai(name: str, **update: Any) -> Callable[[dict[str, Any]], None]:
    def change(data: dict[str, Any]) -> None:
        for entry in data["ai"]:
            if entry["name"] == name:
                entry.update(update)
    return change


def _swap_x1_y1(data: dict[str, Any]) -> None:
    x1, y1 = (next(e for e in data["ai"] if e["name"] == n) for n in ("x1", "y1"))
    x1["physical_channel"], y1["physical_channel"] = y1["physical_channel"], \
        x1["physical_channel"]


class ForgetsTheJournal(SimulatedCommissioner):
    """Allows the drive with the journal still in: the seal's 26 N of friction holds the
    housing against 2 N."""

    def confirm(self, action: str, question: str) -> bool:
        return True if action == "drive" else super().confirm(action, question)


def commission(tool_map: ChannelMap = EXAMPLE, wiring: ChannelMap | None = None,
               params: RigParams | None = None, watchdog: float | None = WATCHDOG_S,
               spec_watchdog: float | None = WATCHDOG_S, listener: Any = None,
               operator: Any = None, hands: type[SimulatedCommissioner] = SimulatedCommissioner,
               ao_peaks: list[float] | None = None,
               ) -> tuple[CommissionResult, list[str], SimulatedBackend]:
    """Commission ``tool_map`` on the simulated rig wired as ``wiring``; ``ao_peaks`` collects
    the largest |AO| of every block written."""
    clock = FakeClock(0.0)
    backend = SimulatedBackend(params or RigParams(), seed=4, wiring=wiring, watchdog_s=watchdog,
                               clock=clock, sleep=clock.sleep)
    backend.configure(tool_map)
    if ao_peaks is not None:
        write = backend.write_ao

        def recorded(block: np.ndarray, at: int | None = None) -> None:
            ao_peaks.append(float(np.max(np.abs(block), initial=0.0)))
            write(block, at)

        backend.write_ao = recorded  # type: ignore[method-assign]
    lines: list[str] = []
    job = Commissioning(backend, operator or hands(backend, say=lines.append),
                        CommissionSpec(watchdog_s=spec_watchdog), listener=listener,
                        log=lines.append, clock=clock, sleep=clock.sleep)
    try:
        return job.run(), lines, backend
    finally:
        backend.close()


def fails(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("FAIL")]


def test_the_correct_map_passes_with_the_physics_numbers() -> None:
    result, lines, _ = commission()
    assert result.passed, "\n".join(lines)
    assert not fails(lines) and not result.corrections
    w = 2 * math.pi * 20.0
    for axis, k in (("x", 788e3), ("y", 823e3)):
        got = result.measured[f"drive_{axis}"]
        assert got["force_n"] == pytest.approx(2.0, rel=1e-9)  # 0.04 V x 50 N/V
        ch = got["channels"]
        x_expected = 2.0 / abs(complex(k - w * w * 9.7, w * 370.0))  # 3.15 um on x
        for probe in (f"{axis}1", f"{axis}2"):
            assert abs(complex(ch[probe]["re"], ch[probe]["im"])) == pytest.approx(
                x_expected, rel=0.02)
        f = complex(ch[f"f{axis}"]["re"], ch[f"f{axis}"]["im"])
        assert abs(f) == pytest.approx(2.0, rel=0.02)
        assert abs(math.degrees(np.angle(f))) < 3  # in phase with the drive
        a = complex(ch[f"a{axis}"]["re"], ch[f"a{axis}"]["im"])
        x = complex(ch[f"{axis}1"]["re"], ch[f"{axis}1"]["im"])
        assert a / (-w * w * x) == pytest.approx(1.0, abs=0.03)  # a = -w^2 x
    assert any(line.startswith("OK   estop (Dev1/port0/line1)") for line in lines)
    assert any(line.startswith("OK   watchdog: expired after 1.5 s unfed") for line in lines)
    # the pump proven by its effect: the report's 15.5 kPa, and eq. 5's 0.49 L/min through the
    # film land at 15.5 - 5.7 kPa; then both gone once the watchdog dropped the relay
    (on,) = [line for line in lines if line.startswith("OK   pump (Dev1/port0/line0): switched on")]
    assert re.search(r"p_in 15\.\d kPa .*q_in 0\.4[89]\d L/min", on), on
    (off,) = [line for line in lines if "the watchdog expired: the pump stopped" in line]
    assert re.search(r"p_in 0\.[0-4]\d* kPa \(was 15\.\d kPa\)", off), off


def _swap(a: str, b: str, group: str = "ai") -> Callable[[dict[str, Any]], None]:
    def change(data: dict[str, Any]) -> None:
        ea, eb = (next(e for e in data[group] if e["name"] == n) for n in (a, b))
        ea["physical_channel"], eb["physical_channel"] = eb["physical_channel"], \
            ea["physical_channel"]
    return change


def _gaps(data: dict[str, Any]) -> None:
    """Each probe's own gap voltage, as a lab measures and writes them (section 2)."""
    for entry, gap in zip(data["ai"][2:6], (-8.3, -8.7, -8.4, -8.6), strict=True):
        entry["offset_v"] = gap


GAPS = changed(_gaps)
X1_GAIN = 7874.015748031496  # 200 mV/mil, 7.87 V/mm
#: the FAIL lines each mis-wiring must give, in order (regexes, matched from the start)
MATRIX: dict[str, tuple[dict[str, Any], list[str]]] = {
    "x1 and y1 swapped (a sensor on the wrong axis)": (dict(wiring=changed(_swap_x1_y1)), [
        r"FAIL x1 \(Dev1/ai2\) and y1 \(Dev1/ai4\): swapped: driving x, y1 moved 3\.\d+ um "
        r"and x1 0\.00\d+ um; driving y, x1 moved 3\.\d+ um"]),
    "fx and fy swapped": (dict(wiring=changed(_swap("fx", "fy"))), [
        r"FAIL fx \(Dev1/ai0\) and fy \(Dev1/ai1\): swapped: driving x, fy moved 2 N"]),
    "the drives swapped between the amplifiers": (
        dict(wiring=changed(_swap("shaker_x", "shaker_y", "ao"))), [
            r"FAIL shaker_x \(Dev1/ao0\) and shaker_y \(Dev1/ao1\): the drives are swapped: "
            r"shaker_x moved every y sensor \(fy 2 N, y1 2\.9\d um, y2 2\.9\d um, ay 0\.04\d+ "
            r"m/s\^2\) and no x sensor; shaker_y moved every x sensor"]),
    "x1 and x2 swapped with their cables": (
        dict(tool_map=GAPS, wiring=changed(_swap("x1", "x2"), GAPS)), [
            r"FAIL x1 \(Dev1/ai2\) and x2 \(Dev1/ai3\): swapped: x1's terminal reads -8\.70\d V, "
            r"x2's gap voltage \(offset_v -8\.700 V\), and x2's reads -8\.30\d V, x1's"]),
    "x1's sensitivity entered 2x (7.87 for 3.94 V/mm)": (
        dict(tool_map=changed(_ai("x1", gain_v_per_unit=X1_GAIN)),
             wiring=changed(_ai("x1", gain_v_per_unit=X1_GAIN / 2))), [
            r"FAIL x1 \(Dev1/ai2\): reads 1\.5\d um for the x drive where x2 and ax \(-a/w\^2\) "
            r"say 3\.1\d um \(x0\.50; .*\): its sensitivity measures 3\.9\d+ V/mm where "
            r"gain_v_per_unit says 7\.874 V/mm \(2x too large; proposed 39[34]\d;"]),
    "ax's gain 10x (1 V/g entered)": (
        dict(tool_map=changed(_ai("ax", gain_v_per_unit=0.10197162129779284)),
             wiring=EXAMPLE), [
            r"FAIL ax \(Dev1/ai6\): reads 0\.00499 m/s\^2 for the x drive where x1 and x2 say "
            r"0\.049\d m/s\^2 \(x0\.10; .*\): its sensitivity measures 10\d\.?\d* mV/g where "
            r"gain_v_per_unit says 1000 mV/g \(9\.9x too large; proposed 0\.0102;"]),
    "fx inverted (AI+ and AI- swapped)": (dict(params=RigParams.model_validate(
        {"effects": {"reversed_polarity": {"enabled": True, "channels": ["fx"]}}})), [
            r"FAIL fx \(Dev1/ai0\): inverted: [+-]1[78]\d deg from the x drive"]),
    "fx's gain 10x": (dict(tool_map=changed(_ai("fx", gain_v_per_unit=0.2)), wiring=EXAMPLE), [
        r"FAIL fx \(Dev1/ai0\): reads 0\.2 N for the x drive where the drive and the axis's "
        r"motion x \(K - w\^2 M\) say 2 N: its gain_v_per_unit 0\.2 is 10x too large \(measured "
        r"20 mV/N; proposed 0\.02;"]),
    "x2 dead (cable open)": (dict(wiring=changed(lambda d: d["ai"].pop(3))), [
        r"FAIL x2 \(Dev1/ai3\): reads [+-]0\.000 V where its gap voltage should be about "
        r"-8\.50 V: a dead probe"]),
    "x2's gap out of range": (dict(wiring=changed(_ai("x2", offset_v=-9.6))), [
        r"FAIL x2 \(Dev1/ai3\): gap voltage -9\.60 V is out of range: the clearance's motion "
        r"needs \+/-0\.97 V"]),
    "p_in's loop open": (dict(wiring=changed(lambda d: d["ai"].pop(8))), [
        r"FAIL p_in \(Dev1/ai8\): reads [+-]0\.000 V where the 4 mA of an unpressurised loop "
        r"is 1 V: the loop is open"]),
    "the e-stop wired open": (dict(wiring=changed(lambda d: d.pop("estop"))), [
        r"FAIL estop \(Dev1/port0/line1\): reads pressed \(low\) before anyone pressed it"]),
    "the pump relay on another DO line": (
        dict(wiring=changed(lambda d: d["do"][0].update(physical_channel="Dev1/port0/line2"))), [
            r"FAIL pump \(Dev1/port0/line0\): switched on, nothing followed within 2 s: p_in "
            r"[+-]?0\.0\d+ kPa \(at least 2 kPa expected\), q_in .* L/min \(at least 0\.05 L/min "
            r"expected\): the pump's relay is not on this line"]),
    "the X amplifier not connected": (dict(wiring=changed(lambda d: d["ao"].pop(0))), [
        r"FAIL shaker_x \(Dev1/ao0\): nothing answers this drive at 20 Hz; fx read 0\.0\d+ N "
        r"and no sensor moved"]),
    "the housing held (the journal left in: the seal's friction)": (
        dict(hands=ForgetsTheJournal), [
            r"FAIL housing: held: the load cells read the drives \(fx 2 N, fy 2 N\) and none of "
            r"the 6 motion sensors moved \(x1 0\.0\d+ um where 3\.1\d um is expected"]),
    "no watchdog on the board": (dict(watchdog=None), [
        r"FAIL watchdog: still running after 1\.5 s without being fed \(timeout 1 s\)"]),
}
#: the mis-wirings found before anything is driven
AT_REST = {"x1 and x2 swapped with their cables", "x2 dead (cable open)", "x2's gap out of range",
           "p_in's loop open", "the e-stop wired open", "the pump relay on another DO line",
           "no watchdog on the board"}


@pytest.mark.parametrize("fault", list(MATRIX))
def test_each_miswiring_gives_exactly_the_fail_that_names_it(fault: str) -> None:
    kwargs, patterns = MATRIX[fault]
    peaks: list[float] = []
    result, lines, _ = commission(ao_peaks=peaks, **kwargs)
    got = fails(lines)
    print(f"{fault}: {got}")
    assert len(got) == len(patterns), "\n".join(lines)
    for line, pattern in zip(got, patterns, strict=True):
        assert re.match(pattern, line), line
    assert not result.passed
    if fault in AT_REST:  # nothing driven: every AO block written was 0 V
        assert max(peaks, default=0.0) == 0.0, max(peaks)
        assert "drive_x" not in result.measured
    else:
        assert max(peaks, default=0.0) == pytest.approx(0.04, rel=1e-6)  # 2 N at 50 N/V, no more


def test_probes_swapped_with_equal_gap_voltages_are_a_warning_by_their_gains() -> None:
    """x1 (202 mV/mil) and x2 (195) on each other's terminals, their gap voltages alike: each
    reads the other's gain over its own, 0.965 and 1.036 of the motion, within the 10 % of a
    calibration; their ratio (195/202)^2 = 0.932 is the swap's signature: a WARN, no FAIL."""
    result, lines, _ = commission(wiring=changed(_swap("x1", "x2")))
    assert result.passed, "\n".join(lines)
    (warn,) = [line for line in lines if line.startswith("WARN x1 (Dev1/ai2) and x2")]
    assert re.search(r"read the same motion 0\.93\d:1, the square of their gains' ratio "
                     r"\(7677\.2/7952\.8\)\^2 = 0\.932", warn), warn
    _, lines, _ = commission()
    assert not [line for line in lines if line.startswith("WARN x1")]


def test_nothing_is_driven_when_the_rest_fails() -> None:
    result, lines, backend = commission(wiring=changed(_ai("x2", offset_v=-9.6)))
    assert "drive_x" not in result.measured and "drive_y" not in result.measured
    assert result.stopped.startswith("1 input(s) do not read what their sensors should")
    assert backend.rig is not None and backend.rig.last_truth is not None
    assert float(np.max(np.abs(backend.rig.last_truth.fx_n))) == 0.0


def test_corrections_make_a_map_that_passes() -> None:
    """The swap and the 10x gain are corrected in the proposed map; commissioning the proposed
    map on the same rig passes."""
    wiring = changed(_swap_x1_y1)
    tool = changed(_ai("fx", gain_v_per_unit=0.2))
    result, lines, _ = commission(tool_map=tool, wiring=wiring)
    assert len(fails(lines)) == 2
    proposed = result.proposed
    assert proposed is not None
    assert proposed.ai_channel("x1").physical_channel == "Dev1/ai4"
    assert proposed.ai_channel("y1").physical_channel == "Dev1/ai2"
    assert proposed.ai_channel("fx").gain_v_per_unit == 0.02
    again, lines2, _ = commission(tool_map=proposed, wiring=wiring)
    assert again.passed, "\n".join(lines2)


def test_a_probe_gap_voltage_off_the_map_is_corrected_not_failed() -> None:
    result, lines, _ = commission(wiring=changed(_ai("y2", offset_v=-8.1)))
    assert result.passed, "\n".join(lines)
    (warn,) = [line for line in lines if line.startswith("WARN y2")]
    assert "gap voltage -8.100 V, the map's offset_v -8.500 V: it would read +51 um" in warn
    assert result.proposed is not None
    assert result.proposed.ai_channel("y2").offset_v == pytest.approx(-8.1, abs=2e-3)


def test_a_board_without_a_watchdog_fails_the_watchdog_test() -> None:
    result, lines, _ = commission(watchdog=None)
    assert fails(lines) == ["FAIL watchdog: still running after 1.5 s without being fed "
                            "(timeout 1 s): the board would keep a hung PC's drives and pump "
                            "going"]
    assert "drive_x" not in result.measured


class NobodyPresses:
    def instruct(self, action: str, text: str) -> None:
        pass

    def confirm(self, action: str, question: str) -> bool:
        return True


def test_an_estop_that_never_reads_pressed_fails_before_any_drive() -> None:
    result, lines, _ = commission(operator=NobodyPresses())
    assert fails(lines) == ["FAIL estop (Dev1/port0/line1): did not read pressed within 30 s "
                            "of being asked: check its wiring and pressed_level (False)"]
    assert "drive_x" not in result.measured


class CtrlC:
    """Ctrl-C in the middle of the X drive's record (a listener raising it, as the signal would
    between two blocks)."""

    def __init__(self, at_sample: int) -> None:
        self.at = at_sample
        self.events: list[str] = []

    def on_block(self, first: int, ai: np.ndarray, ao: np.ndarray | None) -> None:
        if first >= self.at:
            self.at = 1 << 62
            raise KeyboardInterrupt

    def on_step(self, step: StepRecord) -> None:
        pass

    def on_event(self, kind: str, message: str, sample: int) -> None:
        self.events.append(message)


def test_ctrl_c_ramps_the_drive_down() -> None:
    # rest 1 s, the pump on 2 s and off 2 s (the watchdog's expiry), then 0.6 s into drive x
    listener = CtrlC(at_sample=10_000 + 20_000 + 20_000 + 6_000)
    clock = FakeClock(0.0)
    backend = SimulatedBackend(RigParams(), seed=4, watchdog_s=WATCHDOG_S, clock=clock,
                               sleep=clock.sleep)
    backend.configure(EXAMPLE)
    job = Commissioning(backend, SimulatedCommissioner(backend, say=lambda s: None),
                        CommissionSpec(watchdog_s=WATCHDOG_S), listener=listener,
                        log=lambda s: None, clock=clock, sleep=clock.sleep)
    try:
        with pytest.raises(CommissionInterrupted, match="the drive ramped down to 0 V"):
            job.run()
        truth = backend.rig.last_truth  # type: ignore[union-attr]
        assert truth is not None
        assert float(np.max(np.abs(truth.fx_n))) < 1e-3  # was 2 N when interrupted
    finally:
        backend.close()


def test_a_drive_over_2_n_or_near_the_resonance_is_refused() -> None:
    with pytest.raises(CommissionError, match=r"the drive must be in \(0, 2\] N"):
        CommissionSpec(drive_n=5.0).check(EXAMPLE)
    with pytest.raises(CommissionError, match=r"away from the rig's resonance \(45 Hz\)"):
        CommissionSpec(freq_hz=40.0).check(EXAMPLE)


def test_the_record_holds_the_stages_and_the_findings(tmp_path: Path) -> None:
    from control.run.files import create_run_writer

    clock = FakeClock(0.0)
    wiring = changed(_swap_x1_y1)
    backend = SimulatedBackend(RigParams(), seed=4, wiring=wiring, watchdog_s=WATCHDOG_S,
                               clock=clock, sleep=clock.sleep)
    backend.configure(EXAMPLE)
    writer = create_run_writer(tmp_path / "c.h5", "commissioning", backend.channel_map, run_id="c1")
    job = Commissioning(backend, SimulatedCommissioner(backend, say=lambda s: None),
                        CommissionSpec(watchdog_s=WATCHDOG_S), listener=writer,
                        log=lambda s: None, clock=clock, sleep=clock.sleep)
    try:
        job.run()
    finally:
        writer.close("completed", "commissioning 1 problem")
        backend.close()
    with open_run(tmp_path / "c.h5") as run:
        assert run.kind == "commissioning"
        assert [s["stage"] for s in run.steps] == ["rest", "pump on", "pump off", "drive x",
                                                   "drive y"]
        drive_x = run.steps[3]
        y1 = run.channel("y1", drive_x["first_sample"], drive_x["last_sample"])
        assert float(np.std(y1)) * math.sqrt(2) == pytest.approx(3.15e-6, rel=0.03)  # x moves
        assert any(e["kind"] == "error" and "swapped" in e["message"] for e in run.events)


def test_the_command_writes_the_record_the_report_and_the_proposed_map(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from sfdrig.cli import main

    wiring = tmp_path / "wiring.toml"
    wiring.write_text(changed(_swap_x1_y1).to_toml())
    out = tmp_path / "out"
    example = REPO_ROOT / "examples" / "channels_report_rig.toml"
    code = main(["commission", str(example), "--wiring", str(wiring), "--watchdog-s", "0",
                 "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 1
    assert text.rstrip().endswith(
        f"commissioning 1 problem on the simulated rig (in process): {example}")
    assert text.startswith(f"commissioning {example} on the simulated rig (in process); ")
    (record,) = out.glob("commission-*.h5")
    with open_run(record) as run:
        assert run.status == "completed"
        assert run.attrs["status_reason"] == \
            "commissioning 1 problem on the simulated rig (in process)"
        assert run.test_spec["board"] == "simulated rig (in process)"
    (proposed,) = out.glob("commission-*-proposed.toml")
    assert load_channel_map(proposed).ai_channel("x1").physical_channel == "Dev1/ai4"
    assert proposed.read_text().count("\n#") == example.read_text().count("\n#")
    (report,) = out.glob("commission-*.md")
    assert report.read_text().startswith(
        f"# Commissioning of {example} on the simulated rig (in process): FAILED\n\n"
        "- verdict: FAILED on the simulated rig (in process)\n")
    assert '-physical_channel = "Dev1/ai2"\n+physical_channel = "Dev1/ai4"' in text


@pytest.mark.parametrize("args,line", [
    (["missing.toml"], r"commission: missing\.toml: cannot read: No such file or directory$"),
    (["EXAMPLE", "--drive-n", "5"], r"commission: the drive must be in \(0, 2\] N, got 5 N$"),
    (["EXAMPLE", "--freq-hz", "45"], r"commission: the test frequency 45 Hz must be in 5-200 "
                                     r"Hz and at least 30% away from the rig's resonance"),
    (["EXAMPLE", "--wiring", "missing.toml"], r"commission: missing\.toml: cannot read"),
    (["EXAMPLE", "--rig", "missing.toml"], r"commission: missing\.toml: cannot read"),
    (["EXAMPLE", "--grpc-target", "x:1"], r"commission: --grpc-target needs --backend nidaqmx"),
    (["EXAMPLE", "--watchdog-s", "-1"], r"commission: --watchdog-s must be in \[0, 60\] s"),
    (["EXAMPLE", "--pump-s", "0"], r"commission: --pump-s must be in \[0\.2, 120\] s, got 0$"),
])
def test_bad_input_is_one_line_exit_2(args: list[str], line: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    from sfdrig.cli import main

    example = str(REPO_ROOT / "examples" / "channels_report_rig.toml")
    assert main(["commission", *[example if a == "EXAMPLE" else a for a in args]]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and re.match(line, err.strip()), err


def test_an_amplifier_gain_off_the_map_is_named_and_corrected() -> None:
    params = RigParams()
    params.shaker.force_per_volt_n = 200.0  # the knob turned up: the map says 50 N/V
    result, lines, _ = commission(params=params)
    assert [line.split(":")[0] for line in fails(lines)] == \
        ["FAIL shaker_x (Dev1/ao0)", "FAIL shaker_y (Dev1/ao1)"]
    assert "the rig answers 4x what 2 N from nominal_force_n_per_v 50 N/V should give: the " \
           "amplifier's gain is 200 N/V" in fails(lines)[0]
    assert result.proposed is not None
    assert [ao.nominal_force_n_per_v for ao in result.proposed.ao] == [200.0, 200.0]
