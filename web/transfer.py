"""The rig's transfer function across a sweep, from the recorded samples of each step.

For one step, its recorded span (``first_sample`` to ``last_sample``, whole cycles at the
step's frequency) is split into `MAX_SEGMENTS` (or fewer) segments of whole cycles (of at most
`MAX_SEGMENT_SAMPLES`, spread over a long record); each
segment's displacement X_k and force F_k at the drive frequency come from a one-bin Fourier sum
(the segment's mean removed). The averages give

* the receptance H = X/F by the H1 estimator: H = sum(X_k F_k*) / sum(|F_k|^2) [m/N],
* the dynamic stiffness K = 1/H [N/m] (k - m w^2 + j c w for a linear rig), and
* the magnitude-squared coherence g2 = |sum X_k F_k*|^2 / (sum |X_k|^2 sum |F_k|^2): 1 when
  every segment shows the same ratio, lower when noise or a drifting, non-linear response
  (stick-slip, contact) spoils it. One segment has no coherence (it would be 1 by definition).

This is computed from the samples themselves, never from the controller's own lock-in result,
so it checks what the controller reports. No I/O here (`web.history` reads the samples).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TypedDict

import numpy as np

MAX_SEGMENTS = 8
#: samples per segment at most: a long record (1,500 cycles at 20 Hz and 62.5 kS/s is 4.7 M
#: samples a channel) is judged on whole-cycle segments spread over it, so the web process
#: reads a bounded part of each step (about 0.1 s of CPU) beside the paced daemon
MAX_SEGMENT_SAMPLES = 100_000
#: below this coherence the page greys the step's points and shows the value
COHERENCE_LOW = 0.9
#: the direct axes of each motion: a single-axis motion drives its axis only
AXES_OF_MOTION = {"x": ("x",), "y": ("y",)}
TWO_AXES = ("x", "y")


def one_bin(segment: np.ndarray, freq_hz: float, fs: float,
            basis: tuple[np.ndarray, np.ndarray] | None = None) -> complex:
    """The complex amplitude of ``segment`` at ``freq_hz`` (2/N times the Fourier sum, the
    segment's mean removed so an offset that is not whole cycles long does not leak in).
    ``basis``: `cos_sin` of the segment's length, when several segments share it."""
    n = segment.shape[-1]
    cos, sin = basis if basis is not None else cos_sin(n, freq_hz, fs)
    centred = segment - segment.mean()
    return complex(2.0 / n * float(centred @ cos), -2.0 / n * float(centred @ sin))


def cos_sin(n: int, freq_hz: float, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of the drive's phase over ``n`` samples (two real dot products are a
    quarter of the cost of a complex exponential and a mixed-type dot)."""
    phase = 2 * np.pi * freq_hz / fs * np.arange(n)
    return np.cos(phase), np.sin(phase)


def segments_of(n_samples: int, freq_hz: float, fs: float,
                max_samples: int = MAX_SEGMENT_SAMPLES) -> list[tuple[int, int]]:
    """Up to `MAX_SEGMENTS` spans (start, stop) of whole cycles each within ``n_samples``: the
    record cut in equal parts, each part's first whole cycles up to ``max_samples``."""
    # a recorded span is whole cycles rounded to a sample: half a sample short is still whole
    cycles = int(math.floor((n_samples + 0.5) * freq_hz / fs))
    if cycles < 1:
        return []
    count = min(MAX_SEGMENTS, cycles)
    per = cycles // count
    used = max(1, min(per, int(max_samples * freq_hz / fs)))  # cycles read of each part
    out = []
    for k in range(count):
        start = round(k * per * fs / freq_hz)
        stop = round((k * per + used) * fs / freq_hz)
        out.append((start, min(stop, n_samples)))
    return out


class Transfer(TypedDict):
    """One step's transfer at its drive frequency: |X/F| [um/kN] and its phase [deg], the
    dynamic stiffness F/X [MN/m], the coherence (None for one segment), the segments used."""

    h_um_per_kn: float
    phase_deg: float
    k_re_mn_per_m: float
    k_im_mn_per_m: float
    coherence: float | None
    segments: int


def transfer(force: np.ndarray, disp: np.ndarray, freq_hz: float, fs: float
             ) -> Transfer | None:
    """The receptance X/F, the dynamic stiffness F/X and the coherence of one step's record.

    Parameters
    ----------
    force, disp : ndarray, shape (n,)
        The step's recorded force [N] and displacement [m], the same samples.
    freq_hz, fs : float
        The step's drive frequency and the sample rate [Hz].

    Returns
    -------
    dict or None
        ``h_um_per_kn`` (|X/F|), ``phase_deg`` (of X/F), ``k_re_mn_per_m``, ``k_im_mn_per_m``
        (K = F/X), ``coherence`` (None for one segment) and ``segments``; None when the record
        holds no whole cycle or no force at the frequency.
    """
    if not (freq_hz > 0 and fs > 0) or force.shape != disp.shape:
        return None
    spans = segments_of(force.shape[-1], freq_hz, fs)
    return from_segments(((force[a:b], disp[a:b]) for a, b in spans), freq_hz, fs)


def from_segments(segments: Iterable[tuple[np.ndarray, np.ndarray]], freq_hz: float,
                  fs: float) -> Transfer | None:
    """`transfer` over (force, displacement) segments given one at a time (a long record is
    read segment by segment, never whole)."""
    bases: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # by length: segments share one
    pairs = []
    for f, x in segments:
        n = f.shape[-1]
        if n not in bases:
            bases.clear()  # lengths differ by a sample at most: keep one
            bases[n] = cos_sin(n, freq_hz, fs)
        pairs.append((one_bin(f, freq_hz, fs, bases[n]), one_bin(x, freq_hz, fs, bases[n])))
    if not pairs:
        return None
    fk = np.array([p[0] for p in pairs])
    xk = np.array([p[1] for p in pairs])
    sff = float(np.sum(np.abs(fk) ** 2))
    sxx = float(np.sum(np.abs(xk) ** 2))
    sxf = complex(np.sum(xk * np.conj(fk)))
    if sff <= 0.0 or sxf == 0:
        return None
    h = sxf / sff  # m/N
    k = 1.0 / h  # N/m
    coherence = abs(sxf) ** 2 / (sxx * sff) if len(pairs) > 1 else None
    return {
        "h_um_per_kn": abs(h) * 1e9,
        "phase_deg": math.degrees(float(np.angle(h))),
        "k_re_mn_per_m": k.real / 1e6,
        "k_im_mn_per_m": k.imag / 1e6,
        "coherence": coherence,
        "segments": len(pairs),
    }


def axes_of(motion: str) -> tuple[str, ...]:
    """The axes whose direct X/F a step of ``motion`` shows (two-axis orbits: both, with the
    cross-coupled terms inside each, as the step table's F/X)."""
    return AXES_OF_MOTION.get(motion, TWO_AXES)
