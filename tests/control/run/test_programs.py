"""The non-sweep test programmes on the simulated rig: each writes a run file of its kind that
the matching analysis turns into the report's numbers (Tables 2, 3, A1; flow against eq. 5)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from analysis.structure import (
    identify_flow,
    identify_impact,
    identify_probe_calibration,
    identify_static,
)
from control.run.files import create_run_writer
from control.run.programs.operator import OperatorDesk, Question
from control.run.programs.procedures import (
    FlowSpec,
    ImpactSpec,
    ProbeCalSpec,
    StaticSpec,
    run_flow_test,
    run_impact_test,
    run_probe_calibration,
    run_static_test,
)
from daq.channels import default_channel_map
from rig_model.params import RigParams
from storage import open_run
from tests.control.conftest import WriteLog

MIL_M = 25.4e-6
GAUGE_RESOLUTION_M = 0.0001 * 0.0254  # dial gauge, +/- 0.0001 in (Appendix A)


def no_seal() -> RigParams:
    """The report's static and impact tests ran without the journal, so without the seal."""
    p = RigParams()
    p.seal.enabled = False
    return p


def backend(params: RigParams, seed: int = 3) -> WriteLog:
    b = WriteLog(params, seed=seed)
    b.configure(default_channel_map())
    return b


class ScriptedDesk(OperatorDesk):
    """Answers each question as it is asked, from ``answer(question) -> (choice, text)``; keeps
    every question and answer."""

    def __init__(self, answer) -> None:  # noqa: ANN001
        super().__init__(lambda kind, message: self.log.append(message))
        self.log: list[str] = []
        self.asked: list[Question] = []
        self._script = answer

    def post(self, question: Question) -> Question:
        q = super().post(question)
        self.asked.append(q)
        choice, text = self._script(q)
        self.submit(q.id, choice, text)
        return q


class Hands:
    """A test's own hands on the simulated rig (no code shared with the composition root's)."""

    def __init__(self, rig) -> None:  # noqa: ANN001
        self.rig = rig
        self.strikes: list[tuple[str, float, str]] = []
        self.pressures: list[float] = []

    def strike(self, axis: str, peak_force_n: float, kind: str) -> None:
        self.strikes.append((axis, peak_force_n, kind))
        if kind == "overload":  # the hammer's range: 10 V at 2.3 mV/N is 4,348 N
            self.rig.schedule_impact(axis, 5000.0, 0.002)
            return
        self.rig.schedule_impact(axis, peak_force_n, 0.002)
        if kind == "double":  # the hammer bounces: 100 N 25 ms later
            self.rig.schedule_impact(axis, 100.0, 0.002, delay_s=0.025)

    def gauge_reading_m(self, axis: str) -> float:
        truth = self.rig.last_truth
        z = float(np.mean(truth.x_m if axis == "x" else truth.y_m))
        return round(z / GAUGE_RESOLUTION_M) * GAUGE_RESOLUTION_M

    def set_supply_pressure(self, pressure_pa: float) -> None:
        self.pressures.append(pressure_pa)
        self.rig.params.oil.supply_pressure_pa = pressure_pa

    def set_journal(self, installed: bool) -> None:
        self.rig.set_journal(installed)


def accept_all(q: Question) -> tuple[str, str]:
    return "ok", q.shows


