"""Whether the held-out data tell two models apart: the paired difference of their squared
errors against its own noise.

Two models' held-out residuals on the same samples, ``r_w`` (the worse, supposedly) and
``r_b``, differ by the difference of their predictions ``d = r_w - r_b``:
``|r_w|^2 - |r_b|^2 = |d|^2 + 2 r_b . d``. The noise cancels from the squares and enters only
through ``2 r_b . d``; the data prefer ``b`` when the difference stands ``Z_DISTINCT`` of its
standard deviations above zero.

That deviation is the data's own, per held-out segment: the segment is cut into blocks (of
whole periods on a dwell, where a model's error is the same in each block) and the difference
of the squared errors scatters from block to block by the noise only; the segment's variance is
that scatter times the number of blocks it holds (each period a block: a 1 s dwell at 20 Hz
gives 19 degrees of freedom). Outside dwells the blocks also differ by the
signal, which only makes the deviation larger (the safe side). The replay's resolution
(``residual_structure.RESOLUTION`` of the response: no replay claims finer, even of noise-free
data) adds ``2 RESOLUTION |prediction| |d|`` in quadrature: a model error of that size, aligned
with ``d``, moves the difference by as much. The differences of the segments add, and so do
their variances.

``Z_DISTINCT`` is the structure tests' ``Z_STRUCTURE`` (5): a preference that stands 5 sd
above the noise is taken as the data's; one that does not leaves the two causes alike. A segment
on which ``b`` is itself ``Z_DISTINCT`` sd worse (``contrary``) means neither describes every
dwell: the two are not told apart either.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.model import Residuals
from analysis.diagnose.residual_structure import MAX_BLOCKS, RESOLUTION, Z_STRUCTURE

#: standard deviations of its own noise by which one model's held-out squared error must
#: exceed another's for the data to tell them apart
Z_DISTINCT = Z_STRUCTURE


@dataclass(frozen=True)
class Difference:
    """Held-out squared error of the worse model minus the better's (weighted, as
    ``Residuals.sse``), its standard deviation from the noise, and the segments on which the
    better is itself ``Z_DISTINCT`` sd worse."""

    excess: float
    sd: float
    contrary: list[str] = field(default_factory=list)

    @property
    def z(self) -> float:
        """The difference in standard deviations (0 for identical models, NaN: not known)."""
        if not math.isfinite(self.excess):
            return math.inf if self.excess == math.inf else math.nan
        if self.sd > 0:
            return self.excess / self.sd
        return 0.0 if self.excess == 0 else math.copysign(math.inf, self.excess)

    @property
    def distinct(self) -> bool:
        """The data prefer the better model beyond their noise, on the whole and nowhere
        against it."""
        return bool(self.z >= Z_DISTINCT and not self.contrary)

    def to_dict(self) -> dict[str, object]:
        return {"excess_sd": self.z, "contrary_segments": self.contrary}


def held_out_difference(records: list[RunRecord], worse: Residuals, better: Residuals,
                        segs: list[Segment]) -> Difference:
    """`Difference` of ``worse`` and ``better`` over the held-out segments ``segs``."""
    total = var = 0.0
    contrary: list[str] = []
    for seg in segs:
        excess, v = _segment(records[seg.run].sample_rate_hz, seg, worse, better)
        if not math.isfinite(excess) or not math.isfinite(v):
            # a diverged replay: worse without measure when it is the worse model's
            return Difference(math.inf if excess == math.inf else math.nan, 0.0, contrary)
        total += excess
        var += v
        if excess < 0 and excess**2 >= Z_DISTINCT**2 * v:
            contrary.append(seg.label)
    return Difference(total, math.sqrt(var), contrary)


def _segment(fs: float, seg: Segment, worse: Residuals, better: Residuals) -> tuple[float, float]:
    """One segment's difference of squared errors and its variance (module doc)."""
    rw, rb, pb = worse.per_segment[seg], better.per_segment[seg], better.predicted[seg]
    weights = better.weights
    n = seg.n
    per_sample = np.zeros(n)
    d2 = p2 = 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        for ch, b in rb.items():
            w2 = weights.get(ch, 1.0) ** 2
            d = rw[ch] - b
            per_sample += w2 * (rw[ch] ** 2 - b**2)
            d2 += w2 * float(np.dot(d, d))
            p2 += w2 * float(np.dot(pb[ch], pb[ch]))
    excess = float(np.sum(per_sample))
    if not math.isfinite(excess):
        return excess, 0.0
    if n < 4:
        return excess, excess**2  # too short to scatter: its difference is its own doubt
    starts, length = _blocks(fs, seg)
    sums = np.array([per_sample[a:a + length].sum() for a in starts])
    scatter = float(np.var(sums, ddof=1)) * n / length
    return excess, scatter + 4.0 * RESOLUTION**2 * p2 * d2


def _blocks(fs: float, seg: Segment) -> tuple[list[int], int]:
    """Starts and length of the blocks a segment is cut into: each period on a dwell of at
    least two (the most degrees of freedom for the scatter: a dwell of 20 periods gives 19),
    else ``MAX_BLOCKS`` equal pieces."""
    n = seg.n
    if seg.freq_hz and seg.freq_hz > 0:
        per = fs / seg.freq_hz
        periods = int(n / per)
        if periods >= 2:
            return [int(round(b * per)) for b in range(periods)], int(round(per))
    blocks = max(2, min(MAX_BLOCKS, n // 2))
    length = n // blocks
    return [b * length for b in range(blocks)], length
