"""Whether held-out data tell two models apart (``analysis.diagnose.distinguish``): the paired
difference of their squared errors against its own noise, the rule behind a finding's
"ambiguous", the swap check and the sensor pair check (issue 24 item 2)."""

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


def _dwell(run: int = 0, label: str = "d0") -> Segment:
    return Segment(run, 0, N, label, F_HZ, "x")


def _residuals(seg_meas_pred: dict[Segment, tuple[np.ndarray, np.ndarray]]) -> Residuals:
    per = {seg: {"x": meas - pred} for seg, (meas, pred) in seg_meas_pred.items()}
    pred = {seg: {"x": p} for seg, (_, p) in seg_meas_pred.items()}
    return Residuals(per, pred, {})


def _records(n_runs: int = 1) -> list:
    return [records_from_arrays(np.zeros(N), {"x": np.zeros(N)}, FS) for _ in range(n_runs)]


def _sine(amplitude: float, phase: float = 0.0) -> np.ndarray:
    t = np.arange(N) / FS
    return amplitude * np.cos(2 * math.pi * F_HZ * t + phase)


def _z(truth: np.ndarray, pred_worse: np.ndarray, pred_better: np.ndarray, sigma: float,
       seed: int) -> float:
    meas = truth + np.random.default_rng(seed).normal(0.0, sigma, N)
    seg = _dwell()
    return held_out_difference(_records(), _residuals({seg: (meas, pred_worse)}),
                               _residuals({seg: (meas, pred_better)}), [seg]).z


def test_the_difference_in_noise_sd_follows_the_noise() -> None:
    # a model off by a sine of amplitude a against the right one, noise sigma over n samples:
    # excess |d|^2 = a^2 n / 2, its sd 2 sigma |d| = sigma a sqrt(2 n), so
    # z = a sqrt(n) / (2 sqrt(2) sigma): 0.1 -> 2.5 sd, 0.4 -> 10 sd
    truth = _sine(10.0)
    small = [_z(truth, truth + _sine(0.1, 0.3), truth, 1.0, seed) for seed in range(40)]
    large = [_z(truth, truth + _sine(0.4, 0.3), truth, 1.0, seed) for seed in range(40)]
    assert np.mean(small) == pytest.approx(2.5, abs=0.5)
    assert np.mean(large) == pytest.approx(10.0, abs=1.0)
    # under the noise the small one is told apart in no seed, the large one in every seed
    assert max(small) < Z_DISTINCT
    assert min(large) >= Z_DISTINCT


def test_two_models_equally_wrong_scatter_by_one_sd() -> None:
    # the null: each model off by the same sine in opposite sense; their held-out errors are
    # equal but for the noise, and the block scatter gives that noise's sd (z ~ N(0, 1))
    truth = _sine(10.0)
    d = _sine(0.3, 1.0)
    z = np.array([_z(truth, truth + d, truth - d, 1.0, seed) for seed in range(300)])
    assert abs(float(np.mean(z))) < 0.2
    assert 0.8 < float(np.std(z)) < 1.25
    assert float(np.max(np.abs(z))) < Z_DISTINCT


def test_noise_free_data_are_judged_against_the_replays_resolution() -> None:
    # without noise the blocks do not scatter; a difference finer than the replay's
    # resolution (1e-3 of the response) is not told apart, a clear one is
    truth = _sine(1.0)
    fine = _z(truth, truth + _sine(1e-4), truth, 0.0, 0)
    clear = _z(truth, truth + _sine(0.05), truth, 0.0, 0)
    assert fine == pytest.approx(0.05, rel=0.05)
    assert clear == pytest.approx(25.0, rel=0.05)


def test_a_segment_against_the_preferred_model_keeps_the_two_alike() -> None:
    # on the first dwell the better model is far better, on the second far worse: the totals
    # prefer it by many sd, but neither describes every dwell
    rng = np.random.default_rng(7)
    a, b = _dwell(0, "a"), _dwell(1, "b")
    truth = _sine(10.0)
    meas = {s: truth + rng.normal(0.0, 1.0, N) for s in (a, b)}
    worse = _residuals({a: (meas[a], truth + _sine(2.0)), b: (meas[b], truth)})
    better = _residuals({a: (meas[a], truth), b: (meas[b], truth + _sine(1.0))})
    diff = held_out_difference(_records(2), worse, better, [a, b])
    assert diff.z >= Z_DISTINCT
    assert diff.contrary == ["b"]
    assert not diff.distinct


def test_a_diverged_replay_of_the_worse_model_is_worse() -> None:
    seg = _dwell()
    truth = _sine(1.0)
    worse = _residuals({seg: (truth, np.full(N, np.inf))})
    better = _residuals({seg: (truth, truth)})
    assert held_out_difference(_records(), worse, better, [seg]).distinct