def test_static_programme(tmp_path: Path) -> None:
    params = no_seal()
    b = backend(params)
    spec = StaticSpec(forces_n=(-80.0, -40.0, 0.0, 40.0, 80.0), repeats=2, record_s=0.3)
    w = create_run_writer(tmp_path / "s.h5", "static", b.channel_map, run_id="s", rig_config=params,
                          test_spec=spec)
    out = run_static_test(b, w, spec)
    w.close()
    assert out.completed and out.steps == 2 * 2 * 5
    with open_run(tmp_path / "s.h5") as r:
        assert r.kind == "static"
        steps = r.steps
        assert [s["motion"] for s in steps[:10]] == ["x"] * 10
        # the held force reached the target (drive corrected on the load cell)
        for st in steps:
            fx = r.signal("f" + st["motion"], st["first_sample"], st["last_sample"]).mean()
            assert fx == pytest.approx(st["target_value"], abs=0.02 * 80)
        # drives end at zero
        assert r.channel("shaker_x")[-1] == 0.0 and r.channel("shaker_y")[-1] == 0.0
        skipped: list = []
        fits = identify_static(r, skipped, 9.7, 0.01)
    assert skipped == []
    k = {f.axis: f.k_n_per_m for f in fits}
    assert k["x"] == pytest.approx(788e3, rel=0.01)
    assert k["y"] == pytest.approx(823e3, rel=0.01)
    assert fits[0].natural_freq_hz == pytest.approx(45.4, abs=0.3)


def test_impact_programme(tmp_path: Path) -> None:
    params = no_seal()
    b = backend(params)
    rig = b.rig
    hands = Hands(rig)
    spec = ImpactSpec(strikes=2, window_s=1.0)
    w = create_run_writer(tmp_path / "i.h5", "impact", b.channel_map, run_id="i", rig_config=params)
    out = run_impact_test(b, w, ScriptedDesk(accept_all), spec, hands=hands)
    w.close()
    assert out.completed, out.reason
    assert hands.strikes == [("x", 300.0, "ok")] * 2 + [("y", 300.0, "ok")] * 2
    with open_run(tmp_path / "i.h5") as r:
        for st in r.steps:
            assert st["trigger_sample"] - st["first_sample"] == int(0.02 * 10_000)
            assert st["target_value"] == pytest.approx(300.0, rel=0.05)  # measured peak
        skipped: list = []
        fits = identify_impact(r, skipped)
    assert skipped == []
    by = {f.axis: f for f in fits}
    m_true = params.structure.mass_kg
    for axis, k_true in (("x", 788e3), ("y", 823e3)):
        f = by[axis]
        assert f.k_n_per_m == pytest.approx(k_true, rel=0.03)
        assert f.m_kg == pytest.approx(m_true, rel=0.03)
        assert f.c_ns_per_m == pytest.approx(370.0, rel=0.10)
        assert f.natural_freq_hz == pytest.approx(math.sqrt(k_true / m_true) / 2 / math.pi,
                                                  rel=0.01)
        assert f.r2 > 0.98
        assert f.n_impacts == 2


def test_impact_without_strike_stops_safely(tmp_path: Path) -> None:
    b = backend(no_seal())
    w = create_run_writer(tmp_path / "i.h5", "impact", b.channel_map, run_id="i")
    no_hit = Hands(b.rig)
    no_hit.strike = lambda axis, peak, kind: None  # type: ignore[method-assign]
    out = run_impact_test(b, w, ScriptedDesk(accept_all), ImpactSpec(wait_s=0.5), hands=no_hit)
    w.close()
    assert not out.completed
    assert "impact step 1 (x, hit 1)" in out.reason and "no strike" in out.reason
    with open_run(tmp_path / "i.h5") as r:
        assert any(e["kind"] == "abort" and "no strike" in e["message"] for e in r.events)
        assert r.channel("shaker_x")[-1] == 0.0


def test_static_programme_stops_at_the_force_limit(tmp_path: Path) -> None:
    b = backend(no_seal())
    w = create_run_writer(tmp_path / "s.h5", "static", b.channel_map, run_id="s")
    out = run_static_test(b, w, StaticSpec(forces_n=(20.0, 120.0), max_force_n=100.0))
    w.close()
    assert not out.completed
    assert "static step 2 (x, 120 N, pass 1)" in out.reason and "over the 100 N limit" in out.reason
    assert out.steps == 1
    with open_run(tmp_path / "s.h5") as r:
        assert np.all(r.channel("shaker_x")[-100:] == 0.0)
        # the trip is found at the end of the block that saw it: drives at zero 100 ms later
        trip = next(e["sample"] for e in r.events if e["kind"] == "abort")
        fx = r.channel("fx")
        first_over = int(np.nonzero(np.abs(fx) > 100.0)[0][0])
        assert trip - first_over <= 100  # detected within the 10 ms block
        drive = np.abs(r.channel("shaker_x"))
        assert drive[first_over] > 1.0
        # the two blocks queued ahead do not play: 0 V from the end of the trip's block
        assert trip % 100 == 0 and drive[trip - 1] > 1.0
        assert np.all(drive[trip:] == 0.0)
        assert len(drive) >= trip + 200 + 400  # the motion read out (queue + 40 ms ramp)
    written = b.ao_written()[0]
    assert np.all(np.abs(written[trip:trip + 200]) > 1.0)  # it had been written


