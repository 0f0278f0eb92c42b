"""How well the data determine a finding's size: a standard deviation for each fitted parameter.

At the final model, the Jacobian ``J`` of the fit's own objective (the training residual,
decimated and scaled as the fit sees it) over every free parameter together (the baseline's
and all findings'), so that a parameter's deviation includes what its correlation with the
others leaves undetermined. ``C = (J'J)^-1`` is the Gauss-Newton covariance per unit of
residual variance; the residual's own noise sets the scale, in three ways, the largest kept:

- *per sample*: ``s^2 C``, ``s^2`` the residual's mean square (noise and any misfit, taken as
  independent from sample to sample);
- *per segment* (the sandwich over training segments, ``C (sum_s J_s' r_s r_s' J_s) C``): a
  misfit that pulls the parameter one way on some dwells and the other way on others, and noise
  correlated within a segment, count as the doubt they are. It is an estimate from the few
  segments there are, so it only ever raises the per-sample one;
- *per frequency* (``coloured_spread``): the sandwich over frequency, ``C J'SJ C`` with ``S``
  the residual's own periodogram about each frequency, per segment and channel: the residual
  is the model's response to the load cell's noise, a low-pass, stronger under the dwells'
  1X, where a size's columns lie, than its mean square says (the harmonic-balance
  generator's threshold friction at seed 5101: +19 % off with a per-sample sd of 3.8 %,
  6.5 % per frequency; checked on AR(1) noise in ``tests/analysis/test_diagnose_precision``,
  where it gives the scatter to 5 % and the per-sample one 2.4x under it).

A finding's size is *determined* when its main parameter's doubt, the deviation and how far
it moved when the later findings were refitted jointly with it (added in quadrature: a size
that moves with the other findings is not pinned down by the data apart from them), is within
its effect's documented tolerance (``Effect.tolerance``, e.g. 10 %) of its value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.diagnose.data import Segment
from analysis.diagnose.fitting import apply
from analysis.diagnose.model import Evaluator, Model, Param, residuals

#: relative step of the finite differences, in each parameter's typical scale (as the fits')
_STEP = 1e-3
#: bins either side over which the residual's periodogram is averaged for its level in
#: ``coloured_spread`` (7 bins: a level to about 40 % per segment and channel, averaged
#: again over the bins and segments the parameter's columns span; not sized on data)
SPECTRUM_BINS = 3


@dataclass(frozen=True)
class Precision:
    """Each parameter's standard deviation [its own units] at a model, and its two estimates,
    in the order of the parameters asked about."""

    sd: list[float]
    per_sample: list[float]
    per_segment: list[float]
    per_spectrum: list[float]


def parameter_sd(ev: Evaluator, model: Model, params: list[Param], train: list[Segment],
                 scale_m: float, step: int) -> Precision:
    """Standard deviations of ``params`` at ``model`` from the training residual (module doc).

    A parameter the data do not determine at all (a column of ``J`` that the others explain)
    gets an infinite deviation.
    """
    if not params:
        return Precision([], [], [], [])
    base = residuals(ev, model, train)
    segs = list(base.per_segment)
    r0 = [_seg_vector(base, s, step) / scale_m for s in segs]
    cols: list[list[np.ndarray]] = []
    for p in params:
        x = p.get(model)
        d = _STEP if x + _STEP * p.scale <= p.hi else -_STEP
        moved = residuals(ev, apply(model, [p], np.array([x + d * p.scale])), train)
        cols.append([(_seg_vector(moved, s, step) / scale_m - r) / d
                     for s, r in zip(segs, r0, strict=True)])
    jac_s = [np.column_stack([c[i] for c in cols]) for i in range(len(segs))]
    scales = np.array([p.scale for p in params])
    sample, segment = spread(jac_s, r0)
    lengths = [[v[::step].size for v in base.per_segment[s].values()] for s in segs]
    spectrum = coloured_spread(jac_s, r0, lengths)
    per_sample = [_finite(v) for v in sample * scales]
    per_segment = [_finite(v) for v in segment * scales]
    per_spectrum = [_finite(v) for v in spectrum * scales]
    return Precision([max(a, b, c) for a, b, c in zip(per_sample, per_segment, per_spectrum,
                                                      strict=True)],
                     per_sample, per_segment, per_spectrum)


def spread(jac: list[np.ndarray], r: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviations of the least-squares parameters of residuals ``r`` (one vector per
    segment) with Jacobians ``jac`` (one n_s x k matrix per segment): per sample and per
    segment (module doc); infinite for a parameter the Jacobian does not determine."""
    k = jac[0].shape[1]
    if not all(np.all(np.isfinite(j)) for j in jac) or not all(np.all(np.isfinite(v))
                                                               for v in r):
        # a diverging replay next to the model: nothing is known of the parameters' spread
        return np.full(k, np.inf), np.full(k, np.inf)
    full = np.vstack(jac)
    res = np.concatenate(r)
    cov, undetermined = _inverse(full.T @ full)
    s2 = float(np.dot(res, res)) / max(res.size - k, 1)
    grads = np.array([j.T @ v for j, v in zip(jac, r, strict=True)])
    # the sandwich's small-sample correction: n / (n - 1) segments
    meat = grads.T @ grads * len(jac) / max(len(jac) - 1, 1)
    sample = np.sqrt(np.maximum(np.diag(cov) * s2, 0.0))
    segment = np.sqrt(np.maximum(np.diag(cov @ meat @ cov), 0.0))
    sample[undetermined] = segment[undetermined] = np.inf
    return sample, segment


