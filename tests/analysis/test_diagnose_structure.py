"""Structure in a residual above its own noise floor (issue 24, deliverable 1): the tests of
``analysis.diagnose.residual_structure`` on dwells whose "model error" is known exactly.

Each case is a record of X dwells (5 frequencies x 3 amplitudes in shuffled order, the first
dwell repeated at the end, 0.5 s at 5 kHz, probe noise 2 um on x and y: a noisy record, so the
noise, not the replay's resolution, sets the floor) and a residual built
as the measured response times a known relative error of the dynamic stiffness (plus the noise
the model cannot predict). Pure noise must show no structure; an error varying with amplitude,
with time, a response of the undriven axis, or a harmonic, each sized at about ten noise
standard deviations, must be named by its own test, with its size.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.model import Residuals
from analysis.diagnose.residual_structure import (
    excess_chi2,
    find_structure,
    signature_sd,
    z_of_chi2,
)
from analysis.diagnose.verdict import judge

FS = 5000.0
FREQS = (20.0, 30.0, 40.0, 50.0, 60.0)
AMPS = (13e-6, 25e-6, 38e-6)
DWELL_S = 0.5
NOISE_M = 2e-6


def _plan(seed: int) -> list[tuple[float, float]]:
    grid = [(f, a) for a in AMPS for f in FREQS]
    order = np.random.default_rng(seed).permutation(len(grid))
    plan = [grid[i] for i in order]
    return plan + [plan[0]]


def _case(seed: int, error=None, y_share: float = 0.0, third: float = 0.0):
    """A record and the residual of a model whose relative error of the measured 1X is
    ``error(freq, amp, t)`` (complex; None: no error), with the y probe responding to x by
    ``y_share`` of x's amplitude (the model predicting none) and a 3X of ``third`` x's
    amplitude in x's residual."""
    rng = np.random.default_rng(seed)
    plan = _plan(seed)
    n = int(DWELL_S * FS)
    total = n * len(plan)
    t_all = np.arange(total) / FS
    x = np.zeros(total)
    y = np.zeros(total)
    rx = np.zeros(total)
    ry = np.zeros(total)
    segs = []
    for i, (f, a) in enumerate(plan):
        sl = slice(i * n, (i + 1) * n)
        t = t_all[sl]
        w = 2 * math.pi * f
        clean = a * np.cos(w * t - 0.3)
        e = error(f, a, float(t.mean())) if error else 0.0
        nx, ny = rng.normal(0, NOISE_M, n), rng.normal(0, NOISE_M, n)
        x[sl] = clean + nx
        # a dynamic stiffness (1 + e) times the model's: the model predicts (1 + e) times the
        # measured 1X, so the residual (measured - predicted) is -e times it
        rx[sl] = (np.real(-e * a * np.exp(1j * (w * t - 0.3))) + nx
                  + third * a * np.cos(3 * w * t))
        y_clean = y_share * a * np.cos(w * t + 0.4)
        y[sl] = y_clean + ny
        ry[sl] = y_clean + ny
        segs.append(Segment(0, i * n, (i + 1) * n, f"d{i}", f, "x"))
    rec = RunRecord("synthetic", FS, np.zeros((2, total)), {"x": x, "y": y}, {"x": 0, "y": 1},
                    t_oil_c=24.0 + rng.normal(0, 0.02, total), lubricated=True,
                    kind="imported", segments=segs)
    res = Residuals({s: {"x": rx[s.start:s.stop], "y": ry[s.start:s.stop]} for s in segs},
                    {}, {})
    return rec, res, segs


def _rows(rec, res, segs, n_params=4):
    return find_structure([rec], res, segs, n_params)


@pytest.mark.parametrize("seed", range(8))
def test_noise_alone_shows_no_structure(seed):
    rows = _rows(*_case(seed))
    assert rows, "no test was made"
    assert not [r for r in rows if r["structure"]], rows[:3]
    # the statistics are of noise: the largest of ~40 tests stays within a few sd
    assert max(r["z"] for r in rows) < 4.0, rows[0]
    fundamental = next(r for r in rows if r["test"] == "fundamental" and r["channel"] == "x")
    # the replay's resolution is added to the noise: the chi-square falls a little below its
    # degrees of freedom, never far above
    assert -3.5 < fundamental["z"] < 3.0, fundamental


def test_a_stiffness_changing_with_amplitude_is_named_with_its_size():
    # +2 % in |K| from 13 to 38 um, log-linear, centred: about 10 sd of the slope
    change = 0.02
    rows = _rows(*_case(3, error=lambda f, a, t: change * (math.log(a / AMPS[0])
                                                           / math.log(AMPS[-1] / AMPS[0]) - 0.5)))
    found = [r for r in rows if r["structure"]]
    # the chi-square of the 1X error ("fundamental") sees it too; what names it is amplitude
    top = next(r for r in found if r["test"] != "fundamental")
    assert (top["test"], top["channel"], top["part"]) == ("amplitude", "x", "re"), found[:3]
    assert 7.0 < top["z"] < 14.0, top
    assert top["size"] == pytest.approx(change, rel=0.15)
    assert "amplitude" in top["text"] and "sd)" in top["text"]
    assert not [r for r in found if r["test"] in ("time", "repeated_dwell", "other_axis")]


