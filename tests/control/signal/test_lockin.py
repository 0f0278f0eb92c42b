"""Lock-in demodulation: exact on synthetic signals, harmonics, eq. 12-13 convention."""

from __future__ import annotations

import numpy as np
import pytest

from control.signal.lockin import LockIn, cycles_to_samples, relative_change

FS = 10_000.0


def _signal(first: int, n: int, f: float, dc: float, z: list[complex]) -> np.ndarray:
    k = np.arange(first, first + n)
    s = np.full(n, dc)
    for h, zh in enumerate(z, start=1):
        s += (zh * np.exp(1j * h * 2 * np.pi * f * k / FS)).real
    return s


def test_fundamental_and_harmonics_exact_on_any_window():
    z = [1.5 - 2.0j, 0.1 + 0.3j, -0.05j, 0.02, 0.007 - 0.001j]
    li = LockIn(FS)
    for f, first, n in [(20.0, 0, 5000), (33.3, 123_457, 1234), (199.7, 9_999_999, 777)]:
        x = _signal(first, n, f, 0.25, z)
        harm, mean = li.demodulate(x, first, f)
        np.testing.assert_allclose(harm, z, atol=1e-10)
        assert mean == pytest.approx(0.25, abs=1e-10)


def test_convention_of_eq_12():
    """z = zc cos(wt) + zs sin(wt) -> Z = zc - i zs, with t = k / fs from the run's sample 0."""
    f, first, n = 40.0, 2500, 2000
    t = np.arange(first, first + n) / FS
    w = 2 * np.pi * f
    x = 3.0 * np.cos(w * t) + 4.0 * np.sin(w * t)
    assert LockIn(FS).fundamental(x, first, f) == pytest.approx(3.0 - 4.0j, abs=1e-10)


def test_many_channels_at_once():
    li = LockIn(FS)
    rows = np.stack([_signal(77, 3000, 55.0, 0.0, [a]) for a in (1.0, 2j, -0.5 + 0.5j)])
    np.testing.assert_allclose(li.fundamental(rows, 77, 55.0), [1.0, 2j, -0.5 + 0.5j],
                               atol=1e-10)


def test_harmonic_above_nyquist_is_not_fitted():
    li = LockIn(1000.0)
    k = np.arange(1000)
    x = np.cos(2 * np.pi * 150.0 * k / 1000.0)
    harm, _ = li.demodulate(x, 0, 150.0)
    assert harm[0] == pytest.approx(1.0, abs=1e-10)
    assert np.all(harm[3:] == 0)  # 4X = 600 Hz and 5X are above 500 Hz


def test_cycles_to_samples_and_change():
    assert cycles_to_samples(20.0, FS, 10) == 5000
    assert cycles_to_samples(30.0, FS, 2) == 667
    with pytest.raises(ValueError):
        cycles_to_samples(0.0, FS, 1)
    assert relative_change(np.array([1.0]), np.array([1.01]), np.array([1.0])) == \
        pytest.approx(0.01)
    with pytest.raises(ValueError, match="too short"):
        LockIn(FS).demodulate(np.zeros(5), 0, 10.0)


def test_the_matrix_cache_keeps_the_most_recent_windows():
    li = LockIn(10_000.0, cache_size=3)
    x = np.cos(2 * np.pi * 50.0 * np.arange(1000) / 10_000.0)
    for n in range(800, 1000, 20):  # ten windows
        li.demodulate(x[:n], 0, 50.0)
    assert [k[1] for k in li._cache] == [940, 960, 980]
    z, _ = li.demodulate(x[:960], 0, 50.0)  # a hit moves to the end, and fits as before
    assert abs(z[0]) == pytest.approx(1.0, rel=1e-3)
    assert [k[1] for k in li._cache] == [940, 980, 960]
