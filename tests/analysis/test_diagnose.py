"""Diagnose: inputs, splits, replay, bootstrap, JSON, extended model and the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from analysis.diagnose import DiagnoseError, diagnose, load_run, parse_spans
from analysis.diagnose.candidates import bootstrap_gain
from analysis.diagnose.data import Segment, records_from_arrays, split_segments
from analysis.diagnose.fitting import apply, arx_linear_guess, levenberg_marquardt
from analysis.diagnose.model import Evaluator, Model, Residuals, residuals, rig_param
from analysis.diagnose.start import dynamic_stiffness_points, one_mode_estimate
from rig_model import load_rig_params
from rig_model.params import RigParams
from sfdrig.cli import main
from tests.analysis.hidden_effects import make_case
from tests.analysis.independent_cases import COUPLING_TOLERANCE, make_independent_case


def test_parse_spans():
    assert parse_spans("40650:105712, 1:5") == [(40650, 105712), (1, 5)]
    assert parse_spans(None) is None and parse_spans(" ") is None
    with pytest.raises(DiagnoseError, match=r"--test: span '5:1' is empty"):
        parse_spans("5:1", "--test")
    with pytest.raises(DiagnoseError, match=r"--train: 'a:b' is not a sample span"):
        parse_spans("a:b")


def _sine_record(n=4096, fs=1000.0):
    t = np.arange(n) / fs
    return records_from_arrays(np.sin(2 * np.pi * 20 * t), {"x": 1e-6 * np.sin(t)}, fs)


def test_split_rejects_overlap_and_out_of_range():
    rec = _sine_record()
    with pytest.raises(DiagnoseError, match="overlaps"):
        split_segments([rec], [(0, 2000)], [(1500, 3000)])
    with pytest.raises(DiagnoseError, match="runs past the end"):
        split_segments([rec], [(0, 2000)], [(2000, 9000)])
    with pytest.raises(DiagnoseError, match="both --train and --test"):
        split_segments([rec], [(0, 2000)], None)


def test_split_holds_out_whole_dwells():
    rec = _sine_record()
    rec.segments = [Segment(0, 100 * i, 100 * i + 80, f"d{i}", 20.0) for i in range(9)]
    train, test = split_segments([rec])
    assert [s.label for s in test] == ["d1", "d4", "d7"]
    assert not {s.label for s in train} & {s.label for s in test}


def test_span_blocks_cover_the_span_without_overlap():
    rec = _sine_record(n=20000)
    train, test = split_segments([rec], [(0, 10000)], [(10000, 20000)], block_s=2.0)
    assert [(s.start, s.stop) for s in test] == [(10000, 12000), (12000, 14000),
                                                  (14000, 16000), (16000, 18000),
                                                  (18000, 20000)]
    assert sum(s.n for s in train) == 10000


def test_replay_of_the_simulator_is_exact_without_noise():
    """The config replay of a force through the rig equals simulate_response itself."""
    from rig_model import simulate_response

    fs = 5000.0
    rig = RigParams()
    t = np.arange(6000) / fs
    force = np.vstack([80 * np.sin(2 * np.pi * 30 * t), 60 * np.cos(2 * np.pi * 30 * t)])
    # the film warms as configured (1 degC per hour with the pump on), viscosity by eq. 1
    visc = np.exp(-0.01665 * rig.oil.warming_c_per_hour / 3600.0 * t)
    truth, _ = simulate_response(force, rig, fs, 1.0, visc)
    rec = records_from_arrays(force, {"x1": truth.x_m, "y1": truth.y_m}, fs, kind="sweep",
                              rig=rig, lubricated=True)
    seg = Segment(0, 0, 6000, "all", 30.0)
    ev = Evaluator([rec], warmup_s=0.0)
    res = residuals(ev, Model(rig=rig), [seg])
    assert res.rms() < 1e-15


def test_a_model_with_memory_replays_from_the_runs_start(tmp_path, monkeypatch):
    """A micro-slipping joint (or a sticking seal) keeps the offset of every earlier slip: the
    run replayed with its true rig from the run's start leaves every dwell at its noise; from
    rest 0.5 s before each dwell (a memoryless model's window) some dwell is far off."""
    import analysis.diagnose.model as model_mod
    from analysis.diagnose import residual_analysis as ra

    case = make_case(tmp_path, ["joint_microslip"], 11)
    rec = load_run(case.paths[0], 0)
    rig = case.truth.model_copy(update={"contact": case.truth.contact.model_copy(
        update={"enabled": False})})
    assert model_mod.remembers(Model(rig=rig))
    memoryless = rig.model_copy(update={
        "seal": rig.seal.model_copy(update={"enabled": False}),
        "effects": rig.effects.model_copy(update={
            "joint_microslip": rig.effects.joint_microslip.model_copy(
                update={"enabled": False})})})
    assert not model_mod.remembers(Model(rig=memoryless))
    # the held-out dwells diagnose judges on: apart, each its own window
    train, test = split_segments([rec])
    noise = math.sqrt(ra.channel_noise([rec], test)["x1"])

    def worst(ev: Evaluator) -> float:
        res = residuals(ev, Model(rig=rig), train, test)
        return max(float(np.sqrt(np.mean(res.per_segment[s]["x1"] ** 2))) for s in test)

    # measured: 0.75-0.78 noise per held-out dwell from the start; from a warm-up 1.26-1.29 and
    # 4.82 on one (coulomb_friction at seed 21, the seal sticking: 0.88-0.93 and 54 on one)
    assert worst(Evaluator([rec], warmup_s=0.5)) < 1.2 * noise
    monkeypatch.setattr(model_mod, "remembers", lambda m: False)
    assert worst(Evaluator([rec], warmup_s=0.5)) > 3.0 * noise


def test_the_replay_cache_holds_no_more_than_its_limit():
    """A dwell replayed in steady state after a long lead caches its own samples only: a view
    past the lead kept the whole replay alive while the cache counted the view's bytes (a
    30 s lead before 1 s dwells held 31x the limit: 12 GB, the process killed)."""
    import tracemalloc

    fs, n = 2000.0, 400  # 0.2 s dwell at 20 Hz, 10 s of lead: 50x the dwell
    t = np.arange(n) / fs
    force = np.vstack([50 * np.sin(2 * np.pi * 20 * t), np.zeros(n)])
    rig = RigParams()
    rec = records_from_arrays(force, {"x": 1e-6 * np.sin(2 * np.pi * 20 * t)}, fs, rig=rig)
    rec.segments = [Segment(0, 0, n, "dwell", 20.0)]
    ev = Evaluator([rec], warmup_s=10.0, steady_state_dwells=True)
    assert ev._lead(0, 0, n) == 20000
    ev.cache_limit_bytes = 2**20
    k = rig_param("k", "structure.stiffness_x_n_per_m", 1e4)
    ev.truth(k.set(Model(rig=rig), 7e5), 0, 0, n)  # the kernel loaded before counting
    tracemalloc.start()
    try:
        for i in range(60):
            ev.truth(k.set(Model(rig=rig), 8e5 * (1 + 1e-3 * i)), 0, 0, n)
        held, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert ev.simulations == 61
    # each replay is 20,400 samples of every kernel output (over 1 MB); 60 views would hold
    # over 60 MB
    assert held < 2 * ev.cache_limit_bytes, f"{held / 2**20:.1f} MiB held"


def test_a_replay_is_redone_only_when_what_the_kernel_reads_changes():
    """The Evaluator keys its replays on the kernel's inputs: an effect enabled at 0 or a
    measurement term replays nothing and predicts the same; a stiffness, the viscosity's
    drift or a force offset replays."""
    fs = 5000.0
    rig = RigParams()
    t = np.arange(4000) / fs
    force = np.vstack([80 * np.sin(2 * np.pi * 30 * t), np.zeros_like(t)])
    rec = records_from_arrays(force, {"x1": np.zeros_like(t)}, fs, kind="sweep", rig=rig,
                              lubricated=True)
    seg = Segment(0, 0, 4000, "all", 30.0)
    ev = Evaluator([rec], warmup_s=0.0)
    base = Model(rig=rig)
    x0 = ev.predict(base, [seg])[seg]["x1"]
    assert ev.simulations == 1
    zero_cubic = rig.model_copy(update={"effects": rig.effects.model_copy(update={
        "cubic_stiffness": rig.effects.cubic_stiffness.model_copy(
            update={"enabled": True, "k3_n_per_m3": 0.0})})})
    for same in (Model(rig=zero_cubic), Model(rig=rig, gain={"x1": 1.1})):
        ev.predict(same, [seg])
    assert ev.simulations == 1
    np.testing.assert_array_equal(ev.predict(Model(rig=zero_cubic), [seg])[seg]["x1"], x0)
    stiffer = rig_param("k", "structure.stiffness_x_n_per_m", 1.0).set(
        base, 1.01 * rig.structure.stiffness_x_n_per_m)
    for other in (stiffer, Model(rig=rig, visc_relative_change=0.1),
                  Model(rig=rig, force_offset_n=(1.0, 0.0))):
        x = ev.predict(other, [seg])[seg]["x1"]
        assert np.max(np.abs(x - x0)) > 1e-3 * np.max(np.abs(x0))
    assert ev.simulations == 4


def test_bootstrap_is_seeded_and_brackets_the_gain():
    segs = [Segment(0, i, i + 1, f"s{i}") for i in range(12)]
    rng = np.random.default_rng(3)
    before = Residuals({s: {"x": rng.normal(0, 2.0, 50)} for s in segs}, {}, {})
    after = Residuals({s: {"x": rng.normal(0, 1.0, 50)} for s in segs}, {}, {})
    lo, hi = bootstrap_gain(before, after, segs, seed=5)
    assert (lo, hi) == bootstrap_gain(before, after, segs, seed=5)
    gain = before.rms() / after.rms()
    assert lo < gain < hi
    assert lo > 1.5 and hi < 2.7


def test_levenberg_marquardt_solves_a_bounded_fit():
    x = np.linspace(0, 1, 200)

    def fun(u):
        return u[0] * np.exp(-u[1] * x) - 3.0 * np.exp(-2.0 * x)

    u, nfev = levenberg_marquardt(fun, np.array([1.0, 1.0]), np.array([0.0, 0.0]),
                                  np.array([10.0, 10.0]), 200)
    assert np.allclose(u, [3.0, 2.0], rtol=1e-4) and nfev < 200
    u, _ = levenberg_marquardt(fun, np.array([1.0, 1.0]), np.array([0.0, 0.0]),
                               np.array([2.5, 10.0]), 200)
    assert u[0] == pytest.approx(2.5)  # held on its bound


def test_a_parameter_fitted_onto_its_bound_stays_within_it():
    """A fit that ends on a bound maps back as x0 + ((lo - x0) / s) s, which rounding put at
    -1.2e-10 N/m for a joint stiffness bounded at 0; the rig's validation refused it and the
    diagnosis ended in a traceback (independent second_mode case, seed 1)."""
    x0, s = 837407.452880671, 43843.939722600284
    u_lo = (0.0 - x0) / s
    assert x0 + u_lo * s < 0.0  # the rounding this guards against
    p = rig_param("stiffness_N_per_m", "effects.joint_microslip.stiffness_n_per_m", s, 0.0)
    m = apply(Model(RigParams()), [p], np.array([x0 + u_lo * s]))
    assert m.rig.effects.joint_microslip.stiffness_n_per_m == 0.0
    p_hi = rig_param("slip_force_N", "effects.joint_microslip.slip_force_n", 1.0, 1.0, 5.0)
    m = apply(Model(RigParams()), [p_hi], np.array([5.0 + 1e-9]))
    assert m.rig.effects.joint_microslip.slip_force_n == 5.0


def test_arx_guess_finds_a_linear_oscillator():
    from rig_model import simulate_response

    fs = 2000.0
    rig = RigParams().model_copy(update={"seal": RigParams().seal.model_copy(
        update={"enabled": False})})
    rng = np.random.default_rng(0)
    f = rng.normal(0, 10, 20000)
    tr, _ = simulate_response(np.vstack([f, 0 * f]), rig, fs, 0.0)
    rec = records_from_arrays(f, {"x": tr.x_m}, fs)
    m, c, k, off = arx_linear_guess(rec, [Segment(0, 0, 20000, "all")])
    assert k == pytest.approx(788e3, rel=0.05)
    assert m == pytest.approx(9.7, rel=0.1)


def test_config_baseline_needs_a_rig_for_imported_data():
    rec = _sine_record()
    with pytest.raises(DiagnoseError, match="--baseline config needs a rig configuration"):
        diagnose([rec], "config", [(0, 2000)], [(2000, 4096)])
    with pytest.raises(DiagnoseError, match="unknown effect"):
        diagnose([rec], "fitted", [(0, 2000)], [(2000, 4096)], effects=["gremlins"])


def test_load_run_errors_name_the_file(tmp_path):
    bad = tmp_path / "nope.h5"
    with pytest.raises(DiagnoseError, match="nope.h5"):
        load_run(bad)


def test_cli_json_report_and_extended_model(tmp_path, capsys):
    """End to end: a hidden cubic spring; the JSON contract; the TOML loads in the simulator."""
    case = make_case(tmp_path, ["cubic_stiffness"], 5)
    out = tmp_path / "out.json"
    rep = tmp_path / "report"
    rc = main(["diagnose", str(case.paths[0]), "--json", str(out), "--report", str(rep),
               "--quiet", "--effects", "cubic_stiffness,added_mass,sensor_gain",
               "--max-effects", "2"])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert set(doc) >= {"baseline", "findings", "unexplained", "extended_model"}
    assert doc["baseline"]["kind"] == "config" and doc["baseline"]["units"] == "m"
    f = doc["findings"][0]
    assert f["effect"] == "cubic_stiffness"
    assert set(f) >= {"parameters", "error_before", "error_after", "gain", "gain_interval",
                      "evidence"}
    k3 = case.effects["cubic_stiffness"]["k3_N_per_m3"]
    # measured -0.42 % at this seed (5), within 0.05 % at seeds 6-8: held to 2 %
    assert f["parameters"]["k3_N_per_m3"] == pytest.approx(k3, rel=0.02)
    assert f["gain"] == pytest.approx(f["error_before"] / f["error_after"])
    assert doc["baseline"]["rms_error"] == pytest.approx(f["error_before"])
    ext = load_rig_params(doc["extended_model"])
    assert ext.effects.cubic_stiffness.enabled
    assert ext.effects.cubic_stiffness.k3_n_per_m3 == pytest.approx(k3, rel=0.02)
    page = (rep / "index.html").read_text()
    assert "cubic_stiffness" in page and "dwells.png" in page
    for png in ("time.png", "dwells.png", "harmonics.png", "segments.png", "errors.png"):
        assert (rep / png).read_bytes()[:4] == b"\x89PNG"
    # its size with its sd from the data's noise, in the JSON, the CLI and the report
    size = f["evidence"]["size"]
    sd = size["sd"]["k3_N_per_m3"]
    assert 0 < sd < 0.02 * abs(k3)
    assert size["determined"] and f["evidence"]["confidence"] == "high"
    assert "k3_N_per_m3=" in page and " +- " in page
    cli = capsys.readouterr().out
    assert "found cubic_stiffness (k3_N_per_m3=" in cli and " +- " in cli
    # the extended model replays the data to the noise floor: diagnose it again
    rc = main(["diagnose", str(case.paths[0]), "--rig", doc["extended_model"], "--json",
               str(tmp_path / "again.json"), "--quiet", "--effects", "cubic_stiffness",
               "--max-effects", "1"])
    again = json.loads((tmp_path / "again.json").read_text())
    assert rc == 0 and again["findings"] == []
    # the same replay: measured identical (seeds 5-8)
    assert again["baseline"]["rms_error"] == pytest.approx(f["error_after"], rel=1e-9)


def test_the_start_leaves_out_an_axis_a_dwell_does_not_drive(tmp_path):
    """Dwells along x, along y and circular (independent generator, clean, lubricated): the
    undriven axis of a dwell (its force and motion only noise) gives no point, so each axis's
    start is its structure (before: x 3.85 kg, 0 N.s/m, 882 kN/m from 15 points; y none)."""
    case = make_independent_case(tmp_path, "clean", 1, rig_described=False, both_axes=True)
    rec = load_run(case.run)
    film = RigParams().film
    film_mass = film.fluid_mass_kg + film.added_mass()
    film_damping = film.eq16_damping_centred(film.viscosity_pa_s(24.0))
    for axis, k_n_per_m in ((0, 788e3), (1, 823e3)):
        est = one_mode_estimate([rec], rec.segments, axis, film_mass, film_damping)
        assert est is not None and est.points == 10  # 5 dwells along the axis, 5 circular
        assert est.stiffness_n_per_m == pytest.approx(k_n_per_m, rel=0.01)
        assert est.mass_kg == pytest.approx(9.7, rel=0.01)
        assert est.damping_ns_per_m == pytest.approx(370.0, rel=0.05)


def test_an_axis_is_driven_when_its_force_stands_above_its_own_noise():
    """Two x dwells with a y force: noise only (0.05 N white) gives no y point; 0.5 % of the x
    force, 40 sd above that noise, is a drive (the fixed 1 % of the other axis's force, before,
    left it out) and gives the y dynamic stiffness it was made with."""
    fs, n = 5000.0, 5000
    rng = np.random.default_rng(11)
    t = np.arange(2 * n) / fs
    e = np.exp(2j * math.pi * 30.0 * t)
    k_y = 5e5 - 2e3j  # the y dynamic stiffness [N/m]
    fx = np.real(200.0 * e)
    fy = np.where(t < n / fs, 0.0, np.real(1.0 * e)) + 0.05 * rng.standard_normal(2 * n)
    y = np.where(t < n / fs, 0.0, np.real(1.0 / k_y * e)) + 1e-9 * rng.standard_normal(2 * n)
    rec = records_from_arrays(np.vstack([fx, fy]), {"x": np.real(200.0 / 6e5 * e), "y": y},
                              fs)
    segs = [Segment(0, 0, n, "noise", 30.0, "x"), Segment(0, n, 2 * n, "0.5 %", 30.0, "x")]
    w, d, _ = dynamic_stiffness_points([rec], segs, 1)
    assert w.size == 1  # the second dwell only
    # the force noise's 1X error is 0.05 N x sqrt(2 / 5000) = 1e-3 of the 1 N: within 3 sd
    assert d[0] == pytest.approx(k_y, rel=3e-3)


def test_cli_coupled_axes_in_the_order_table_report_and_extended_model(tmp_path, capsys):
    """Imported without the rig description, rods turned from x and y (the independent
    generator): the CLI's order lines, the HTML table and the JSON show the coupled order
    chosen with its cross stiffness, and the extended rig TOML carries it."""
    case = make_independent_case(tmp_path, "coupled_axes", 3, rig_described=False)
    out, rep = tmp_path / "out.json", tmp_path / "report"
    rc = main(["diagnose", str(case.run), "--json", str(out), "--report", str(rep), "--quiet",
               "--effects", "cubic_stiffness", "--max-effects", "1"])
    assert rc == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "order:" in ln]
    assert len(lines) == 2  # one mode uncoupled, one mode coupled (no second mode asked for)
    assert "axes uncoupled" in lines[0] and "(chosen)" not in lines[0]
    assert "axes coupled (k_xy" in lines[1] and lines[1].endswith("(chosen)")
    doc = json.loads(out.read_text())
    base = doc["baseline"]
    want = case.truth["stiffness_xy_N_per_m"]
    assert base["coupled_axes"] is True
    # within 0.07 % at seeds 1-5 (independent_cases.COUPLING_TOLERANCE)
    assert base["parameters"]["stiffness_xy_N_per_m"] == pytest.approx(want,
                                                                      rel=COUPLING_TOLERANCE)
    assert [r["coupled_axes"] for r in base["order_selection"]] == [False, True]
    assert "axes coupled (k_xy" in (rep / "index.html").read_text()
    ext = load_rig_params(doc["extended_model"])
    assert ext.structure.stiffness_xy_n_per_m == pytest.approx(want, rel=COUPLING_TOLERANCE)


