"""The oil's temperature in diagnose: the course a viscosity drift follows (``oil.py``), the
warm-up of a lubricated fitted baseline, and the film's cross terms the data can show."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose.baseline import data_start
from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.effects import LIBRARY, Context, extended_rig
from analysis.diagnose.model import Evaluator, Model
from analysis.diagnose.oil import drift_course, mean_temperature
from analysis.diagnose.residual_structure import Z_STRUCTURE
from rig_model.params import VISCOSITY_SLOPE_PER_C, RigParams

FS = 2000.0


def _record(temp: np.ndarray, force_y: float = 0.0, noise_y: float = 0.0) -> RunRecord:
    """x driven at 30 Hz (100 N), y by ``force_y`` at 30 Hz, its load cell reading seeded
    noise of ``noise_y`` N RMS."""
    n = temp.size
    t = np.arange(n) / FS
    x = 20e-6 * np.sin(2 * math.pi * 30 * t)
    force = np.vstack([100.0 * np.sin(2 * math.pi * 30 * t),
                       force_y * np.sin(2 * math.pi * 30 * t)
                       + np.random.default_rng(11).normal(0.0, noise_y, n)])
    return RunRecord("synthetic", FS, force, {"x": x, "y": 0.05 * x}, {"x": 0, "y": 1},
                     t_oil_c=temp, lubricated=True, kind="imported",
                     segments=[Segment(0, 0, n, "all", 30.0)])


def test_a_drift_follows_the_recorded_temperature_through_eq1() -> None:
    """Oil warming 24 -> 41.3 C along a bent course (fast, then slower), recorded with 0.05 C
    of noise: the drift's share is the temperature's, so the film's damping scaled by
    (1 + r) ** (u - u_model) is eq. 1's exp(-0.01665 (T - T_model)) within 0.2 % at every
    sample, where a share of time would be off by 6 %."""
    rng = np.random.default_rng(7)
    n = int(16 * FS)
    tau = np.arange(n) / n
    rise = -math.log(0.75) / VISCOSITY_SLOPE_PER_C  # 17.28 C: the film damping -25 %
    true_t = 24.0 + rise * (1 - np.exp(-3 * tau)) / (1 - math.exp(-3))
    rec = _record(true_t + rng.normal(0, 0.05, n))
    course = drift_course([rec], Z_STRUCTURE)
    assert course.follows_temperature
    assert course.first_c == pytest.approx(24.0, abs=0.05)
    assert course.last_c == pytest.approx(24.0 + rise, abs=0.05)
    t_mean = mean_temperature([rec])
    assert t_mean is not None
    ev = Evaluator([rec], drift=course)
    model = Model(RigParams().model_copy(update={"oil": RigParams().oil.model_copy(
        update={"initial_temperature_c": t_mean, "warming_c_per_hour": 0.0})}),
        visc_relative_change=-0.25)
    u = course.share(0, np.arange(n) / FS, n / FS) - ev.drift_anchor(model)
    drift = 0.75**u
    law = np.exp(-VISCOSITY_SLOPE_PER_C * (true_t - t_mean))
    assert np.max(np.abs(drift / law - 1)) < 2e-3
    time_share = 0.75 ** (tau - ev.drift_anchor(model))
    assert np.max(np.abs(time_share / law - 1)) > 0.05


def test_a_temperature_that_stays_within_its_noise_leaves_the_drift_on_time() -> None:
    rng = np.random.default_rng(3)
    n = int(4 * FS)
    rec = _record(24.0 + rng.normal(0, 0.05, n))
    course = drift_course([rec], Z_STRUCTURE)
    assert not course.follows_temperature
    assert course.describe() == "time"
    t = np.array([0.0, 1.0, 2.0])
    assert np.allclose(course.share(0, t, 4.0), t / 4.0)
    assert course.model_share(24.0) == 0.0


def test_the_warm_up_counts_the_films_damping() -> None:
    """Lubricated dwells of a rig whose warm oil gives 75 % of the film's nominal damping: the
    structure's own share is then nothing (the start clips it), but the mode still decays in
    2 M / C = 7 ms with the film; the warm-up is the least, 0.5 s (it was 30 s, and with it
    a fit on 2 of 11 dwells)."""
    rig = RigParams()
    film = rig.film
    m_tot = rig.structure.mass_kg + film.fluid_mass_kg + film.added_mass()
    c_tot = 0.75 * film.eq16_damping_centred(film.viscosity_pa_s(24.0))
    k = rig.structure.stiffness_x_n_per_m
    segs, xs, fs_ = [], [], []
    n = int(FS)
    t = np.arange(n) / FS
    for i, f in enumerate((20.0, 30.0, 40.0, 50.0, 60.0)):
        w = 2 * math.pi * f
        dyn = k - w**2 * m_tot + 1j * w * c_tot
        xs.append(np.real(20e-6 * np.exp(1j * w * t)))
        fs_.append(np.real(dyn * 20e-6 * np.exp(1j * w * t)))
        segs.append(Segment(0, i * n, (i + 1) * n, f"d{i}", f))
    x = np.concatenate(xs)
    force = np.vstack([np.concatenate(fs_), np.zeros(x.size)])
    rec = RunRecord("warm", FS, force, {"x": x}, {"x": 0}, lubricated=True, kind="imported",
                    segments=segs)
    notes: list[str] = []
    model, warmup = data_start([rec], segs, rig, notes, lambda msg: None)
    assert warmup == 0.5
    assert model.rig.structure.stiffness_x_n_per_m == pytest.approx(k, rel=1e-6)


def _context(records: list[RunRecord]) -> Context:
    return Context(records=records, base=Model(RigParams()), fitted_baseline=True,
                   duration_s=4.0, x_rms_m=14e-6, f_rms_n=70.0, f_typ_hz=30.0)


def test_the_film_cross_terms_fitted_are_those_from_a_driven_axis() -> None:
    """x dwells (the y load cell reads noise of 1/100 of x's force): C_yx and D_yx, what y's
    response to x's motion shows; both axes driven: all four."""
    n = int(4 * FS)
    temp = np.full(n, 24.0)
    eff = LIBRARY["cross_coupling"]
    x_only = _context([_record(temp, noise_y=1.0)])
    assert eff.applicable(x_only) is None
    (var,) = eff.variants(x_only, x_only.base)
    assert [p.name for p in var.params] == ["c_yx_Ns_per_m", "d_yx_kg"]
    both = _context([_record(temp, force_y=80.0)])
    (var,) = eff.variants(both, both.base)
    assert [p.name for p in var.params] == ["c_xy_Ns_per_m", "c_yx_Ns_per_m", "d_xy_kg",
                                            "d_yx_kg"]
    one_sensor = _context([RunRecord("x only", FS, np.ones((2, n)), {"x": np.zeros(n)},
                                     {"x": 0}, lubricated=True)])
    assert "both axes" in str(eff.applicable(one_sensor))


def test_the_extended_rig_warms_from_where_the_drift_starts() -> None:
    """A film held at 32.64 C (the data's mean) half-way through a -25 % drift over 16 s: the
    rig the simulator loads starts at 24.0 C and warms 17.28 C over the 16 s (eq. 1)."""
    rise = -math.log(0.75) / VISCOSITY_SLOPE_PER_C
    rig = RigParams()
    held = rig.model_copy(update={"oil": rig.oil.model_copy(
        update={"initial_temperature_c": 24.0 + 0.5 * rise, "warming_c_per_hour": 0.0})})
    ext = extended_rig(Model(held, visc_relative_change=-0.25), 16.0, drift_anchor=0.5)
    assert ext.oil.initial_temperature_c == pytest.approx(24.0, abs=1e-9)
    assert ext.effects.viscosity_drift.warming_c_per_s * 16.0 == pytest.approx(rise, rel=1e-9)