def test_a_drift_over_the_run_shows_in_time_and_the_repeated_dwell():
    duration = DWELL_S * 16
    # the damping (quadrature) drifting by 0.04 rad over the run
    rows = _rows(*_case(5, error=lambda f, a, t: 0.04j * (t / duration - 0.5)))
    found = {(r["test"], r["part"]) for r in rows if r["structure"] and r["channel"] == "x"}
    assert ("time", "im") in found and ("repeated_dwell", "im") in found, found
    time_row = next(r for r in rows if (r["test"], r["part"], r["channel"]) == ("time", "im", "x"))
    # the dwells' centres span 0.25..7.75 s of the 8 s run: 15/16 of the drift
    assert time_row["size"] == pytest.approx(0.04 * 15 / 16, rel=0.15)
    # the oil temperature here is a constant with noise: no structure against it
    assert ("oil_temperature", "im") not in found


def test_the_undriven_axis_responding_is_named():
    # y moving 2 % of x at 1X: 0.26-0.76 um against 2 um noise over 2500 samples per dwell
    # (a 1X estimate's sd 0.06 um)
    rows = _rows(*_case(7, y_share=0.02))
    other = next(r for r in rows if r["test"] == "other_axis")
    assert other["channel"] == "y" and other["structure"], other
    assert not [r for r in rows if r["structure"] and r["channel"] == "x"]


def test_harmonics_the_model_does_not_predict_are_named():
    rows = _rows(*_case(9, third=2e-2))
    harm = next(r for r in rows if r["test"] == "harmonics" and r["channel"] == "x")
    assert harm["structure"], harm
    assert harm["size"] == pytest.approx(2e-2, rel=0.1)


def test_the_noise_scale_is_the_datas_own():
    # the same error, three times the noise: the significance falls about threefold
    err = lambda f, a, t: 0.02 * (math.log(a / AMPS[0]) / math.log(3) - 0.5)  # noqa: E731
    rec, res, segs = _case(3, error=err)
    quiet = next(r for r in _rows(rec, res, segs) if r["test"] == "amplitude"
                 and r["part"] == "re" and r["channel"] == "x")
    rng = np.random.default_rng(99)
    for s in segs:
        extra = rng.normal(0, math.sqrt(8) * NOISE_M, s.n)
        rec.responses["x"][s.start:s.stop] += extra
        res.per_segment[s]["x"] = res.per_segment[s]["x"] + extra
    noisy = next(r for r in _rows(rec, res, segs) if r["test"] == "amplitude"
                 and r["part"] == "re" and r["channel"] == "x")
    assert 2.2 < quiet["z"] / noisy["z"] < 3.8, (quiet["z"], noisy["z"])


def test_wilson_hilferty_matches_the_chi_square():
    # chi-square at its median: 0 sd; at the quantiles of 3 and 5 sd (scipy.stats.chi2.isf
    # of norm.sf(3), norm.sf(5): 58.62 and 85.74 at 30 degrees of freedom, 45.57 at 8 for 5 sd)
    assert abs(z_of_chi2(29.34, 30)) < 0.05
    assert z_of_chi2(58.62, 30) == pytest.approx(3.0, abs=0.05)
    assert z_of_chi2(85.74, 30) == pytest.approx(5.0, abs=0.1)
    assert z_of_chi2(45.57, 8) == pytest.approx(5.0, abs=0.15)


def test_structure_makes_the_verdict_unexplained():
    rec, res, segs = _case(3, error=lambda f, a, t: 0.02 * (math.log(a / AMPS[0])
                                                          / math.log(3) - 0.5))
    rows = _rows(rec, res, segs)
    clean_rec, clean_res, clean_segs = _case(3)
    # measured signals minus residuals: the fits' explained fractions are near 1 in both
    noise = {"x": NOISE_M**2, "y": NOISE_M**2}
    with_structure = judge([rec], res, res, segs, noise, None, rows)
    assert with_structure.text == "unexplained discrepancy"
    assert {"amplitude", "fundamental"} <= {r["test"] for r in with_structure.structure}
    without = judge([clean_rec], clean_res, clean_res, clean_segs, noise, None,
                    _rows(clean_rec, clean_res, clean_segs))
    assert without.text == "explained"


def test_a_terms_signature_is_the_structure_it_removes_in_noise_sd():
    err = lambda f, a, t: 0.02 * (math.log(a / AMPS[0]) / math.log(3) - 0.5)  # noqa: E731
    rec, before, segs = _case(3, error=err)
    # the same record with the error modelled: what is left is the noise alone
    after = Residuals({s: {ch: v.copy() for ch, v in before.per_segment[s].items()}
                       for s in segs}, {}, {})
    clean_rec, clean, _ = _case(3)
    for s in segs:
        after.per_segment[s]["x"] = clean.per_segment[s]["x"]
    sig = signature_sd([rec], before, after, segs, 4)
    rows = find_structure([rec], before, segs, 4)
    fundamental = next(r for r in rows if r["test"] == "fundamental" and r["channel"] == "x")
    # the 1X chi-square's excess over its dof is what the term removes
    assert sig == pytest.approx(math.sqrt(fundamental["chi2"] - fundamental["dof"]), rel=0.1)
    assert sig > 10.0
    # a term that removes nothing but noise has no signature to speak of
    assert signature_sd([clean_rec], clean, clean, segs, 4) == 0.0
    assert excess_chi2(find_structure([clean_rec], clean, segs, 4)) < 60.0
