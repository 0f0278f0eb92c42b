"""The parameters a candidate's joint refit moves (``engine._refit_params``): the baseline's,
except the spring of an axis no run drives and no dwell moves above its noise, which the data
hardly fix (issue 24, deliverable 2: 15 N of seal friction on x dwells was refitted to 17.1 N
with y's spring free, 15.0 N with it held; tests/independent_hb's friction_large)."""

from __future__ import annotations

import math

import numpy as np

from analysis.diagnose.baseline import baseline_params
from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.effects import Context
from analysis.diagnose.engine import _refit_params
from analysis.diagnose.model import Model
from rig_model.params import RigParams

FS = 5000.0
#: probe noise on both axes [m]: a 1X estimate over one 1 s dwell scatters by
#: 0.05 um * sqrt(2 / 5000) = 1 nm per component
PROBE_NOISE_M = 0.05e-6
X_STIFF = ["mass_kg", "damping_Ns_per_m", "stiffness_x_N_per_m"]
BOTH = [*X_STIFF, "stiffness_y_N_per_m"]


def _names(force_y_share: float, y_response_share: float) -> list[str]:
    """The refit's parameters on one 1 s dwell at 30 Hz, 30 N on x and ``force_y_share`` of
    it on y (a load cell's noise of 0.05 N besides), the y probe moving ``y_response_share``
    of x's 38 um besides its noise."""
    rng = np.random.default_rng(3)
    t = np.arange(int(FS)) / FS
    wave = np.sin(2 * math.pi * 30.0 * t)
    force = np.vstack([30.0 * wave, force_y_share * 30.0 * wave])
    force += rng.normal(0.0, 0.05, force.shape)
    resp = {"x": 38e-6 * wave + rng.normal(0.0, PROBE_NOISE_M, t.size),
            "y": y_response_share * 38e-6 * wave + rng.normal(0.0, PROBE_NOISE_M, t.size)}
    seg = Segment(0, 0, t.size, "dwell 30 Hz", 30.0, "x")
    rec = RunRecord("refit", FS, force, resp, {"x": 0, "y": 1}, lubricated=True,
                    kind="imported", segments=[seg])
    model = Model(RigParams())
    ctx = Context(records=[rec], base=model, fitted_baseline=True, duration_s=1.0,
                  x_rms_m=27e-6, f_rms_n=21.2, f_typ_hz=30.0)
    return [p.name for p in _refit_params(baseline_params(model, [rec]), ctx, [seg])]


def test_the_spring_of_a_still_axis_is_held():
    # y's force is its load cell's noise (0.05 N against 21 N RMS on x) and its probe noise:
    # its spring is held, the mode's mass and damping and x's spring move with the candidate
    assert _names(0.0, 0.0) == X_STIFF


def test_an_undriven_axis_that_responds_keeps_its_spring_free():
    # y moving 0.2 % of x (76 nm, about 76 sd of its 1X estimate's noise): the response
    # fixes its spring; at 0.002 % (0.76 nm, under 1 sd) it is still
    assert _names(0.0, 2e-3) == BOTH
    assert _names(0.0, 2e-5) == X_STIFF


def test_every_spring_moves_where_both_axes_are_driven():
    # 20 % of x's force on y is a drive (data.driven_axes: 10 % RMS)
    assert _names(0.2, 0.0) == BOTH