def test_cli_bad_input_exits_2(tmp_path, capsys):
    rc = main(["diagnose", str(tmp_path / "missing.h5")])
    assert rc == 2
    assert "missing.h5" in capsys.readouterr().err


def _joint_rig() -> RigParams:
    rig = RigParams()
    data = rig.model_dump()
    data["effects"]["joint_microslip"].update(enabled=True, stiffness_n_per_m=2e5,
                                              slip_force_n=5.0)
    return RigParams.model_validate(data)


def test_a_model_with_memory_replays_a_segment_before_the_drive_starts():
    """A record whose drive grows from nothing (the silverbox's arrow) has held-out samples
    before the drive's start, where a model with memory starts its replay: they are replayed
    from a warm-up before them, every sample (the window had started after them: no
    prediction, and every joint fit on the silverbox failed with a broadcast error)."""
    fs, n = 1000.0, 3000
    t = np.arange(n) / fs
    force = np.vstack([np.where(t > 1.0, 40 * np.sin(2 * np.pi * 30 * t), 0.0), np.zeros(n)])
    force[0] += 1e-3 * np.sin(2 * np.pi * 7 * t)  # the quiet start: not nothing
    rec = records_from_arrays(force, {"x": 1e-6 * np.sin(2 * np.pi * 30 * t)}, fs)
    ev = Evaluator([rec], warmup_s=0.5)
    assert ev._memory_start(0) > 100  # the drive starts after the first held-out block
    early, late = Segment(0, 100, 600, "block", None), Segment(0, 1200, 2400, "block", None)
    model = Model(rig=_joint_rig())
    res = residuals(ev, model, [late], [early, late])
    assert {s: v["x"].size for s, v in res.per_segment.items()} == {early: 500, late: 1200}
    assert math.isfinite(res.rms())


