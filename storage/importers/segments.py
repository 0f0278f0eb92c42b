"""Dwells (and sweeps) in a continuous record.

A new dwell starts wherever the excitation frequency, the amplitude of the response or of the
force, or the motion changes, or where a step column changes value. Within a run of constant
frequency the record is cut into cycles and each cycle's fundamental (x, y, fx, fy) is compared
with the dwell's so far: a change of more than ``AMPLITUDE_STEP`` (relative) in the response or the
force, or another motion class, starts a new dwell; pieces shorter than ``MIN_CYCLES`` (the
transitions between dwells) are left out. A frequency column that changes every few samples is a
continuous sine sweep: it is recorded as a sweep, not as dwells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Relative change of a cycle's amplitude that starts a new dwell (the report's amplitudes 13, 19,
#: 25, 32, 38 um differ by 19 % or more).
AMPLITUDE_STEP = 0.08
#: Fewest cycles a piece must hold to be a dwell.
MIN_CYCLES = 3
#: Cycles at the start of a dwell that its later cycles are compared with.
REFERENCE_CYCLES = 5
#: A run of constant frequency shorter than this many periods is a piece of a sweep.
SWEEP_PIECE_PERIODS = 2.0
#: Fewest consecutive such runs that make a sweep.
SWEEP_MIN_PIECES = 10
#: Ratio |Y/X| below which the motion is along x (above 1/ratio: along y).
UNIDIRECTIONAL_RATIO = 0.15
#: |Y/X| within this of 1 and phase within ``CIRCULAR_PHASE_DEG`` of +-90 deg: circular.
CIRCULAR_RATIO = 0.15
CIRCULAR_PHASE_DEG = 15.0


def classify_motion(x: complex, y: complex) -> tuple[str, str]:
    """Motion of the fundamental (X, Y) and a sentence saying why (the evidence)."""
    ax, ay = abs(x), abs(y)
    if ax == 0 and ay == 0:
        return "x", "no motion measured; x assumed"
    if ay <= UNIDIRECTIONAL_RATIO * ax:
        return "x", f"|Y/X| = {ay / ax:.3f}"
    if ax <= UNIDIRECTIONAL_RATIO * ay:
        return "y", f"|X/Y| = {ax / ay:.3f}"
    ratio = ay / ax
    phase = math.degrees(np.angle(y / x))
    why = f"|Y/X| = {ratio:.3f}, Y leads X by {phase:.1f} deg"
    if abs(ratio - 1) <= CIRCULAR_RATIO and abs(phase + 90) <= CIRCULAR_PHASE_DEG:
        return "circular_forward", why
    if abs(ratio - 1) <= CIRCULAR_RATIO and abs(phase - 90) <= CIRCULAR_PHASE_DEG:
        return "circular_backward", why
    return "elliptical", why


@dataclass
class Segmentation:
    """Steps (contract A dicts), sweeps and the evidence of what was inferred."""

    steps: list[dict[str, Any]] = field(default_factory=list)
    sweeps: list[dict[str, Any]] = field(default_factory=list)
    motion_evidence: list[str] = field(default_factory=list)  # per step, "" when given


def _fundamental(sig: np.ndarray, fs: float, f: float, a: int, b: int) -> complex:
    t = np.arange(a, b) / fs
    return complex(2 * np.mean(sig[a:b] * np.exp(-2j * math.pi * f * t)))


def _runs(values: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) runs of equal values (NaN equal to NaN)."""
    v = np.asarray(values, dtype=np.float64)
    same = (v[1:] == v[:-1]) | (np.isnan(v[1:]) & np.isnan(v[:-1]))
    change = np.flatnonzero(~same) + 1
    bounds = np.concatenate(([0], change, [v.size]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def dominant_frequency(sig: np.ndarray, fs: float) -> float:
    """Frequency of the largest spectral peak [Hz] (parabolic interpolation), NaN if flat."""
    s = np.asarray(sig, dtype=np.float64) - np.mean(sig)
    if s.size < 8 or not np.any(s):
        return math.nan
    spec = np.abs(np.fft.rfft(s * np.hanning(s.size)))
    k = int(np.argmax(spec[1:])) + 1
    if 1 <= k < spec.size - 1:
        lo, mid, hi = np.log(spec[k - 1:k + 2] + 1e-300)
        den = lo - 2 * mid + hi
        k_frac = k + (0.5 * (lo - hi) / den if den else 0.0)
    else:
        k_frac = float(k)
    return float(k_frac * fs / s.size)


def _split_by_cycles(resp: tuple[np.ndarray | None, np.ndarray | None],
                     force: tuple[np.ndarray | None, np.ndarray | None], fs: float, f: float,
                     a: int, b: int) -> list[tuple[int, int]]:
    """Cut [a, b) at cycles where amplitude or motion changes; drop pieces < MIN_CYCLES."""
    period = fs / f
    n_cyc = int((b - a) // period)
    if n_cyc < 2 * MIN_CYCLES:
        return [(a, b)]
    edges = np.array([a + int(round(k * period)) for k in range(n_cyc + 1)])
    # per-cycle fundamentals from cumulative sums: O(n) for any number of cycles
    t = np.arange(a, b) / fs
    phasor = np.exp(-2j * math.pi * f * t)

    def per_cycle(sig: np.ndarray | None) -> np.ndarray:
        if sig is None:
            return np.zeros(n_cyc, dtype=complex)
        cs = np.concatenate(([0j], np.cumsum(sig[a:b] * phasor)))
        lo, hi = edges[:-1] - a, edges[1:] - a
        return 2 * (cs[hi] - cs[lo]) / (hi - lo)

    zx, zy, fx, fy = (per_cycle(s) for s in (*resp, *force))
    z_mag, f_mag = np.hypot(np.abs(zx), np.abs(zy)), np.hypot(np.abs(fx), np.abs(fy))
    feats = [(float(z_mag[k]), float(f_mag[k]),
              classify_motion(complex(zx[k]), complex(zy[k]))[0] if resp[1] is not None
              else "x") for k in range(n_cyc)]
    pieces: list[tuple[int, int]] = []
    start = 0
    for k in range(1, n_cyc + 1):
        if k < n_cyc:
            ref = feats[start:min(k, start + REFERENCE_CYCLES)]
            z_ref = float(np.median([r[0] for r in ref]))
            f_ref = float(np.median([r[1] for r in ref]))
            zk, fk, mk = feats[k]
            changed = (abs(zk - z_ref) > AMPLITUDE_STEP * max(z_ref, 1e-300)
                       or abs(fk - f_ref) > AMPLITUDE_STEP * max(f_ref, 1e-300)
                       or mk != ref[-1][2])
            if not changed:
                continue
        if k - start >= MIN_CYCLES:
            pieces.append((int(edges[start]), int(edges[k]) if k < n_cyc else b))
        start = k
    return pieces


def segment_record(signals: dict[str, np.ndarray], fs_hz: float, freq_hz: np.ndarray | None,
                   step: np.ndarray | None = None, motion: str | None = None) -> Segmentation:
    """Dwells and sweeps of a record (canonical signal names, see `storage.importers`).

    Parameters
    ----------
    signals : dict
        Canonical name -> samples; the response is ``x_m``/``y_m`` or, without them, the
        accelerations or velocities.
    fs_hz : float
    freq_hz : ndarray or None
        Excitation frequency per sample (NaN or <= 0: rest).
    step : ndarray or None
        A step column: each run of one value is one dwell (NaN or < 0: rest), not split further.
    motion : str or None
        The motion of every dwell when stated; else inferred per dwell from the x/y phase.
    """
    out = Segmentation()
    resp = _response(signals)
    force = (signals.get("fx_N"), signals.get("fy_N"))
    pieces: list[tuple[int, int, float]] = []
    if step is not None:
        for a, b in _runs(step):
            v = float(step[a])
            if not (math.isfinite(v) and v >= 0):
                continue
            f = _step_frequency(freq_hz, signals, a, b, fs_hz)
            if math.isfinite(f) and f > 0:
                pieces.append((a, b, f))
    elif freq_hz is not None:
        sweep_run: list[tuple[int, int]] = []
        for a, b in _runs(freq_hz) + [(-1, -1)]:
            f = float(freq_hz[a]) if a >= 0 else math.nan
            is_piece = a >= 0 and math.isfinite(f) and f > 0 and (b - a) < \
                SWEEP_PIECE_PERIODS * fs_hz / f
            if is_piece:
                sweep_run.append((a, b))
                continue
            if len(sweep_run) >= SWEEP_MIN_PIECES:
                s0, s1 = sweep_run[0][0], sweep_run[-1][1]
                out.sweeps.append({"first_sample": s0, "last_sample": s1,
                                   "f_start_hz": float(freq_hz[s0]),
                                   "f_stop_hz": float(freq_hz[s1 - 1])})
            else:  # a few short dwells are still dwells (whether they hold enough cycles is
                # for the analysis to judge)
                pieces.extend((p0, p1, float(freq_hz[p0])) for p0, p1 in sweep_run)
            sweep_run = []
            if a < 0 or not (math.isfinite(f) and f > 0):
                continue
            for c0, c1 in _split_by_cycles(resp, force, fs_hz, f, a, b):
                pieces.append((c0, c1, f))
    for a, b, f in pieces:
        x = _fundamental(resp[0], fs_hz, f, a, b) if resp[0] is not None else 0j
        y = _fundamental(resp[1], fs_hz, f, a, b) if resp[1] is not None else 0j
        if motion is not None:
            m, why = motion, ""
        elif resp[1] is None:
            m, why = ("x", "only x measured") if resp[0] is not None else ("y", "only y measured")
        elif resp[0] is None:
            m, why = "y", "only y measured"
        else:
            m, why = classify_motion(x, y)
        out.steps.append({
            "index": len(out.steps), "freq_hz": f, "target_kind": "", "target_value": math.nan,
            "motion": m, "first_sample": a, "last_sample": b, "updates": 0,
            "converged": True, "reason": "", "harmonics": {}, "drive_v": {},
        })
        out.motion_evidence.append(why)
    return out


def _response(signals: dict[str, np.ndarray]) -> tuple[np.ndarray | None, np.ndarray | None]:
    for xs, ys in (("x_m", "y_m"), ("vx_mps", "vy_mps"), ("ax_mps2", "ay_mps2")):
        if xs in signals or ys in signals:
            return signals.get(xs), signals.get(ys)
    return None, None


def _step_frequency(freq_hz: np.ndarray | None, signals: dict[str, np.ndarray], a: int, b: int,
                    fs: float) -> float:
    if freq_hz is not None:
        f = freq_hz[a:b]
        f = f[np.isfinite(f) & (f > 0)]
        return float(np.median(f)) if f.size else math.nan
    for name in ("fx_N", "fy_N", "x_m", "y_m", "ax_mps2", "ay_mps2"):
        if name in signals and np.ptp(signals[name][a:b]) > 0:
            return dominant_frequency(signals[name][a:b], fs)
    return math.nan
