"""The parameters a candidate's joint refit moves (``engine._refit_params``): the baseline's,
except the spring of an axis no run drives, which the data hardly fix (issue 24, deliverable
2: 15 N of seal friction on x dwells was refitted to 17.1 N with y's spring free, 15.0 N
with it held; tests/independent_hb's friction_large)."""

from __future__ import annotations

import math

import numpy as np

from analysis.diagnose.baseline import baseline_params
from analysis.diagnose.data import RunRecord
from analysis.diagnose.effects import Context
from analysis.diagnose.engine import _refit_params
from analysis.diagnose.model import Model
from rig_model.params import RigParams

FS = 5000.0


def _record(force_y_share: float) -> RunRecord:
    """One second of a 30 Hz, 30 N force on x and ``force_y_share`` of it on y (a load cell's
    noise of 0.05 N besides), probes on both axes."""
    rng = np.random.default_rng(3)
    t = np.arange(int(FS)) / FS
    fx = 30.0 * np.sin(2 * math.pi * 30.0 * t)
    force = np.vstack([fx, force_y_share * fx]) + rng.normal(0.0, 0.05, (2, t.size))
    resp = {"x": fx / 788e3, "y": force_y_share * fx / 1.6e6}
    return RunRecord("refit", FS, force, resp, {"x": 0, "y": 1}, lubricated=True,
                     kind="imported")


def _names(force_y_share: float) -> list[str]:
    rec = _record(force_y_share)
    model = Model(RigParams())
    ctx = Context(records=[rec], base=model, fitted_baseline=True, duration_s=1.0,
                  x_rms_m=27e-6, f_rms_n=21.2, f_typ_hz=30.0)
    return [p.name for p in _refit_params(baseline_params(model, [rec]), ctx)]


def test_the_spring_of_an_axis_no_run_drives_is_held():
    # y's force is its load cell's noise (0.05 N against 21 N RMS on x): its spring is held,
    # the mode's mass and damping and x's spring move with the candidate
    assert _names(0.0) == ["mass_kg", "damping_Ns_per_m", "stiffness_x_N_per_m"]


def test_every_spring_moves_where_both_axes_are_driven():
    # 20 % of x's force on y is a drive (data.driven_axes: 10 % RMS)
    assert _names(0.2) == ["mass_kg", "damping_Ns_per_m", "stiffness_x_N_per_m",
                           "stiffness_y_N_per_m"]
