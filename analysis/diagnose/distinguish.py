"""Whether the held-out data tell two models apart: the excess of one's squared error over the
other's, against the noise floor and the replay's resolution.

Two models' held-out residuals on the same samples, ``r_b`` (the better, supposedly) and
``r_w``, differ by the difference of their predictions ``d = r_w - r_b``. With ``r_b = n + m_b``
(noise and the better model's own misfit),
``E = |r_w|^2 - |r_b|^2 = |m_w|^2 - |m_b|^2 + 2 n . d``: its expectation is how much more the
worse model misses, and only ``2 n . d`` is random, with standard deviation
``2 sqrt(sum sigma^2 d^2)``, ``sigma`` each channel's noise floor on each segment (what the
harmonics 1X-5X leave of the measured signal on a dwell, ``residual_analysis.channel_noise``;
elsewhere the better model's own residual, an upper bound). The floor is the data's, not the
scatter of ``E`` from period to period: that scatter also holds whatever in ``d`` or ``m_b``
is not periodic (a dwell's settling, a drift within it), which is no noise.

The replay's resolution (``residual_structure.RESOLUTION`` of the prediction ``p``: no replay
claims finer) is a bias, not noise: a replay error of that size, aligned with ``d``, could
move ``E`` by ``2 RESOLUTION |p| |d|`` at most, once. It is taken off ``E`` before ``E`` is
compared with its noise. (Added to the noise in quadrature and then multiplied by
``Z_DISTINCT``, it asked the models to differ by 10x the resolution: on low-noise records it
dominated the noise 5-9x and left runners-up 1.2-3.4x worse in mean square "alike".)

The data tell the two apart when ``(E - 2 RESOLUTION |p| |d|) / sd`` reaches ``Z_DISTINCT`` =
``Z_STRUCTURE`` (5): a preference that stands 5 sd above the noise is the data's. That a
model misses some dwells (structure left in its residual) is the structure tests' verdict, not
this one's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.diagnose import residual_analysis as ra
from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.model import Residuals
from analysis.diagnose.residual_structure import (
    RESOLUTION,
    Z_STRUCTURE,
    within_frequency_deviations,
)

#: standard deviations of its noise by which one model's held-out squared error must exceed
#: another's (the replay's resolution taken off) for the data to tell them apart
Z_DISTINCT = Z_STRUCTURE


@dataclass(frozen=True)
class Difference:
    """The worse model's held-out squared error minus the better's (weighted, as
    ``Residuals.sse``), the replay's resolution bias on it and its noise sd; and the same
    excess among dwells of one frequency in noise sd (``within``, `within_frequency_z`)."""

    excess: float
    bias: float
    sd: float
    within: float = 0.0

    @property
    def z(self) -> float:
        """The excess beyond the resolution in noise sd (NaN: not known; inf: the worse model
        diverged, or noise-free data)."""
        if math.isnan(self.excess):
            return math.nan
        if self.excess == math.inf:
            return math.inf
        margin = self.excess - self.bias
        if self.sd > 0:
            return margin / self.sd
        return math.copysign(math.inf, margin) if margin != 0 else 0.0

    @property
    def distinct(self) -> bool:
        """The data prefer the better model beyond the replay's resolution and the noise, over
        the samples or among dwells of one frequency."""
        return bool(self.z >= Z_DISTINCT or self.within >= Z_DISTINCT)

    def to_dict(self) -> dict[str, float]:
        return {"excess_sd": self.z, "within_frequency_excess_sd": self.within}


def held_out_difference(records: list[RunRecord], worse: Residuals, better: Residuals,
                        segs: list[Segment]) -> Difference:
    """`Difference` of ``worse`` and ``better`` over the held-out segments ``segs``."""
    excess = var = d2 = p2 = 0.0
    weights = better.weights
    for seg in segs:
        noise = ra.channel_noise(records, [seg])
        with np.errstate(over="ignore", invalid="ignore"):
            for ch, rb in better.per_segment[seg].items():
                w2 = weights.get(ch, 1.0) ** 2
                rw = worse.per_segment[seg][ch]
                d = rw - rb
                dd = float(np.dot(d, d))
                excess += w2 * (float(np.dot(rw, rw)) - float(np.dot(rb, rb)))
                sigma2 = noise.get(ch, float(np.dot(rb, rb)) / max(rb.size, 1))
                var += 4.0 * w2 * w2 * sigma2 * dd
                d2 += w2 * dd
                p2 += w2 * float(np.dot(better.predicted[seg][ch], better.predicted[seg][ch]))
    if not math.isfinite(excess):
        # a diverged replay: worse without measure when it is the worse model's
        return Difference(math.inf if excess == math.inf else math.nan, 0.0, 0.0)
    return Difference(excess, 2.0 * RESOLUTION * math.sqrt(p2 * d2), math.sqrt(var),
                      within_frequency_z(records, worse, better, segs))


def within_frequency_z(records: list[RunRecord], worse: Residuals, better: Residuals,
                       segs: list[Segment]) -> float:
    """The excess of ``worse``'s chi-square among dwells of one frequency over ``better``'s,
    in sd of the noise: ``(|u_w|^2 - |u_b|^2) / (2 |u_w - u_b|)`` with ``u`` each model's
    deviations in noise sd (`within_frequency_deviations`, on ``better``'s floor). The replay's
    resolution, a function of the frequency, cancels there, so no bias is taken off: what one
    model follows with amplitude or time and the other does not is told at the noise's own
    level. At most ``|u_w - u_b|``: two models closer than the noise cannot be told apart by
    it (their difference, a share of the measured 1X, may follow the noise itself). 0 without
    dwells sharing a frequency."""
    ub, floor = within_frequency_deviations(records, better, segs)
    uw, _ = within_frequency_deviations(records, worse, segs, floor)
    keys = ub.keys() & uw.keys()
    if not keys:
        return 0.0
    excess = sum(abs(uw[k]) ** 2 - abs(ub[k]) ** 2 for k in keys)
    d = math.sqrt(sum(abs(uw[k] - ub[k]) ** 2 for k in keys))
    if not math.isfinite(excess) or d == 0.0:
        return 0.0
    return float(min(excess / (2.0 * d), d))
