"""Whether held-out data tell two models apart (``analysis.diagnose.distinguish``): the excess
of one's squared error over the other's against the noise floor, the replay's resolution taken
off once; the rule behind a finding's "ambiguous", the swap check and the sensor pair check
(issue 24 deliverable 2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose.data import Segment, records_from_arrays
from analysis.diagnose.distinguish import Z_DISTINCT, held_out_difference
from analysis.diagnose.model import Residuals

FS = 5000.0
F_HZ = 20.0
N = 5000  # one second: 20 periods


def _sine(amplitude: float, phase: float = 0.0) -> np.ndarray:
    t = np.arange(N) / FS
    return amplitude * np.cos(2 * math.pi * F_HZ * t + phase)


def _difference(meas: list[np.ndarray], worse: list[np.ndarray], better: list[np.ndarray]):
    """The difference of two models' predictions of the measured dwells ``meas``."""
    records = [records_from_arrays(np.zeros(N), {"x": m}, FS) for m in meas]
    segs = [Segment(i, 0, N, f"d{i}", F_HZ, "x") for i in range(len(meas))]

    def res(pred: list[np.ndarray]) -> Residuals:
        return Residuals({s: {"x": m - p} for s, m, p in zip(segs, meas, pred, strict=True)},
                         {s: {"x": p} for s, p in zip(segs, pred, strict=True)}, {})

    return held_out_difference(records, res(worse), res(better), segs)


def _z(truth: np.ndarray, worse: np.ndarray, better: np.ndarray, sigma: float,
       seed: int) -> float:
    meas = truth + np.random.default_rng(seed).normal(0.0, sigma, N)
    return _difference([meas], [worse], [better]).z


def test_the_excess_in_noise_sd_follows_the_noise() -> None:
    # a model off by a sine of amplitude a against the right one, noise sigma over n samples:
    # excess a^2 n / 2, its noise sd 2 sigma |d| = sigma a sqrt(2 n), the resolution's bias
    # 2e-3 |p| |d| = 1e-3 A a n (A = 10 the signal), so
    # z = a sqrt(n / 2) / (2 sigma) - 1e-3 A sqrt(n / 2) / sigma: 0.1 -> 2.5 - 0.5 = 2.0 sd,
    # 0.4 -> 10.0 - 0.5 = 9.5 sd
    truth = _sine(10.0)
    small = [_z(truth, truth + _sine(0.1, 0.3), truth, 1.0, seed) for seed in range(40)]
    large = [_z(truth, truth + _sine(0.4, 0.3), truth, 1.0, seed) for seed in range(40)]
    assert np.mean(small) == pytest.approx(2.0, abs=0.3)
    assert np.mean(large) == pytest.approx(9.5, abs=0.5)
    assert max(small) < Z_DISTINCT <= min(large)


def test_two_models_equally_wrong_scatter_by_one_sd() -> None:
    # the null: each model off by the same sine in opposite sense (equally good), on a signal
    # small enough for the resolution's bias to be negligible (0.03 sd): z ~ N(0, 1) from the
    # noise floor the harmonics leave
    truth = _sine(0.1)
    d = _sine(0.3, 1.0)
    z = np.array([_z(truth, truth + d, truth - d, 1.0, seed) for seed in range(300)])
    assert abs(float(np.mean(z))) < 0.2
    assert 0.85 < float(np.std(z)) < 1.15
    assert float(np.max(np.abs(z))) < Z_DISTINCT


def test_a_low_noise_record_tells_a_clearly_worse_runner_up_apart() -> None:
    # noise 1e-3 of the signal; the runner-up misses by a sine of 5e-3 of it: 13.5x the right
    # model's mean square. The resolution's bias 2e-3 |p| |d| is 2e-3 / 5e-3 = 0.4 of the
    # excess, taken off once: 0.6 of it stands 0.6 a sqrt(n / 2) / (2 sigma) = 75 sd above the
    # noise. Counted as a deviation in quadrature (it is 50x the noise's), the same excess
    # would stand only 1 / 0.4 = 2.5 "sd": "alike"
    truth = _sine(1.0)
    diff = _difference([truth + np.random.default_rng(1).normal(0.0, 1e-3, N)],
                       [truth + _sine(5e-3, 0.5)], [truth])
    assert diff.bias == pytest.approx(0.4 * diff.excess, rel=0.05)
    assert diff.z == pytest.approx(75.0, rel=0.1)
    assert diff.excess / math.hypot(diff.sd, diff.bias) < Z_DISTINCT
    assert diff.distinct


def test_noise_free_data_are_judged_against_the_replays_resolution() -> None:
    # without noise a difference finer than twice the replay's resolution (1e-3 of the
    # response) is not told apart, one above it is
    truth = _sine(1.0)
    assert not _difference([truth], [truth + _sine(1.5e-3)], [truth]).distinct
    assert _difference([truth], [truth + _sine(2.5e-3)], [truth]).distinct


