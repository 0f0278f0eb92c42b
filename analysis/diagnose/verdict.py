"""Verdicts against the signal: how much of the measured response a model explains.

A model is judged on held-out segments against the signal itself, not against another model:

- signal: the measured response of each channel with the channel's offset removed;
- noise floor: what no model of the excitation can predict, per channel over every held-out
  segment, whether it moves the channel's axis or not (per dwell, what the harmonics 1X..5X
  leave; for other data the white-noise level of second differences,
  ``residual_analysis.channel_noise``);
- explained fraction: ``1 - max(residual_ms - noise_ms, 0) / (signal_ms - noise_ms)`` (mean
  squares over the held-out samples; 1: everything above the noise floor is explained, 0: no
  better than predicting nothing; negative: worse than nothing).

What the final model leaves is "unexplained" when it exceeds ``UNEXPLAINED_SHARE`` of the signal
above the noise floor or ``NOISE_MARGIN`` times the noise floor (RMS), where that is known.

When the baseline explains less than ``ADEQUATE`` (0.90), and no single term of the library
brings it there, the verdict is "baseline inadequate": the baseline does not describe the data,
so no term added on top of it can be named with confidence; the verdict says what is missing:
the residual's spectral peaks, the channels explained worst (and, from the engine, a mode that
a second-mode term found).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import find_peaks, welch

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.model import Residuals
from analysis.diagnose.residual_structure import Z_STRUCTURE, excess_chi2

#: explained fraction below which the model family is inadequate
ADEQUATE = 0.90
#: share of the above-noise signal a model may leave before the rest counts as unexplained
UNEXPLAINED_SHARE = 0.02
#: share of the signal a term must explain to be a cause once the rest is explained
REFINEMENT_SHARE = 0.005
#: share of what the model before it left (above the noise) that a term must explain to be the
#: cause of that remainder, however small a share of the signal it is (held-out gain 2), where
#: no dwell gives the noise (blocks, the inverse model's force); on dwells the term's signature
#: against the dwells' own noise decides instead (`refinement_share`). Measured causes remove
#: 89-99.97 % of the remainder (independent generators, seed 1).
REMAINDER_SHARE = 0.75
#: residual RMS, in noise-floor RMS, beyond which what a model leaves is a discrepancy however
#: small a share of the signal it is (1.5x is a systematic remainder of sqrt(1.5^2 - 1) = 1.1
#: noise RMS, larger than the noise itself). Not from the noise's statistics, and measured why
#: (independent generators, seed 1): a model that describes the data leaves 1.016-1.042x the
#: noise floor (time-domain generator: clean 1.041, after a cubic, delay or gain finding
#: 1.039-1.042; harmonic-balance generator after its cubic or gain finding 1.016-1.017), while
#: the RMS's own scatter over the held-out samples is well under 1 %: the excess is the
#: replay's resolution, so 1 + 5 sd of that scatter would call clean records unexplained. A
#: smaller remainder with structure is caught at 5 sd of the dwells' own noise
#: (`residual_structure`; the harmonic-balance cubic left 1.14x, at 30 sd): this margin is the
#: backstop for a remainder without structure (blocks, or noise-like).
NOISE_MARGIN = 1.5
#: structure (excess chi-square over the noise) the findings may leave, as a share of the
#: baseline's, and still be named with confidence: they explain at least nine tenths of what
#: the baseline left beyond the noise, so they are its main cause; the rest is named as
#: structure (the verdict stays "unexplained"). A larger remainder may be another cause that
#: the findings partly stand in for: every finding is then low confidence.
STRUCTURE_LEFT = 0.1


@dataclass
class SignalFit:
    """Held-out explained fraction of one model, overall and per channel."""

    explained: float
    signal_rms: float
    residual_rms: float
    noise_rms: float
    per_channel: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"explained_fraction": self.explained, "signal_rms": self.signal_rms,
                "residual_rms": self.residual_rms, "noise_rms": self.noise_rms,
                "explained_fraction_per_channel": self.per_channel}


def _fraction(sig_ms: float, res_ms: float, noise_ms: float) -> float:
    above = sig_ms - noise_ms
    if above <= 0.0:
        return math.nan  # nothing above the noise floor to explain
    return 1.0 - max(res_ms - noise_ms, 0.0) / above


def signal_fit(records: list[RunRecord], res: Residuals, segs: list[Segment],
               noise_ms_of: dict[str, float] | None = None) -> SignalFit:
    """Explained fraction of ``res`` on ``segs``; ``noise_ms_of``: noise mean square per channel.

    Per channel in its own units; overall, the channels weighted as in the fit
    (``res.weights``), so the totals are displacement-equivalent [m]. The channel's offset
    (``res.offsets``, fitted on training data) is taken off the signal, so a probe's gap is not
    counted as signal.
    """
    noise_ms_of = noise_ms_of or {}
    w = res.weights
    sig: dict[str, list[float]] = {}
    resid: dict[str, list[float]] = {}
    count: dict[str, int] = {}
    for seg in segs:
        rec = records[seg.run]
        for ch, r in res.per_segment[seg].items():
            m = rec.signal(ch)[seg.start:seg.stop] - res.offsets.get((seg.run, ch), 0.0)
            with np.errstate(over="ignore", invalid="ignore"):
                rr = float(np.dot(r, r))
            sig.setdefault(ch, []).append(float(np.dot(m, m)))
            resid.setdefault(ch, []).append(rr if math.isfinite(rr) else math.inf)
            count[ch] = count.get(ch, 0) + r.size
    per: dict[str, float] = {}
    tot_s = tot_r = tot_n = 0.0
    n_all = 0
    for ch in sig:
        n = count[ch]
        s_ms, r_ms = sum(sig[ch]) / n, sum(resid[ch]) / n
        n_ms = noise_ms_of.get(ch, 0.0)
        per[ch] = _fraction(s_ms, r_ms, n_ms)
        w2 = w.get(ch, 1.0) ** 2  # channels of other quantities in displacement-equivalent
        tot_s += w2 * s_ms * n
        tot_r += w2 * r_ms * n
        tot_n += w2 * n_ms * n
        n_all += n
    if n_all == 0:
        return SignalFit(math.nan, math.nan, math.nan, math.nan)
    return SignalFit(_fraction(tot_s / n_all, tot_r / n_all, tot_n / n_all),
                     math.sqrt(tot_s / n_all), math.sqrt(tot_r / n_all),
                     math.sqrt(tot_n / n_all), per)


def excited_band(records: list[RunRecord], segs: list[Segment],
                 share: float = 0.999) -> tuple[float, float]:
    """Frequency band [Hz] holding ``share`` of the force's power on ``segs`` (dwells: their
    frequencies)."""
    freqs = [s.freq_hz for s in segs if s.freq_hz]
    if freqs:
        return float(min(freqs)), float(max(freqs))
    psd_sum: np.ndarray | None = None
    f_axis = None
    for seg in segs:
        rec = records[seg.run]
        n = min(seg.n, 1024)
        if n < 16:
            continue
        for axis in (0, 1):
            f_seg = rec.force_n[axis, seg.start:seg.stop]
            if not np.any(f_seg):
                continue
            fa, p = welch(f_seg - f_seg.mean(), rec.sample_rate_hz, nperseg=n, nfft=1024)
            if psd_sum is None:
                psd_sum, f_axis = p, fa
            else:
                psd_sum = psd_sum + p
    if psd_sum is None or f_axis is None:
        return 0.0, math.inf
    c = np.cumsum(psd_sum) / np.sum(psd_sum)
    lo = float(f_axis[int(np.searchsorted(c, (1 - share) / 2))])
    hi = float(f_axis[min(int(np.searchsorted(c, 1 - (1 - share) / 2)), f_axis.size - 1)])
    return lo, hi


def residual_peaks(records: list[RunRecord], res: Residuals, segs: list[Segment],
                   n_peaks: int = 3) -> list[dict[str, float]]:
    """The largest peaks of the residual's spectrum (Welch, averaged over segments and
    channels): frequency [Hz] and share of the residual power within +/-2 bins."""
    acc: np.ndarray | None = None
    f_axis = None
    fs0 = records[segs[0].run].sample_rate_hz if segs else 0.0
    nper = min([s.n for s in segs] + [4096])
    if nper < 32:
        return []
    for seg in segs:
        if records[seg.run].sample_rate_hz != fs0:
            continue
        for r in res.per_segment[seg].values():
            if not np.all(np.isfinite(r)):
                continue
            fa, p = welch(r - r.mean(), fs0, nperseg=nper)
            acc = p if acc is None else acc + p
            f_axis = fa
    if acc is None or f_axis is None or not np.any(acc > 0):
        return []
    total = float(np.sum(acc))
    idx, _ = find_peaks(acc, prominence=0.02 * float(np.max(acc)))
    if idx.size == 0:
        idx = np.array([int(np.argmax(acc))])
    top = idx[np.argsort(acc[idx])[::-1][:n_peaks]]
    return [{"freq_hz": float(f_axis[i]),
             "share_of_residual_power": float(np.sum(acc[max(0, i - 2):i + 3]) / total)}
            for i in top]


@dataclass
class Verdict:
    """The verdict on the held-out data: baseline and final model against the signal."""

    baseline: SignalFit
    final: SignalFit
    adequate: bool
    unexplained: bool
    missing: dict[str, Any]
    threshold: float = ADEQUATE
    #: the tests of the final model's residual for structure above its noise
    #: (``residual_structure.find_structure``), largest first
    structure_tests: list[dict[str, Any]] = field(default_factory=list)

    #: the final model's residual leaves too much of the signal (share or noise margin)
    signal_unexplained: bool = False
    #: the structure the final model leaves over the baseline's (excess chi-square over the
    #: noise, ``residual_structure.excess_chi2``); NaN where the baseline had none
    structure_left_share: float = math.nan
    #: the whole record's tests (``whole_record.account``: harmonics to 10X, lines between
    #: them, the 1X against the noise and the replay's own error), largest first
    record_tests: list[dict[str, Any]] = field(default_factory=list)
    #: the 1X pattern the whole record shows beyond the noise (``fundamental_at_noise``'s
    #: excess chi-square) that the findings leave of the baseline's; 0 where none is left
    record_1x_left_share: float = 0.0

    @property
    def record(self) -> list[dict[str, Any]]:
        """The whole record's tests that found something the model does not account for
        (each makes the verdict at least "unexplained")."""
        return [t for t in self.record_tests if t["structure"]]

    @property
    def structure_mostly_explained(self) -> bool:
        """The findings explain nearly all the structure of the baseline's residual: what they
        leave (named as structure all the same) is at most ``STRUCTURE_LEFT`` of it."""
        return bool(self.structure_left_share <= STRUCTURE_LEFT)

    @property
    def structure(self) -> list[dict[str, Any]]:
        """The tests that found structure above the noise (each makes the verdict at least
        "unexplained")."""
        return [t for t in self.structure_tests if t["structure"]]

    @property
    def text(self) -> str:
        if not self.adequate:
            return "baseline inadequate"  # whatever the extended model reaches
        return "unexplained discrepancy" if self.unexplained else "explained"

    def to_dict(self) -> dict[str, Any]:
        return {"verdict": self.text, "threshold": self.threshold,
                "baseline": self.baseline.to_dict(), "final": self.final.to_dict(),
                "unexplained_share": UNEXPLAINED_SHARE, "noise_margin": NOISE_MARGIN,
                "missing": self.missing, "structure": self.structure,
                "structure_tests": self.structure_tests,
                "structure_threshold_sd": Z_STRUCTURE,
                "record": self.record, "record_tests": self.record_tests,
                "record_1x_left_share": self.record_1x_left_share,
                "structure_left_share": self.structure_left_share}


def refinement_share(before: SignalFit, after: SignalFit,
                     signature_sd: float | None = None) -> tuple[bool, float]:
    """Whether a term is a refinement, and the share of the signal it explains.

    A term added once the model before it left nothing unexplained (under
    ``UNEXPLAINED_SHARE`` of the signal above the noise floor and, where the floor is known,
    within ``NOISE_MARGIN`` of it), that explains less than ``REFINEMENT_SHARE`` of the signal
    and less than ``REMAINDER_SHARE`` of what was left, refines the model: the data support it,
    but it names no cause (a flexible term that fits part of what a good model leaves, a few
    thousandths of a percent of the signal, describes the residual, not its origin). A term that
    removes most of the remainder is its cause, however small a share of the signal that
    remainder is (a weak nonlinearity beside a linear model that explains 99.5 % of the signal:
    under 0.5 % of the signal, nearly all of what the linear model leaves).

    Where dwells give the noise, ``signature_sd`` (`residual_structure.signature_sd`: what the
    term removes of the residual's structure, in the dwells' own noise sd) decides whether the
    remainder it removes is minor: under ``Z_STRUCTURE`` sd it is; at or above, the term is its
    cause, whatever share of the remainder that is (a remainder is itself measured against the
    noise, so a share of it is no measure of how sure the data are). Without (None),
    ``REMAINDER_SHARE``.
    """
    share = after.explained - before.explained
    beyond_noise = before.noise_rms > 0 and before.residual_rms > NOISE_MARGIN * before.noise_rms
    explained = before.explained >= 1.0 - UNEXPLAINED_SHARE and not beyond_noise
    left_before = max(before.residual_rms**2 - before.noise_rms**2, 0.0)
    left_after = max(after.residual_rms**2 - after.noise_rms**2, 0.0)
    minor = (signature_sd < Z_STRUCTURE if signature_sd is not None
             else left_after > (1.0 - REMAINDER_SHARE) * left_before)
    return bool(explained and share < REFINEMENT_SHARE and minor), float(share)


def judge(records: list[RunRecord], base: Residuals, final: Residuals, segs: list[Segment],
          noise_ms_of: dict[str, float], first: Residuals | None = None,
          structure_tests: list[dict[str, Any]] | None = None,
          baseline_excess: float | None = None,
          record_tests: list[dict[str, Any]] | None = None) -> Verdict:
    """Judge the baseline and the final model against the held-out signal.

    The baseline is adequate when it explains at least ``ADEQUATE`` of the signal above the
    noise floor, or when one term of the library (the first finding, ``first``: the model's
    held-out residuals with it) brings it there: a large effect may hide a sound baseline, but a
    baseline that needs several terms to look adequate does not describe the data, and a term
    added to it is no cause, however much it helps (a broken baseline makes any extra term look
    like an explanation). What the final model leaves is unexplained when it is more than
    ``UNEXPLAINED_SHARE`` of that signal, or, where the noise floor is known (dwells), when its
    RMS exceeds ``NOISE_MARGIN`` times the noise floor's: a slow drift of the structure may leave
    0.1 % of a strong signal and still six times the noise. Structure in the final model's
    residual above its own noise (``structure_tests``, ``residual_structure``: the dynamic
    stiffness's error varying with amplitude, time, frequency or temperature, a repeated dwell
    that changed, harmonics or the other axis's response) is unexplained however small a
    share of the signal it is; so is anything the whole record holds that the model does not
    account for (``record_tests``, ``whole_record``: a harmonic up to 10X, a line at another
    frequency, the 1X beyond the noise and the replay's own error).
    """
    fb = signal_fit(records, base, segs, noise_ms_of)
    ff = signal_fit(records, final, segs, noise_ms_of)
    base_x = fb.explained if math.isfinite(fb.explained) else 1.0
    final_x = ff.explained if math.isfinite(ff.explained) else 1.0
    adequate = base_x >= ADEQUATE
    if not adequate and first is not None:
        one = signal_fit(records, first, segs, noise_ms_of).explained
        adequate = math.isfinite(one) and one >= ADEQUATE
    beyond_noise = bool(ff.noise_rms > 0 and ff.residual_rms > NOISE_MARGIN * ff.noise_rms)
    tests = list(structure_tests or [])
    structured = any(t["structure"] for t in tests + list(record_tests or []))
    signal_left = final_x < 1.0 - UNEXPLAINED_SHARE or beyond_noise
    unexplained = signal_left or structured
    left = math.nan
    if baseline_excess is not None and baseline_excess > 0:
        left = excess_chi2(tests) / baseline_excess
    missing: dict[str, Any] = {}
    for name, fit_, res, show in (("baseline", fb, base, not adequate),
                                  ("final", ff, final, unexplained)):
        if show:
            missing[name] = {
                "residual_peaks": residual_peaks(records, res, segs),
                "channels_worst_first": sorted(
                    ({"channel": ch, "explained_fraction": v}
                     for ch, v in fit_.per_channel.items()),
                    key=lambda d: d["explained_fraction"]
                    if math.isfinite(d["explained_fraction"]) else 2.0),
            }
    return Verdict(fb, ff, adequate, unexplained, missing, structure_tests=tests,
                   signal_unexplained=signal_left, structure_left_share=left,
                   record_tests=list(record_tests or []))