def test_a_force_trip_on_a_resuming_backend_fades_from_the_first_sample_not_generated(
        tmp_path: Path) -> None:
    """A backend that takes back its queue and goes on (the in-process rig with
    ``cut_stops=False``): the 40 ms fault ramp starts where the generation was, no step."""
    b = WriteLog(no_seal(), seed=3, cut_stops=False)
    b.configure(default_channel_map())
    w = create_run_writer(tmp_path / "s.h5", "static", b.channel_map, run_id="s")
    out = run_static_test(b, w, StaticSpec(forces_n=(20.0, 120.0), max_force_n=100.0))
    w.close()
    assert not out.completed and "over the 100 N limit" in out.reason
    with open_run(tmp_path / "s.h5") as r:
        trip = next(e["sample"] for e in r.events if e["kind"] == "abort")
        drive = r.channel("shaker_x")
    level = drive[trip - 1]
    assert abs(level) > 1.0
    fade = drive[trip:trip + 400]  # 40 ms at 10 kS/s, linear to zero
    np.testing.assert_allclose(fade, level * (1 - np.arange(1, 401) / 400), atol=1e-12)
    assert np.all(drive[trip + 400:] == 0.0)
    assert np.max(np.abs(np.diff(drive[trip - 1:trip + 401]))) <= abs(level) / 400 + 1e-12


def test_probe_calibration_programme(tmp_path: Path) -> None:
    params = no_seal()
    params.effects.probe_gain_error.enabled = True  # x1 reads 3 % high: calibration finds it
    params.effects.probe_gain_error.channel = "x1"
    params.effects.probe_gain_error.gain_ratio = 1.03
    b = backend(params)
    w = create_run_writer(tmp_path / "c.h5", "probe_calibration", b.channel_map, run_id="c",
                          rig_config=params)
    out = run_probe_calibration(b, w, ScriptedDesk(accept_all), ProbeCalSpec(),
                                hands=Hands(b.rig))
    w.close()
    assert out.completed and out.steps == 14
    with open_run(tmp_path / "c.h5") as r:
        skipped: list = []
        cals = {c.channel: c for c in identify_probe_calibration(r, skipped)}
    assert skipped == []
    table_a1 = {"x1": 202.0 * 1.03, "x2": 195.0, "y1": 204.0, "y2": 200.0}  # mV/mil
    for ch, gain in table_a1.items():
        assert cals[ch].gain_mv_per_mil == pytest.approx(gain, rel=0.01), ch
        assert cals[ch].r2 > 0.99
        assert 0 < cals[ch].u_gain_rel < 0.05
    assert cals["x1"].gain_in_use_v_per_m * MIL_M * 1e3 == pytest.approx(202.0)


