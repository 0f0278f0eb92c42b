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
    within_excess_chi2,
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


def _case(seed: int, error=None, y_share: float = 0.0, third: float = 0.0,
          noise_m: float = NOISE_M):
    """A record and the residual of a model whose relative error of the measured 1X is
    ``error(freq, amp, t)`` (complex; None: no error), with the y probe responding to x by
    ``y_share`` of x's amplitude (the model predicting none), a 3X of ``third`` x's
    amplitude in x's residual and probe noise ``noise_m`` [m]."""
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
        nx, ny = rng.normal(0, noise_m, n), rng.normal(0, noise_m, n)
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
    # the chi-squares of the 1X error (over all dwells, within each frequency) see it too;
    # what names it is amplitude, over all dwells and among the dwells of each frequency
    top = next(r for r in found if "chi2" not in r)
    assert (top["test"], top["channel"], top["part"]) in (
        ("amplitude", "x", "re"), ("amplitude_within_frequency", "x", "re")), found[:3]
    for test in ("amplitude", "amplitude_within_frequency"):
        row = next(r for r in found if (r["test"], r["channel"], r["part"]) == (test, "x", "re"))
        assert 7.0 < row["z"] < 14.0, row
        assert row["size"] == pytest.approx(change, rel=0.15)
        assert "amplitude" in row["text"] and "sd)" in row["text"]
    assert not [r for r in found if r["test"] in ("time", "time_within_frequency",
                                                  "repeated_dwell", "other_axis")]


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


#: a quiet record: probe noise 0.1 um, so a 1X estimate's noise (2.2e-4 of |K| at 13 um over
#: 2500 samples, 0.75e-4 at 38 um) is well under the replay's resolution (1e-3)
QUIET_M = 0.1e-6


def _friction_like(sigmas: float):
    """A relative error of |K| falling as 1/A (dry friction's describing function beside a
    linear model's absorbed mean), ``sigmas`` noise sd of a quiet record's 13 um dwell there."""
    sd_13 = QUIET_M * math.sqrt(2 / (DWELL_S * FS)) / AMPS[0]
    return lambda f, a, t: sigmas * sd_13 * (AMPS[0] / a - 0.6)


@pytest.mark.parametrize(("sigmas", "flagged"), [(8.0, True), (2.0, False)])
def test_an_amplitude_dependence_under_the_replays_resolution_is_seen_within_frequencies(
        sigmas, flagged):
    # 8 sd of the noise on the smallest dwells is 1.8e-3 of |K|: under twice the replay's
    # resolution, which the tests over all dwells add to the noise, so they do not see it;
    # among dwells of one frequency the resolution cancels and the noise alone is the floor
    rows = _rows(*_case(11, error=_friction_like(sigmas), noise_m=QUIET_M))
    whole = {r["test"]: r for r in rows if r["channel"] == "x" and r["part"] in ("1X", "re")}
    assert not whole["fundamental"]["structure"] and not whole["amplitude"]["structure"]
    within = whole["within_frequency"]
    amp = whole["amplitude_within_frequency"]
    assert within["structure"] is flagged and amp["structure"] is flagged, (within, amp)
    if flagged:
        # the chi-square about each frequency's mean exceeds its dof by the error's own
        # (noncentrality: the error's weighted spread within each frequency, in noise
        # variances) within its noise; the log-amplitude slope's change over 13-38 um is the
        # error's (1/A is not a line in log A: within 25 %)
        err = _friction_like(sigmas)
        lam = 0.0
        for f in FREQS:
            amps = np.array([a for ff, a in _plan(11) if ff == f])
            w = (amps / QUIET_M) ** 2  # 1 / sd^2, up to a common factor
            y = np.array([err(f, a, 0.0) for a in amps])
            lam += float(np.sum(w * (y - np.sum(w * y) / np.sum(w)) ** 2)) * DWELL_S * FS / 2
        excess = within["chi2"] - within["dof"]
        assert excess == pytest.approx(lam, abs=3 * math.sqrt(2 * within["dof"] + 4 * lam))
        assert within["z"] > 8.0 and amp["z"] > 5.0, (within, amp)
        sd_13 = QUIET_M * math.sqrt(2 / (DWELL_S * FS)) / AMPS[0]
        truth = sigmas * sd_13 * (AMPS[0] / AMPS[-1] - 1.0)
        assert amp["size"] == pytest.approx(truth, rel=0.25)
        assert "same frequency" in amp["text"]
    else:
        assert within["z"] < 4.0 and amp["z"] < 4.0, (within, amp)


def test_an_error_that_follows_the_frequency_alone_is_no_structure_within_frequencies():
    # the replay's own resolution is a function of the frequency: 20 noise sd of the 38 um
    # dwells, the same at every amplitude, leaves nothing among the dwells of one frequency
    sd_38 = QUIET_M * math.sqrt(2 / (DWELL_S * FS)) / AMPS[-1]
    rows = _rows(*_case(12, error=lambda f, a, t: 20 * sd_38 * (f / 60.0) ** 2 * (1 + 0.5j),
                        noise_m=QUIET_M))
    within = [r for r in rows if r["test"].endswith("within_frequency")
              or r["test"] == "repeated_dwell"]
    assert len(within) >= 7 and max(r["z"] for r in within) < 4.0, within[:3]


def test_harmonics_above_nyquist_are_not_tested(monkeypatch):
    """At 250 Hz the 3X-5X of 50 and 60 Hz dwells are at or above Nyquist: a harmonic fit
    there aliases (its columns coincide with another harmonic's) and gave harmonics "1e8 of
    the 1X" on noise alone; only the harmonics below Nyquist are tested."""
    import tests.analysis.test_diagnose_structure as here

    monkeypatch.setattr(here, "FS", 250.0)
    monkeypatch.setattr(here, "DWELL_S", 2.0)
    rows = _rows(*_case(3))
    harm = next(r for r in rows if r["test"] == "harmonics" and r["channel"] == "x")
    assert not harm["structure"] and harm["z"] < 4.0, harm
    assert harm["size"] < 0.1, harm
    # below 125 Hz: 20 Hz dwells test 2X-5X, 30 Hz 2X-4X, 40 Hz 2X-3X, 50 and 60 Hz 2X only
    plan = here._plan(3)
    below = {20.0: 4, 30.0: 3, 40.0: 2, 50.0: 1, 60.0: 1}
    assert harm["dof"] == 2 * sum(below[f] for f, _ in plan)


def test_a_signature_under_the_replays_resolution_counts_among_dwells_of_one_frequency():
    # 8 noise sd of a friction-like error on the quiet record's 13 um dwells: under the
    # resolution the tests over every dwell add to the noise, so what a term modelling it
    # removes there is small; among dwells of one frequency it stands above 5 sd
    rec, before, segs = _case(11, error=_friction_like(8.0), noise_m=QUIET_M)
    _, after, _ = _case(11, noise_m=QUIET_M)  # the same noise, the error modelled
    rows_b, rows_a = (find_structure([rec], r, segs, 4) for r in (before, after))
    whole = math.sqrt(max(excess_chi2(rows_b) - excess_chi2(rows_a), 0.0))
    within = math.sqrt(within_excess_chi2(rows_b) - within_excess_chi2(rows_a))
    assert whole < 3.0 and within > 10.0, (whole, within)
    assert signature_sd([rec], before, after, segs, 4) == pytest.approx(within)