def test_a_steady_dwell_is_led_in_as_long_as_the_model_takes_to_forget_its_start():
    """A well-damped model's steady-state dwell is replayed after a lead of 20 of its decay
    times (`lead.py`), not the fixed warm-up (here the dwell's whole 1 s): the same response,
    to 1e-9 of its amplitude, as after the fixed warm-up; a joint (no bound on how long its
    loop takes to centre) keeps the fixed warm-up."""
    from analysis.diagnose.lead import slowest_decay_s
    from rig_model.rig import kernel_params, simulate_response

    fs, n, f_hz = 5000.0, 5000, 20.0
    t = np.arange(n) / fs
    force = np.vstack([40 * np.sin(2 * np.pi * f_hz * t), np.zeros(n)])
    base = RigParams()
    # damping ratio 0.72 (the harmonic-balance generator's lubricated housing): 6.6 ms
    rig = base.model_copy(update={
        "seal": base.seal.model_copy(update={"enabled": False}),
        "structure": base.structure.model_copy(update={"residual_damping_ns_per_m": 4000.0})})
    rec = records_from_arrays(force, {"x": 1e-6 * np.sin(2 * np.pi * f_hz * t)}, fs, rig=rig)
    rec.segments = [Segment(0, 0, n, "dwell", f_hz)]
    ev = Evaluator([rec], warmup_s=0.5, steady_state_dwells=True)
    assert ev._lead(0, 0, n) == n  # the fixed warm-up: the dwell's whole-period chunk
    tau = slowest_decay_s(kernel_params(rig, fs), ev._fill(rec), 1.0)
    short = ev.truth(Model(rig=rig), 0, 0, n)[0]
    lead = next(k[3] for k in ev._force_cache)
    assert lead < n / 4 and lead >= 20 * tau * fs
    # the fixed warm-up's replay: the dwell's force twice, the second scored
    ref, _ = simulate_response(np.hstack([force, force]), rig, fs, ev._fill(rec), 1.0)
    amp = float(np.max(np.abs(ref.x_m[n:])))
    assert float(np.max(np.abs(short - ref.x_m[n:]))) < 1e-9 * amp
    joint = _joint_rig().model_copy(update={"seal": rig.seal})
    assert slowest_decay_s(kernel_params(joint, fs), 1.0, 1.0) == math.inf