def coloured_spread(jac: list[np.ndarray], r: list[np.ndarray],
                    lengths: list[list[int]]) -> np.ndarray:
    """Standard deviations of the least-squares parameters where the residual's noise is
    coloured: ``C J' S J C`` with ``J' S J`` summed over frequency, per segment and channel
    (``lengths``: each channel's share of the segment's vector, in order), ``S`` the
    residual's own periodogram there averaged over ``SPECTRUM_BINS`` bins either side. On
    white noise it is the per-sample deviation (Parseval); where the noise is stronger at the
    frequencies the parameter moves the record at (the model's response to the load cell's
    noise, a low-pass peaking at the mode, under the dwells' 1X), larger."""
    k = jac[0].shape[1]
    if not all(np.all(np.isfinite(j)) for j in jac) or not all(np.all(np.isfinite(v))
                                                               for v in r):
        return np.full(k, np.inf)
    full = np.vstack(jac)
    cov, undetermined = _inverse(full.T @ full)
    meat = np.zeros((k, k))
    for j_s, r_s, lens in zip(jac, r, lengths, strict=True):
        at = 0
        for n in lens:
            if n < 2 * SPECTRUM_BINS + 2:
                # too short for a spectrum: white, at its own mean square
                jj, rr = j_s[at:at + n], r_s[at:at + n]
                meat += jj.T @ jj * float(np.mean(rr * rr)) if n else 0.0
                at += n
                continue
            fj = np.fft.rfft(j_s[at:at + n], axis=0)
            pr = np.abs(np.fft.rfft(r_s[at:at + n])) ** 2 / n
            kernel = np.ones(2 * SPECTRUM_BINS + 1)
            level = (np.convolve(np.pad(pr, SPECTRUM_BINS, mode="reflect"), kernel, "valid")
                     / kernel.size)
            # each bin but DC (and Nyquist for an even n) stands for its negative frequency too
            both = np.full(level.size, 2.0)
            both[0] = 1.0
            if n % 2 == 0:
                both[-1] = 1.0
            meat += np.real(fj.conj().T @ (fj * (both * level)[:, None])) / n
            at += n
    spec = np.sqrt(np.maximum(np.diag(cov @ meat @ cov), 0.0))
    spec[undetermined] = np.inf
    return spec


def doubt(sd: float, shift: float) -> float:
    """A size's doubt: its deviation and its move on the joint refit, in quadrature."""
    return math.hypot(sd, shift)


def determined(value: float, sd: float, shift: float, tolerance: float) -> bool:
    """Whether a size ``value`` is pinned down by the data to within ``tolerance`` of itself."""
    return bool(math.isfinite(sd) and doubt(sd, shift) <= tolerance * abs(value))


def _seg_vector(res, seg: Segment, step: int) -> np.ndarray:
    w = res.weights
    return np.concatenate([w.get(ch, 1.0) * v[::step] for ch, v in res.per_segment[seg].items()])


def _inverse(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a``'s inverse on the directions it determines, and which parameters lie (in part)
    along a direction it does not (their variance is infinite)."""
    w, v = np.linalg.eigh(a)
    tiny = w <= 1e-12 * max(float(w[-1]), 1e-300)
    inv = (v[:, ~tiny] / w[~tiny]) @ v[:, ~tiny].T
    free = np.any(np.abs(v[:, tiny]) > 1e-6, axis=1) if np.any(tiny) else np.zeros(len(w), bool)
    return inv, free


def _finite(v: float) -> float:
    return float(v) if math.isfinite(float(v)) else math.inf
