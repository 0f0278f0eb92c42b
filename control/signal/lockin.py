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
    cache_size : int
        Windows (f, n) whose matrices are kept, least recently used dropped first. A window of
        n samples costs 8 n (1 + 2H) bytes: 0.8 MB for 3 cycles at 20 Hz and 62.5 kS/s.
    """

    def __init__(self, sample_rate_hz: float, n_harmonics: int = N_HARMONICS,
                 cache_size: int = 32) -> None:
        if not sample_rate_hz > 0:
            raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
        if n_harmonics < 1:
            raise ValueError(f"n_harmonics must be >= 1, got {n_harmonics}")
        self.fs = float(sample_rate_hz)
        self.n_harmonics = n_harmonics
        self.cache_size = max(1, cache_size)
        self._cache: OrderedDict[tuple[float, int], tuple[np.ndarray, np.ndarray]] = (
            OrderedDict())

    def _fit_matrices(self, freq_hz: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(basis (n, 1 + 2H), inverse Gram matrix (1 + 2H, 1 + 2H)) for a window of n samples.

        Basis columns: 1, cos(h w k), sin(h w k) for h = 1..H, k = 0..n-1 (local time); a
        harmonic at or above Nyquist gets zero columns and is not fitted.
        """
        key = (float(freq_hz), int(n))
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        h_max = self.n_harmonics
        if n < 1 + 2 * h_max:
            raise ValueError(f"window of {n} samples is too short to fit {h_max} harmonics")
        nyquist_h = self.fs / 2 / freq_hz
        # powers of one complex exponential: cheaper than 2H trigonometric evaluations
        e1 = np.exp(2j * np.pi * (freq_hz / self.fs) * np.arange(n))
        basis = np.zeros((n, 1 + 2 * h_max))
        basis[:, 0] = 1.0
        eh = e1.copy()
        for h in range(1, h_max + 1):
            if h < nyquist_h:
                basis[:, 2 * h - 1] = eh.real
                basis[:, 2 * h] = eh.imag
            eh *= e1
        # normal equations: over whole cycles the columns are nearly orthogonal, so the small
        # Gram matrix is well conditioned
        gram = basis.T @ basis
        active = np.diag(gram) > 0
        ginv = np.zeros_like(gram)
        ginv[np.ix_(active, active)] = np.linalg.inv(gram[np.ix_(active, active)])
        self._cache[key] = (basis, ginv)
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return basis, ginv

    def _coefficients(self, x2: np.ndarray, freq_hz: float) -> tuple[np.ndarray, np.ndarray]:
        basis, ginv = self._fit_matrices(freq_hz, x2.shape[1])
        return (x2 @ basis) @ ginv, basis

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
        coef, _ = self._coefficients(x2, freq_hz)  # (n_ch, 1 + 2H)
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
        basis, ginv = self._fit_matrices(freq_hz, n)
        bx = x @ basis
        coef = bx @ ginv
        # |x - B c|^2 = |x|^2 - (B'x)' c for the least-squares c: no residual array needed
        ss = np.maximum(np.einsum("ij,ij->i", x, x) - np.einsum("ij,ij->i", bx, coef), 0.0)
        dof = max(n - basis.shape[1], 1)
        sigma = np.sqrt(ss / dof) * np.sqrt(2.0 / n)
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


class LockInAccumulator:
    """The same least-squares lock-in, accumulated block by block as the samples arrive.

    A tracking filter for long records: each block adds its share of ``B'x``, ``B'B`` and
    ``x'x`` (B the basis in the run's absolute time), so no work piles up at the end of the
    window, which matters when the acquisition loop runs against the clock.

    Parameters
    ----------
    sample_rate_hz : float
    freq_hz : float
        Fundamental [Hz].
    first, last : int
        Half-open window of run samples to accumulate.
    n_rows : int
        Rows (signals) per block.
    n_harmonics : int
    """

    def __init__(self, sample_rate_hz: float, freq_hz: float, first: int, last: int,
                 n_rows: int, n_harmonics: int = N_HARMONICS) -> None:
        if last <= first:
            raise ValueError(f"empty window [{first}, {last})")
        self.fs = float(sample_rate_hz)
        self.freq_hz = float(freq_hz)
        self.first, self.last = int(first), int(last)
        self.n_harmonics = n_harmonics
        m = 1 + 2 * n_harmonics
        self._bx = np.zeros((n_rows, m))
        self._bb = np.zeros((m, m))
        self._xx = np.zeros(n_rows)
        self._next = self.first  # next sample expected
        self._fitted = np.array(
            [True] + [h < self.fs / 2 / self.freq_hz
                      for h in range(1, n_harmonics + 1) for _ in (0, 1)]
        )

    @property
    def complete(self) -> bool:
        return self._next >= self.last

    def add(self, first_sample: int, block: np.ndarray) -> None:
        """Add the part of ``block`` (n_rows, n) that falls in the window; contiguous order."""
        n = block.shape[1]
        lo = max(self._next, first_sample)
        hi = min(self.last, first_sample + n)
        if hi <= lo:
            return
        if lo != self._next:
            raise ValueError(f"gap: expected sample {self._next}, got {lo}")
        x = block[:, lo - first_sample:hi - first_sample]
        ratio = self.freq_hz / self.fs
        phase0 = math.fmod(ratio * lo, 1.0)
        e1 = np.exp(2j * np.pi * (phase0 + ratio * np.arange(hi - lo)))
        basis = np.zeros((hi - lo, 1 + 2 * self.n_harmonics))
        basis[:, 0] = 1.0
        eh = e1.copy()
        for h in range(1, self.n_harmonics + 1):
            basis[:, 2 * h - 1] = eh.real
            basis[:, 2 * h] = eh.imag
            eh *= e1
        basis[:, ~self._fitted] = 0.0
        self._bx += x @ basis
        self._bb += basis.T @ basis
        self._xx += np.einsum("ij,ij->i", x, x)
        self._next = hi

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(harmonics (n_rows, H) complex, mean (n_rows,), standard error of 1X (n_rows,))."""
        if not self.complete:
            raise ValueError(f"window incomplete: have up to {self._next}, need {self.last}")
        act = self._fitted
        ginv = np.zeros_like(self._bb)
        ginv[np.ix_(act, act)] = np.linalg.inv(self._bb[np.ix_(act, act)])
        coef = self._bx @ ginv
        harm = coef[:, 1::2] - 1j * coef[:, 2::2]
        n = self.last - self.first
        ss = np.maximum(self._xx - np.einsum("ij,ij->i", self._bx, coef), 0.0)
        sigma = np.sqrt(ss / max(n - int(act.sum()), 1)) * np.sqrt(2.0 / n)
        return harm, coef[:, 0], sigma
