"""What the model gets wrong, in numbers: per dwell, per harmonic, against amplitude/frequency/time.

Per dwell (segments with a frequency), the measured and predicted responses of each channel are
decomposed into their mean and harmonics 1X..5X by least squares on the dwell's samples
(``z(t) = Re(Z e^{i k w t})``, ``Z = z_c - i z_s``, t from sample 0 of the run, as eq. 12-13). The
fundamental's amplitude error (predicted / measured - 1) and phase error (predicted - measured)
and the residual's harmonic amplitudes follow. What the harmonics do not explain in the measured
signal is the noise floor (non-periodic content) of that dwell.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from scipy.signal import welch

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.model import Residuals

N_HARMONICS = 5


def harmonics(sig: np.ndarray, start: int, fs: float, freq_hz: float,
              n_harm: int = N_HARMONICS) -> tuple[np.ndarray, float, float]:
    """Complex amplitudes (n_harm,), mean, and RMS of what the fit leaves (noise) of ``sig``."""
    a, pinv = _design(start, sig.size, fs, freq_hz, n_harm)
    coef = pinv @ sig
    rest = sig - a @ coef
    z = coef[1::2] - 1j * coef[2::2]
    return z, float(coef[0]), float(np.sqrt(np.mean(rest**2)))


@functools.lru_cache(maxsize=48)
def _design(start: int, n: int, fs: float, freq_hz: float,
            n_harm: int) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares design of `harmonics` (mean, then cos and sin of each harmonic at the
    run's time of each sample) and its pseudo-inverse: one dwell is decomposed for every
    channel and every model judged on it."""
    t = (start + np.arange(n)) / fs
    cols = [np.ones_like(t)]
    for k in range(1, n_harm + 1):
        w = 2 * math.pi * k * freq_hz
        cols += [np.cos(w * t), np.sin(w * t)]
    a = np.column_stack(cols)
    pinv = np.linalg.pinv(a)
    a.flags.writeable = False
    pinv.flags.writeable = False
    return a, pinv


def dwell_table(records: list[RunRecord], res: Residuals, segs: list[Segment]) -> list[dict]:
    """One row per dwell and moving channel: frequency, amplitude, time, errors, harmonics, noise.

    Channels whose 1X amplitude is below 10 % of the dwell's largest of the same quantity are
    left out (the axis the dwell does not drive). Amplitudes, harmonics and noise are in the
    channel's own units (``quantity``: m, m/s or m/s^2; the keys say ``_m`` for displacement).
    """
    rows: list[dict[str, Any]] = []
    for seg in segs:
        if seg.freq_hz is None or seg.freq_hz <= 0:
            continue
        rec = records[seg.run]
        fs = rec.sample_rate_hz
        if seg.n < fs / seg.freq_hz:
            continue
        fits = {ch: harmonics(rec.signal(ch)[seg.start:seg.stop], seg.start, fs,
                              seg.freq_hz) for ch in res.per_segment[seg]}
        kinds = rec.objective_channels()
        top: dict[str, float] = {}
        for ch, f in fits.items():
            q = kinds[ch][1]
            top[q] = max(top.get(q, 0.0), abs(f[0][0]))
        for ch, r in res.per_segment[seg].items():
            zm, _, noise = fits[ch]
            quantity = kinds[ch][1]
            if abs(zm[0]) < 0.1 * top[quantity]:
                continue  # an axis the dwell hardly moves: relative errors would be noise
            zr, mean_r, _ = harmonics(r, seg.start, fs, seg.freq_hz)
            zp = zm - zr  # predicted harmonics (residual = measured - predicted)
            amp_m = abs(zm[0])
            rows.append({
                "segment": seg.label, "run": seg.run, "channel": ch, "quantity": quantity,
                "set": "",
                "freq_hz": seg.freq_hz, "motion": seg.motion,
                "time_s": 0.5 * (seg.start + seg.stop) / fs,
                "amplitude_m": amp_m,
                "amplitude_error": abs(zp[0]) / amp_m - 1.0 if amp_m > 0 else math.nan,
                "phase_error_deg": math.degrees(float(np.angle(zp[0] / zm[0])))
                if amp_m > 0 else math.nan,
                "residual_harmonics_m": [abs(z) for z in zr],
                "residual_mean_m": mean_r,
                "residual_rms_m": float(np.sqrt(np.mean(r**2))),
                "noise_rms_m": noise,
            })
    return rows


def segment_table(records: list[RunRecord], res: Residuals, segs: list[Segment]) -> list[dict]:
    """One row per segment: time, measured RMS and residual RMS over its displacement
    channels [m]."""
    rows = []
    for seg in segs:
        rec = records[seg.run]
        chans = {ch: v for ch, v in res.per_segment[seg].items() if ch in rec.responses}
        meas = np.concatenate([rec.responses[ch][seg.start:seg.stop] for ch in chans])
        resid = np.concatenate(list(chans.values()))
        rows.append({
            "segment": seg.label, "run": seg.run,
            "time_s": 0.5 * (seg.start + seg.stop) / rec.sample_rate_hz,
            "freq_hz": seg.freq_hz,
            "measured_rms_m": float(np.sqrt(np.mean((meas - meas.mean()) ** 2))),
            "residual_rms_m": float(np.sqrt(np.mean(resid**2))),
        })
    return rows


def _displacement_rows(rows: list[dict]) -> list[dict]:
    return [r for r in rows if r.get("quantity", "displacement") == "displacement"]


def noise_floor(rows: list[dict]) -> float | None:
    """RMS of the non-periodic part of the measured displacement over dwells [m] (None: no
    dwells)."""
    rows = _displacement_rows(rows)
    if not rows:
        return None
    return float(np.sqrt(np.mean([r["noise_rms_m"] ** 2 for r in rows])))


