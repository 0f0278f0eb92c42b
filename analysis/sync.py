"""Synchronous (and harmonic) components of a dwell over whole cycles (report eq. 12-13).

Convention (contract A): ``z(t) = z_c cos(wt) + z_s sin(wt) = Re(Z e^{iwt})`` with
``Z = z_c - i z_s`` and ``t = sample / fs`` counted from sample 0 of the run.
"""

from __future__ import annotations

import numpy as np

N_HARMONICS = 5


def whole_cycle_span(first_sample: int, last_sample: int, freq_hz: float,
                     sample_rate_hz: float) -> tuple[int, int, float]:
    """Trim ``[first_sample, last_sample)`` to a whole number of cycles.

    Returns
    -------
    (first, last, cycles)
        The trimmed half-open span [samples] and the number of whole cycles it holds.
    """
    n = last_sample - first_sample
    if n <= 0 or freq_hz <= 0:
        return first_sample, first_sample, 0.0
    cycles = np.floor(n * freq_hz / sample_rate_hz + 1e-6)
    n_whole = int(round(cycles * sample_rate_hz / freq_hz))
    return first_sample, first_sample + min(n, n_whole), float(cycles)


def harmonics(signals: np.ndarray, first_sample: int, freq_hz: float, sample_rate_hz: float,
              n_harmonics: int = N_HARMONICS) -> tuple[np.ndarray, np.ndarray]:
    """Complex amplitudes of 1X..nX of each signal, by least squares over the span.

    Parameters
    ----------
    signals : ndarray, shape (n_sig, n) or (n,)
        Samples of a dwell in engineering units, sample ``first_sample`` first.
    first_sample : int
        Run-relative index of the first sample (sets the phase reference t = 0).
    freq_hz : float
        Fundamental (excitation) frequency [Hz].
    sample_rate_hz : float
        Sample rate [S/s].
    n_harmonics : int
        Number of harmonics (1X..nX).

    Returns
    -------
    amplitudes : ndarray, complex, shape (n_sig, n_harmonics) (or (n_harmonics,))
        ``Z_k = z_c,k - i z_s,k`` in the signal's units.
    mean : ndarray, shape (n_sig,) (or scalar)
        The DC component.

    Over a whole number of cycles the least-squares fit equals the DFT bins; the fit also stays
    exact when fs/f is not an integer.
    """
    sig = np.asarray(signals, dtype=np.float64)
    one = sig.ndim == 1
    sig2 = sig[None, :] if one else sig
    n = sig2.shape[1]
    if n < 2 * n_harmonics + 1:
        raise ValueError(f"{n} samples are too few for {n_harmonics} harmonics")
    # phase from the run's sample 0; reduce modulo one cycle to keep precision
    k0 = np.arange(n, dtype=np.float64) + first_sample
    phase = 2 * np.pi * np.mod(k0 * freq_hz / sample_rate_hz, 1.0)
    cols = [np.ones(n)]
    for h in range(1, n_harmonics + 1):
        cols.append(np.cos(h * phase))
        cols.append(np.sin(h * phase))
    basis = np.stack(cols, axis=1)
    # normal equations: the sampled sines are nearly orthogonal over several cycles, so B^T B is
    # well conditioned, and this is ~50x faster than an SVD on a tall (n, 2h+1) matrix
    gram = basis.T @ basis
    coef = np.linalg.solve(gram, basis.T @ sig2.T).T
    amps = coef[:, 1::2] - 1j * coef[:, 2::2]
    mean = coef[:, 0]
    if one:
        return amps[0], mean[0]
    return amps, mean


def synthesize(amplitudes: np.ndarray, freq_hz: float, t_s: np.ndarray,
               mean: float = 0.0, derivative: int = 0) -> np.ndarray:
    """Rebuild ``sum_k Re(Z_k (ikw)^d e^{ikwt}) + mean`` from harmonics (derivative d = 0, 1, 2)."""
    w = 2 * np.pi * freq_hz
    out = np.full(np.shape(t_s), mean if derivative == 0 else 0.0, dtype=np.float64)
    for k, z in enumerate(np.atleast_1d(amplitudes), start=1):
        out += np.real(z * (1j * k * w) ** derivative * np.exp(1j * k * w * t_s))
    return out


def amplitude_spectrum(signal: np.ndarray, sample_rate_hz: float,
                       max_freq_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-sided amplitude spectrum (peak units) of a span, Hann window, for waterfalls.

    Returns (frequencies [Hz], amplitudes [signal units, peak]).
    """
    x = np.asarray(signal, dtype=np.float64)
    x = x - x.mean()
    n = x.size
    win = np.hanning(n)
    spec = np.abs(np.fft.rfft(x * win)) * 2.0 / win.sum()
    freqs = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    if max_freq_hz is not None:
        keep = freqs <= max_freq_hz
        freqs, spec = freqs[keep], spec[keep]
    return freqs, spec
