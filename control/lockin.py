"""Lock-in (synchronous) demodulation over whole cycles.

For a window of samples ``k0 .. k0 + n - 1`` at a known frequency ``f``, every channel is fitted in
the least-squares sense with a constant plus harmonics 1X..5X:

    s[k] = s0 + sum_h Re(Z_h exp(i h w k / fs)),   w = 2 pi f,

so ``Z_h`` is the complex amplitude of harmonic ``h`` in the convention of eq. 12-13
(``z(t) = z_c cos(wt) + z_s sin(wt) = Re(Z e^{iwt})``, ``Z = z_c - i z_s``), with ``t = k / fs``
counted from sample 0 of the run. The window should span whole cycles (`cycles_to_samples`); the
least-squares fit is exact for a window of any length, so the rounding of a cycle to a whole
number of samples leaves no leakage.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

N_HARMONICS = 5


def cycles_to_samples(freq_hz: float, sample_rate_hz: float, cycles: float) -> int:
    """Number of samples closest to ``cycles`` whole periods at ``freq_hz`` (at least 1)."""
    if not freq_hz > 0:
        raise ValueError(f"freq_hz must be > 0, got {freq_hz}")
    return max(1, int(round(cycles * sample_rate_hz / freq_hz)))


class LockIn:
    """Least-squares synchronous demodulator, with the fitting matrices cached per (f, n).

    Parameters
    ----------
    sample_rate_hz : float
        Sample clock [S/s].
    n_harmonics : int
        Harmonics to fit (1X..n X); 5 by default.
    """

    def __init__(self, sample_rate_hz: float, n_harmonics: int = N_HARMONICS) -> None:
        if not sample_rate_hz > 0:
            raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
        if n_harmonics < 1:
            raise ValueError(f"n_harmonics must be >= 1, got {n_harmonics}")
        self.fs = float(sample_rate_hz)
        self.n_harmonics = n_harmonics
        self._cache: OrderedDict[tuple[float, int], tuple[np.ndarray, np.ndarray]] = OrderedDict()

    def _projector(self, freq_hz: float, n: int) -> np.ndarray:
        """Pseudo-inverse of the local basis [1, cos(h w k), sin(h w k)], shape (1 + 2H, n)."""
        return self._fit_matrices(freq_hz, n)[0]

    def _fit_matrices(self, freq_hz: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(pseudo-inverse (1 + 2H, n), basis (n, 1 + 2H)) for a window of n samples."""
        key = (float(freq_hz), int(n))
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        h_max = self.n_harmonics
        nyquist_h = self.fs / 2 / freq_hz
        if n < 1 + 2 * h_max:
            raise ValueError(f"window of {n} samples is too short to fit {h_max} harmonics")
        k = np.arange(n)
        cols = [np.ones(n)]
        for h in range(1, h_max + 1):
            ph = 2 * np.pi * h * freq_hz * k / self.fs
            if h < nyquist_h:
                cols += [np.cos(ph), np.sin(ph)]
            else:  # at or above Nyquist the harmonic cannot be told apart: fit nothing for it
                cols += [np.zeros(n), np.zeros(n)]
        basis = np.stack(cols, axis=1)
        proj = np.linalg.pinv(basis)
        self._cache[key] = (proj, basis)
        if len(self._cache) > 64:
            self._cache.popitem(last=False)
        return proj, basis

    def demodulate(
        self, block: np.ndarray, first_sample: int, freq_hz: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Complex harmonic amplitudes of every row of ``block``.

        Parameters
        ----------
        block : array (n_ch, n) or (n,)
            Samples in any unit.
        first_sample : int
            Run sample index of ``block[..., 0]`` (sets the phase reference t = k / fs).
        freq_hz : float
            Fundamental frequency [Hz].

        Returns
        -------
        harmonics : complex array (n_ch, n_harmonics) (or (n_harmonics,) for 1-D input)
            ``Z_h`` for h = 1..n_harmonics, in the block's unit.
        mean : array (n_ch,) (or scalar)
            The constant term.
        """
        x = np.asarray(block, dtype=np.float64)
        one_d = x.ndim == 1
        x2 = x[None, :] if one_d else x
        n = x2.shape[1]
        coef = x2 @ self._projector(freq_hz, n).T  # (n_ch, 1 + 2H)
        c = coef[:, 1::2]
        s = coef[:, 2::2]
        local = c - 1j * s
        # local time origin is first_sample: rotate back to t = 0 of the run
        frac = math.fmod(freq_hz * first_sample / self.fs, 1.0)
        h = np.arange(1, self.n_harmonics + 1)
        harm = local * np.exp(-2j * np.pi * h * frac)[None, :]
        if one_d:
            return harm[0], coef[0, 0]
        return harm, coef[:, 0]

    def fundamental_with_error(
        self, block: np.ndarray, first_sample: int, freq_hz: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """1X of every row of a 2-D block and its standard error.

        The error is what the fit leaves unexplained (noise, harmonics above the fitted ones,
        non-periodic motion): ``rms(residual) * sqrt(2 / n)`` per row, in the block's unit.
        """
        x = np.asarray(block, dtype=np.float64)
        n = x.shape[1]
        proj, basis = self._fit_matrices(freq_hz, n)
        coef = x @ proj.T
        resid = x - coef @ basis.T
        dof = max(n - basis.shape[1], 1)
        sigma = np.sqrt(np.sum(resid * resid, axis=1) / dof) * np.sqrt(2.0 / n)
        frac = math.fmod(freq_hz * first_sample / self.fs, 1.0)
        z = (coef[:, 1] - 1j * coef[:, 2]) * np.exp(-2j * np.pi * frac)
        return z, sigma

    def fundamental(self, block: np.ndarray, first_sample: int, freq_hz: float) -> np.ndarray:
        """Complex amplitude of 1X of every row, shape (n_ch,) (scalar for 1-D input)."""
        harm, _ = self.demodulate(block, first_sample, freq_hz)
        return harm[..., 0]


def relative_change(previous: np.ndarray, current: np.ndarray, scale: np.ndarray) -> float:
    """max_c |current_c - previous_c| / scale_c: how far two successive estimates differ.

    Used for settling detection: a response has settled when successive whole-cycle windows at the
    same drive agree within a small fraction of their magnitude.
    """
    prev = np.atleast_1d(np.asarray(previous, dtype=np.complex128))
    cur = np.atleast_1d(np.asarray(current, dtype=np.complex128))
    sc = np.atleast_1d(np.asarray(scale, dtype=np.float64))
    return float(np.max(np.abs(cur - prev) / sc))