def test_flow_programme(tmp_path: Path) -> None:
    params = RigParams()
    b = backend(params)
    rig = b.rig
    hands = Hands(rig)
    spec = FlowSpec(supply_pressures_pa=(10e3, 15.5e3, 20e3, 25e3), repeats=2, settle_s=2.5)
    w = create_run_writer(tmp_path / "f.h5", "flow", b.channel_map, run_id="f", rig_config=params,
                          lubricated=True)
    out = run_flow_test(b, w, ScriptedDesk(accept_all), spec, hands=hands)
    w.close()
    assert out.completed and out.steps == 8
    assert hands.pressures == [10e3, 15.5e3, 20e3, 25e3] * 2
    assert not rig.pump_on  # switched off at the end
    with open_run(tmp_path / "f.h5") as r:
        assert [e["message"] for e in r.events if e["kind"] == "pump"] == ["pump on", "pump off"]
        skipped: list = []
        fr = identify_flow(r, skipped, params)
    assert skipped == []
    assert len(fr.points) == 4 and all(p["n_repeats"] == 2 for p in fr.points)
    # the simulated film follows eq. 5 with the configuration's viscosity (3.17 cP, Table 5)
    assert fr.viscosity_fit_pa_s == pytest.approx(params.film.viscosity_pa_s(24.0), rel=0.02)
    assert fr.mean_flow_ratio_config == pytest.approx(1.0, abs=0.02)
    # eq. 1 gives 2.78 cP at 24 degC: the flow ratio against it shows the 12 % disagreement
    assert fr.mean_flow_ratio_eq1 == pytest.approx(2.78 / 3.17, rel=0.02)
    assert fr.r2 > 0.999


def test_impact_rejects_double_hits_and_overloads_and_the_operators_reject(tmp_path: Path,
                                                                         ) -> None:
    b = backend(no_seal())
    hands = Hands(b.rig)
    strikes = iter(["double", "overload", "ok", "ok", "ok"])
    reviews = iter(["reject", "ok", "ok"])

    def script(q: Question) -> tuple[str, str]:
        if q.trigger:
            return next(strikes), ""
        if q.prompt.startswith("Hit"):
            return next(reviews), ""
        return "ok", ""

    desk = ScriptedDesk(script)
    w = create_run_writer(tmp_path / "i.h5", "impact", b.channel_map, run_id="i")
    out = run_impact_test(b, w, desk, ImpactSpec(axes=("x",), strikes=2), hands=hands)
    w.close()
    assert out.completed, out.reason
    with open_run(tmp_path / "i.h5") as r:
        steps = r.steps
        fits = identify_impact(r, [])
    assert [st["accepted"] for st in steps] == [False, False, False, True, True]
    assert steps[0]["rejection"].startswith("double hit: a second pulse of 100 N 25 ms after")
    assert steps[1]["rejection"].startswith("overload: hammer reached 43")  # clipped at 10 V
    assert "% of its input range" in steps[1]["rejection"]
    assert steps[2]["rejection"] == "rejected by the operator"
    for st in steps:  # a fixed record per hit: 20 ms before the trigger, 1 s after
        assert st["trigger_sample"] - st["first_sample"] == 200
        assert st["last_sample"] - st["trigger_sample"] == 10_000
    # the operator saw why: the next strike question says so
    rejected_news = [q.info[-1] for q in desk.asked if q.trigger][1:3]
    assert rejected_news[0].startswith("hit 1 rejected: double hit")
    assert rejected_news[1].startswith("hit 2 rejected: overload")
    review = [q for q in desk.asked if q.prompt.startswith("Hit 5")][0]
    assert "H1 of 2 hit(s): peak at 45." in review.info[1] and "coherence" in review.info[1]
    (fit,) = fits
    assert fit.n_impacts == 2  # only the accepted hits are averaged
    assert fit.k_n_per_m == pytest.approx(788e3, rel=0.03)
    band = [c for f, c in zip(fit.freq_hz, fit.coherence, strict=True) if 20 <= f <= 100]
    assert min(band) > 0.95


def test_abort_half_way_keeps_the_points_and_fades_the_drives(tmp_path: Path) -> None:
    b = backend(no_seal())
    answers = iter(["ok"] * 4 + ["abort"])
    desk = ScriptedDesk(lambda q: (next(answers), ""))
    w = create_run_writer(tmp_path / "s.h5", "static", b.channel_map, run_id="s")
    out = run_static_test(b, w, StaticSpec(axes=("x",), repeats=1), operator=desk,
                          hands=Hands(b.rig))
    w.close("aborted", out.reason)
    assert not out.completed and out.steps == 3  # setup + 3 points accepted, then abort
    assert "aborted by the operator" in out.reason and "static x +40 N" in out.reason
    with open_run(tmp_path / "s.h5") as r:
        assert len(r.steps) == 3
        assert np.all(r.channel("shaker_x")[-100:] == 0.0)
        assert any(e["kind"] == "abort" and "aborted by the operator" in e["message"]
                   for e in r.events)
    assert desk.log[-1].endswith("point 4/5): abort")


