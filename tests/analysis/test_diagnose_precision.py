"""How well the data determine a finding's size (``analysis.diagnose.precision``): the
parameters' standard deviations from the Jacobian and the residual's own noise, per sample,
per segment and per frequency (coloured noise), and the rule that a size not pinned down to
its effect's tolerance is no confident finding (issue 24 deliverable 2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose.precision import coloured_spread, determined, doubt, spread

N_SEG = 12
N = 400  # samples per segment


def _line(rng: np.random.Generator, offsets: np.ndarray, sigma: float):
    """Segments of y = a x + (the segment's own offset) + noise, fitted with a alone at its
    least-squares value: the Jacobian (-x per segment) and the residuals."""
    xs = [rng.uniform(-1.0, 1.0, N) for _ in range(N_SEG)]
    ys = [1.0 * x + o + rng.normal(0.0, sigma, N) for x, o in zip(xs, offsets, strict=True)]
    x_all, y_all = np.concatenate(xs), np.concatenate(ys)
    a = float(x_all @ y_all / (x_all @ x_all))
    return a, [-x[:, None] for x in xs], [y - a * x for x, y in zip(xs, ys, strict=True)]


def test_per_sample_sd_is_the_noise_over_the_regressors_norm() -> None:
    # white noise sigma 0.1 on 4800 samples of x ~ U(-1, 1): sd(a) = 0.1 / sqrt(4800 / 3)
    # = 2.5e-3; the fitted a scatters by that over seeds, and both estimates say so
    fits, samples, segments = [], [], []
    for seed in range(200):
        a, jac, r = _line(np.random.default_rng(seed), np.zeros(N_SEG), 0.1)
        s, g = spread(jac, r)
        fits.append(a)
        samples.append(s[0])
        segments.append(g[0])
    assert np.mean(samples) == pytest.approx(2.5e-3, rel=0.03)
    assert np.std(fits) == pytest.approx(2.5e-3, rel=0.15)
    # per segment it is an estimate from 12 segments: right on average, scattering by ~20 %
    assert np.mean(segments) == pytest.approx(2.5e-3, rel=0.1)


def test_a_misfit_the_segments_disagree_on_raises_the_per_segment_sd() -> None:
    # each segment offset by its own 0.3 (a model error the line does not hold) on regressors
    # that differ per segment: the fitted slope moves with the offsets far beyond the noise;
    # the per-sample sd counts the misfit as white noise and misses it, the per-segment one
    # sees it
    rng = np.random.default_rng(3)
    offsets = rng.normal(0.0, 0.3, N_SEG)
    a, jac, r = _line(rng, offsets, 0.01)
    jac = [j + shift for j, shift in zip(jac, rng.uniform(-0.5, 0.5, N_SEG), strict=True)]
    sample, segment = spread(jac, r)
    assert segment[0] > 3 * sample[0]


def test_coloured_noise_under_the_parameters_frequencies_raises_its_sd() -> None:
    # a parameter that moves the record as a slow sine (8 cycles in a segment, as a dwell's
    # 1X) under noise low-passed (AR(1) 0.95, as the model's response to the load cell's
    # noise): the fitted amplitude scatters 2.3x more than the per-sample sd says; the
    # spectral one (the residual's own periodogram about each frequency) says it to 15 %;
    # on white noise the two agree
    t = np.arange(N)
    jac = [np.column_stack([np.sin(2 * math.pi * 0.02 * t), np.ones(N)])] * N_SEG
    full = np.vstack(jac)
    fits, samples, spectra = [], [], []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        r = []
        for _ in range(N_SEG):
            e = rng.normal(0.0, 0.1, N + 200)
            for i in range(1, e.size):
                e[i] += 0.95 * e[i - 1]
            r.append(e[200:])
        fits.append(np.linalg.lstsq(full, np.concatenate(r), rcond=None)[0][0])
        samples.append(spread(jac, r)[0][0])
        spectra.append(coloured_spread(jac, r, [[N]] * N_SEG)[0])
    assert np.mean(samples) < 0.6 * np.std(fits)
    assert np.mean(spectra) == pytest.approx(np.std(fits), rel=0.15)
    white = [np.random.default_rng(7).normal(0.0, 0.1, N) for _ in range(N_SEG)]
    assert coloured_spread(jac, white, [[N // 2, N // 2]] * N_SEG)[0] == pytest.approx(
        spread(jac, white)[0][0], rel=0.1)


def test_a_parameter_the_others_explain_is_undetermined() -> None:
    rng = np.random.default_rng(5)
    x = [rng.normal(size=(N, 1)) for _ in range(N_SEG)]
    jac = [np.hstack([v, 2 * v, rng.normal(size=(N, 1))]) for v in x]  # columns 0 and 1 alike
    r = [rng.normal(0.0, 0.1, N) for _ in range(N_SEG)]
    sample, segment = spread(jac, r)
    assert math.isinf(sample[0]) and math.isinf(sample[1]) and math.isinf(segment[0])
    assert math.isfinite(sample[2]) and sample[2] == pytest.approx(0.1 / math.sqrt(N * N_SEG),
                                                                   rel=0.1)


def test_a_diverged_replay_leaves_every_size_undetermined() -> None:
    jac = [np.ones((N, 2))] * 3
    r = [np.full(N, np.inf)] + [np.zeros(N)] * 2
    assert all(math.isinf(v) for v in np.concatenate(spread(jac, r)))


def test_a_size_is_determined_within_its_tolerance_by_its_sd_and_its_move() -> None:
    # k3 1e12 with tolerance 10 %: sd 3e10 alone (3 %) or a move of 5e10 alone (5 %) pins it
    # down; together 5.8 %; a move of 1e11 on a joint refit does not (10.4 %)
    assert determined(1e12, 3e10, 0.0, 0.10)
    assert determined(1e12, 3e10, 5e10, 0.10)
    assert doubt(3e10, 5e10) == pytest.approx(5.83e10, rel=1e-3)
    assert not determined(1e12, 3e10, 1e11, 0.10)
    # a negative size (a softening spring) by its magnitude; an infinite sd never
    assert determined(-1e12, 3e10, 0.0, 0.10)
    assert not determined(1e12, math.inf, 0.0, 0.10)


def test_a_finding_gives_each_size_with_its_sd() -> None:
    from analysis.diagnose.candidates import Finding

    f = Finding("sensor_gain", {"channel": "x", "gain_ratio": 1.0412}, 1.0, 0.5, 2.0,
                (1.5, 2.5), {"size": {"sd": {"gain_ratio": 0.0013}}}, None, None)  # type: ignore[arg-type]
    assert f.parameters_text() == "channel=x, gain_ratio=1.041 +- 0.0013"
    # without a size (the second mode the order chose) the values alone
    f.evidence = {}
    assert f.parameters_text() == "channel=x, gain_ratio=1.041"