def channel_noise(records: list[RunRecord], segs: list[Segment],
                  without_dwells: bool = False) -> dict[str, float]:
    """Noise mean square of every objective channel (its own units squared).

    Per dwell, what the harmonics 1X..5X leave of the measured signal, over every dwell, whether
    it moves the channel's axis or not (the noise is there either way). With
    ``without_dwells``, a channel with no dwell gets the white-noise level from second
    differences (``var(diff2) / 6``: an upper bound where the signal has content near the sample
    rate, good enough to weigh sensors against each other, not to judge a model by); without it,
    a block of other data (a sweep) gets the white level of its spectrum above the excitation's
    harmonics where it has such a band (`_quiet_band`), else none.
    """
    acc: dict[str, list[float]] = {}
    rough: dict[str, list[float]] = {}
    white: dict[str, list[float]] = {}
    for seg in segs:
        rec = records[seg.run]
        fs = rec.sample_rate_hz
        periodic = bool(seg.freq_hz and seg.freq_hz > 0 and seg.n >= 2 * fs / seg.freq_hz)
        cut = None if periodic or without_dwells else _quiet_band(rec, seg)
        for ch in rec.objective_channels():
            sig = rec.signal(ch)[seg.start:seg.stop]
            if periodic:
                assert seg.freq_hz is not None
                acc.setdefault(ch, []).append(harmonics(sig, seg.start, fs, seg.freq_hz)[2] ** 2)
            elif without_dwells and sig.size > 8:
                rough.setdefault(ch, []).append(float(np.var(np.diff(sig, 2)) / 6.0))
            elif cut is not None:
                level = _white_level(sig, fs, cut)
                if level is not None:
                    white.setdefault(ch, []).append(level)
    out = {ch: float(np.mean(v)) for ch, v in rough.items()}
    out.update({ch: float(np.mean(v)) for ch, v in white.items()})
    out.update({ch: float(np.mean(v)) for ch, v in acc.items()})
    return out


#: samples per Welch window of the white-noise level of a block
_NPER = 1024


def _quiet_band(rec: RunRecord, seg: Segment) -> tuple[float, float] | None:
    """The band of block ``seg`` with nothing of the excitation in it: above five times the
    force's highest frequency (1.25 x where its spectrum falls below 1e-4 of its peak: the
    harmonics a nonlinear structure makes) up to 0.8 x Nyquist (clear of an anti-alias
    filter's edge); None when that band is narrower than a fifth of Nyquist (broadband force)."""
    if seg.n < 4 * _NPER:
        return None
    fs = rec.sample_rate_hz
    f, p = welch(rec.force_n[:, seg.start:seg.stop], fs, nperseg=_NPER, axis=-1)
    pf = p.sum(axis=0)
    if not np.any(pf > 0):
        return None
    f_hi = float(f[np.nonzero(pf > 1e-4 * pf.max())[0][-1]])
    lo, hi = 5 * 1.25 * f_hi, 0.8 * fs / 2
    return (lo, hi) if hi - lo >= 0.2 * fs / 2 else None


def _white_level(sig: np.ndarray, fs: float, band: tuple[float, float]) -> float | None:
    """Mean square of the white noise in ``sig``: the median PSD over ``band`` times the
    Nyquist frequency (None when it is below 1e-10 of the signal's mean square: noise-free
    data, whose floor is the integrator's round-off and judges nothing)."""
    f, p = welch(sig - np.mean(sig), fs, nperseg=_NPER)
    sel = (f >= band[0]) & (f <= band[1])
    ms = float(np.median(p[sel])) * fs / 2
    return ms if ms > 1e-10 * float(np.var(sig)) else None


def noise_weights(records: list[RunRecord], noise_ms: dict[str, float]) -> dict[str, float]:
    """Per non-displacement objective channel: the factor that brings its residual to
    displacement-equivalent noise, ``sqrt(noise of the displacement channels / its own)``
    (mean squares over the channels of each quantity). Displacement channels weigh 1 (absent).
    A quantity without a noise estimate, or data with noise-free displacement, weighs 0."""
    by_q: dict[str, list[float]] = {}
    quantity: dict[str, str] = {}
    for rec in records:
        for ch, (_, q) in rec.objective_channels().items():
            quantity[ch] = q
            if ch in noise_ms:
                by_q.setdefault(q, []).append(noise_ms[ch])
    ref = float(np.mean(by_q["displacement"])) if by_q.get("displacement") else 0.0
    out: dict[str, float] = {}
    for ch, q in quantity.items():
        if q == "displacement":
            continue
        own = float(np.mean(by_q[q])) if by_q.get(q) else 0.0
        out[ch] = math.sqrt(ref / own) if ref > 0 and own > 0 else 0.0
    return out


def summary(rows: list[dict]) -> dict[str, Any]:
    """Per-harmonic residual amplitude (RMS over dwells) and the fundamental's errors, over the
    displacement channels."""
    rows = _displacement_rows(rows)
    if not rows:
        return {}
    h = np.array([r["residual_harmonics_m"] for r in rows])
    return {
        "dwells": len({(r["run"], r["segment"]) for r in rows}),
        "residual_harmonic_rms_m": [float(v) for v in np.sqrt(np.mean(h**2, axis=0))],
        "amplitude_error_rms": float(np.sqrt(np.mean([r["amplitude_error"] ** 2 for r in rows]))),
        "phase_error_rms_deg": float(np.sqrt(np.mean([r["phase_error_deg"] ** 2
                                                       for r in rows]))),
    }