def test_a_linear_models_steady_dwell_is_its_periodic_state_however_slowly_it_decays():
    """A linear model's steady-state dwell is the kernel's periodic steady state itself
    (`periodic`), not a replay after a lead: with a frame mode of 0.5 % damping at 47 Hz
    (coupled to the film: 44 Hz, decay time 0.09 s) the fixed warm-up's 1 s lead left 3e-6 of
    the amplitude; the dwell matches a 40 s lead (440 decay times) to 1e-10 of it, in x and in
    the y the film's cross terms drive, with the oil warming over the window; a remainder
    after the last whole period follows its periodic state."""
    from rig_model.rig import simulate_response

    fs, n, f_hz = 5000.0, 5000, 20.0
    t = np.arange(n) / fs
    rng = np.random.default_rng(7)
    force = np.vstack([40 * np.sin(2 * np.pi * f_hz * t) + rng.normal(0.0, 2.0, n),
                       rng.normal(0.0, 2.0, n)])
    base = RigParams()
    eff = base.effects
    rig = base.model_copy(update={
        "seal": base.seal.model_copy(update={"enabled": False}),
        "contact": base.contact.model_copy(update={"enabled": False}),
        "film": base.film.model_copy(update={"eccentricity_law": False}),
        "effects": eff.model_copy(update={
            "second_mode": eff.second_mode.model_copy(update={
                "enabled": True, "frequency_hz": 47.0, "damping_ratio": 0.005,
                "modal_mass_kg": 60.0}),
            "cross_coupling": eff.cross_coupling.model_copy(update={
                "enabled": True, "c_xy_ns_per_m": 300.0, "c_yx_ns_per_m": -200.0})})})
    rec = records_from_arrays(force, {"x": np.zeros(n), "y": np.zeros(n)}, fs, rig=rig,
                              lubricated=True)
    rec.segments = [Segment(0, 0, n, "dwell", f_hz)]
    ev = Evaluator([rec], warmup_s=0.5, steady_state_dwells=True)
    got = ev.truth(Model(rig=rig), 0, 0, n)
    assert all(k[3] == 0 for k in ev._force_cache)  # no lead replayed
    # the oil warms over the window (the rig's configured warming): the lead at the
    # viscosity of the window's first sample
    visc = ev._viscosity_scale(Model(rig=rig), 0, 0, n)
    assert np.ptp(visc) > 0.0
    ref, _ = simulate_response(np.tile(force, (1, 41)), rig, fs, 1.0,
                               np.concatenate([np.full(40 * n, visc[0]), visc]))
    for row, z in ((0, ref.x_m), (1, ref.y_m), (4, ref.ax_m_per_s2)):
        amp = float(np.max(np.abs(z[-n:])))
        assert float(np.max(np.abs(got[row] - z[-n:]))) < 1e-10 * amp, row
    # what the 1 s lead gave
    assert float(np.max(np.abs(ref.x_m[n:2 * n] - ref.x_m[-n:]))) > 1e-6 * float(
        np.max(np.abs(ref.x_m[-n:])))
    # a dwell of 4.1 periods: its 4 whole periods periodic, the rest replayed after them
    m = int(4.1 * fs / f_hz)
    rec.segments = [Segment(0, 0, m, "dwell", f_hz)]
    ev = Evaluator([rec], warmup_s=0.5, steady_state_dwells=True)
    chunk = ev.periodic_chunk(rec.segments[0])
    assert chunk == 4 * int(fs / f_hz)
    still = Model(rig=rig.model_copy(update={"oil": rig.oil.model_copy(
        update={"warming_c_per_hour": 0.0})}))
    part = ev.truth(still, 0, 0, m)
    visc = ev._viscosity_scale(still, 0, 0, m)
    assert np.ptp(visc) == 0.0
    ref, _ = simulate_response(np.hstack([np.tile(force[:, :chunk], (1, 40)), force[:, :m]]),
                               still.rig, fs, 1.0, float(visc[0]))
    amp = float(np.max(np.abs(ref.x_m[-m:])))
    assert float(np.max(np.abs(part[0] - ref.x_m[-m:]))) < 1e-10 * amp