def test_a_period_that_is_not_like_the_others_does_not_hide_the_preference() -> None:
    # the better model misses the first period of each dwell (a settling it does not replay):
    # a period-to-period scatter of the difference would take it for noise in every period;
    # the noise floor (what the harmonics leave over the dwell) holds it once, spread over the
    # dwell (z 86)
    rng = np.random.default_rng(7)
    truth = _sine(1.0)
    settle = np.zeros(N)
    settle[:250] = 0.05 * np.exp(-np.arange(250) / 50.0)
    meas = [truth + settle + rng.normal(0.0, 1e-3, N) for _ in range(3)]
    z = _difference(meas, [truth + _sine(0.01)] * 3, [truth] * 3).z
    assert z > 50


def test_a_diverged_replay_of_the_worse_model_is_worse_and_of_the_better_unknown() -> None:
    truth = _sine(1.0)
    assert _difference([truth], [np.full(N, np.inf)], [truth]).distinct
    worse_is_finite = _difference([truth], [truth], [np.full(N, np.inf)])
    assert math.isnan(worse_is_finite.z) and not worse_is_finite.distinct


# --- among dwells of one frequency (``within_frequency_z``) --------------------------------
# The records of tests/analysis/test_diagnose_structure.py: 5 frequencies x 3 amplitudes, the
# residual the measured 1X times a known relative error of the dynamic stiffness plus noise.

def _within_lambda(err, seed: int) -> float:
    """The noncentrality of an error ``err`` among dwells of one frequency: its weighted
    spread about each frequency's mean, in noise variances (the quiet record's)."""
    from tests.analysis.test_diagnose_structure import DWELL_S, FREQS, QUIET_M, _plan
    lam = 0.0
    for f in FREQS:
        amps = np.array([a for ff, a in _plan(seed) if ff == f])
        w = (amps / QUIET_M) ** 2  # 1 / sd^2 up to a common factor
        y = np.array([err(f, a, 0.0) for a in amps])
        lam += float(np.sum(w * (y - np.sum(w * y) / np.sum(w)) ** 2)) * DWELL_S * FS / 2
    return lam


@pytest.mark.parametrize("sigmas", [4.0, 8.0])
def test_a_model_missing_what_varies_with_amplitude_is_told_apart_at_the_noise(sigmas):
    # a friction-like error (1/A) under the replay's resolution, missed by the worse model:
    # among dwells of one frequency the excess is |d|^2 with noise sd 2 |d|, so z = |d| / 2,
    # |d|^2 the error's noncentrality there (4 sd on the 13 um dwells: 3.1; 8 sd: 6.2)
    from analysis.diagnose.distinguish import within_frequency_z
    from tests.analysis.test_diagnose_structure import QUIET_M, _case, _friction_like

    rec, worse, segs = _case(11, error=_friction_like(sigmas), noise_m=QUIET_M)
    _, better, _ = _case(11, noise_m=QUIET_M)  # the same noise, the error modelled
    z = within_frequency_z([rec], worse, better, segs)
    expected = math.sqrt(_within_lambda(_friction_like(sigmas), 11)) / 2
    assert z == pytest.approx(expected, abs=1.0)
    assert (z >= Z_DISTINCT) is (sigmas == 8.0)


def test_an_error_that_follows_the_frequency_alone_tells_nothing_within_frequencies():
    # the replay's own kind of error (the same at every amplitude of a frequency), 20 noise sd
    # of the 38 um dwells: it cancels among the dwells of one frequency, to the noise's share
    # of the measured 1X (the error is relative to it)
    from analysis.diagnose.distinguish import within_frequency_z
    from analysis.diagnose.residual_structure import within_frequency_deviations
    from tests.analysis.test_diagnose_structure import AMPS, QUIET_M, _case

    sd_38 = QUIET_M * math.sqrt(2 / (0.5 * FS)) / AMPS[-1]
    rec, worse, segs = _case(12, error=lambda f, a, t: 20 * sd_38 * (f / 60.0) ** 2 * (1 + 0.5j),
                             noise_m=QUIET_M)
    _, better, _ = _case(12, noise_m=QUIET_M)
    ub, floor = within_frequency_deviations([rec], better, segs)
    uw, _ = within_frequency_deviations([rec], worse, segs, floor)
    assert len(ub) == 16
    assert max(abs(uw[k] - ub[k]) for k in ub) < 0.01  # noise sd
    assert within_frequency_z([rec], worse, better, segs) < Z_DISTINCT


def test_two_models_equally_wrong_within_frequencies_scatter_by_one_sd():
    # the null: each model off by the same friction-like error in the opposite sense
    from analysis.diagnose.distinguish import within_frequency_z
    from tests.analysis.test_diagnose_structure import QUIET_M, _case, _friction_like

    err = _friction_like(4.0)
    z = []
    for seed in range(40):
        rec, worse, segs = _case(seed, error=err, noise_m=QUIET_M)
        _, better, _ = _case(seed, error=lambda f, a, t: -err(f, a, t), noise_m=QUIET_M)
        z.append(within_frequency_z([rec], worse, better, segs))
    assert abs(float(np.mean(z))) < 0.4
    assert 0.7 < float(np.std(z)) < 1.3
    assert float(np.max(np.abs(z))) < Z_DISTINCT