def test_an_unsteady_point_is_not_recorded(tmp_path: Path) -> None:
    """With a steadiness limit no signal can meet, the operator is asked to repeat or skip, and
    no point is recorded."""
    b = backend(no_seal())
    desk = ScriptedDesk(lambda q: ("skip", "") if "Not steady" in q.prompt else ("ok", ""))
    w = create_run_writer(tmp_path / "s.h5", "static", b.channel_map, run_id="s")
    spec = StaticSpec(axes=("x",), forces_n=(0.0,), repeats=1, steady_displacement_m=1e-12,
                      steady_timeout_s=0.5)
    out = run_static_test(b, w, spec, operator=desk)
    w.close()
    assert out.completed and out.steps == 0
    not_steady = [q for q in desk.asked if "Not steady" in q.prompt]
    assert len(not_steady) == 1 and "x moved" in not_steady[0].prompt
    assert not_steady[0].choices == ["repeat", "skip", "abort"]  # no way to accept it


def test_static_programme_by_hand(tmp_path: Path) -> None:
    """Loads pushed by hand with a force gauge (IV.1): shakers at 0 V, the typed gauge readings
    paired with the probes give Table 2 as the shaker-held loads do."""
    from sfdrig.simulated_operator import SimulatedHands

    params = no_seal()
    b = backend(params)
    spec = StaticSpec(load_by="hand", repeats=2, record_s=0.3)
    w = create_run_writer(tmp_path / "h.h5", "static", b.channel_map, run_id="h", rig_config=params,
                          test_spec=spec)
    desk = ScriptedDesk(accept_all)
    out = run_static_test(b, w, spec, operator=desk, hands=SimulatedHands(b, seed=4))
    w.close()
    assert out.completed and out.steps == 2 * 2 * 5
    with open_run(tmp_path / "h.h5") as r:
        steps = r.steps
        assert np.all(r.channel("shaker_x") == 0.0) and np.all(r.channel("shaker_y") == 0.0)
        for st in steps:
            assert st["load_by"] == "hand" and st["gauge_text"].endswith(" lbf")
            assert st["gauge_force_n"] == pytest.approx(float(st["gauge_text"][:-4]) * 4.44822,
                                                        rel=1e-5)
            # the hand is off the asked force by a few percent, the gauge says by how much
            assert st["gauge_force_n"] == pytest.approx(st["target_value"], rel=0.12, abs=0.3)
            # the push is not on the load cells: they read the idle shakers' stingers
            fx = r.signal("f" + st["motion"], st["first_sample"], st["last_sample"]).mean()
            assert abs(fx) < 0.05
        assert any(abs(st["gauge_force_n"] - st["target_value"]) > 0.01 * 40 for st in steps)
        skipped: list = []
        fits = identify_static(r, skipped, 9.7, 0.01)
    assert skipped == []
    k = {f.axis: f.k_n_per_m for f in fits}
    assert k["x"] == pytest.approx(788e3, rel=0.01)
    assert k["y"] == pytest.approx(823e3, rel=0.01)
    assert sum("Push the housing along" in q.prompt for q in desk.asked) == 16  # 0 N: hands off
    assert sum(q.entry is not None and q.entry.unit == "lbf" for q in desk.asked) == 20


def test_static_by_hand_needs_an_operator(tmp_path: Path) -> None:
    b = backend(no_seal())
    w = create_run_writer(tmp_path / "h.h5", "static", b.channel_map, run_id="h")
    out = run_static_test(b, w, StaticSpec(load_by="hand"))
    w.close()
    assert not out.completed and out.steps == 0
    assert "static loads by hand need an operator" in out.reason
