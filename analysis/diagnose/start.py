"""A start for the fitted baseline without a prior: a frequency-domain fit of dynamic stiffness.

Per axis, the dynamic stiffness ``D(w) = F(w) / Z(w) = K - w^2 M + i w C`` of a one-mode
structure is linear in (K, M, C), so a least-squares fit over frequencies needs no start:

- dwells: ``F`` and ``Z`` are the 1X complex amplitudes of force and response of each dwell
  (``residual_analysis.harmonics``), one equation per dwell whose 1X force stands
  ``Z_STRUCTURE`` standard deviations above its own noise (`stands_above_noise`; a dwell along
  the other axis leaves this one's load cell noise, whatever its size against the drive);
- other data (broadband, sweeps): ``1 / D`` is the H1 estimate ``S_fz / S_ff`` (Welch), over the
  excited band where the coherence is at least 0.5.

Each equation is weighted by ``|Z / F|``, so the fit minimises the relative error of the
predicted response rather than of the stiffness (a stiffness fit alone favours the frequencies
far from resonance). Only a start: the output-error fit refines it in the time domain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import csd, welch

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.residual_analysis import harmonics
from analysis.diagnose.residual_structure import Z_STRUCTURE


@dataclass(frozen=True)
class OneMode:
    """Mass [kg], damping [N.s/m] and stiffness [N/m] of one axis, with the fit's quality."""

    mass_kg: float
    damping_ns_per_m: float
    stiffness_n_per_m: float
    points: int

    @property
    def natural_hz(self) -> float:
        return math.sqrt(self.stiffness_n_per_m / self.mass_kg) / (2 * math.pi)

    @property
    def damping_ratio(self) -> float:
        return self.damping_ns_per_m / (2 * math.sqrt(self.stiffness_n_per_m * self.mass_kg))

    def decay_time_s(self) -> float:
        """Time constant of the free response's envelope, 2 M / C [s]."""
        return 2 * self.mass_kg / max(self.damping_ns_per_m, 1e-12)


def stands_above_noise(amplitude: float, rest_rms: float, n: int) -> bool:
    """Whether a dwell's 1X amplitude stands ``Z_STRUCTURE`` standard deviations above its own
    noise: the RMS ``rest_rms`` the harmonic fit leaves, over ``n`` samples, is an error of
    ``rest_rms * sqrt(2 / n)`` on each of the amplitude's two components."""
    return amplitude >= Z_STRUCTURE * rest_rms * math.sqrt(2.0 / n)


def _axis_response(rec: RunRecord, axis: int) -> np.ndarray | None:
    chans = [v for c, v in rec.responses.items() if rec.response_axis[c] == axis]
    return np.mean(chans, axis=0) if chans else None


def _points(records: list[RunRecord], segs: list[Segment],
            axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angular frequencies [rad/s], dynamic stiffness [N/m] and weights of the fit."""
    w_all: list[float] = []
    d_all: list[complex] = []
    wt_all: list[float] = []
    broadband: list[Segment] = []
    for seg in segs:
        rec = records[seg.run]
        z = _axis_response(rec, axis)
        f = rec.force_n[axis]
        if z is None or not np.any(f[seg.start:seg.stop]):
            continue
        if not seg.freq_hz:
            broadband.append(seg)
            continue
        fs = rec.sample_rate_hz
        zf, _, f_rest = harmonics(f[seg.start:seg.stop], seg.start, fs, seg.freq_hz, 1)
        zz, _, _ = harmonics(z[seg.start:seg.stop], seg.start, fs, seg.freq_hz, 1)
        if abs(zz[0]) == 0 or not stands_above_noise(abs(zf[0]), f_rest, seg.n):
            # a dwell driven along the other axis: this axis's 1X force is its load cell's
            # noise, and the ratio of noise to motion no dynamic stiffness (weighted |Z/F|,
            # it would outweigh every driven dwell)
            continue
        w_all.append(2 * math.pi * seg.freq_hz)
        d_all.append(complex(zf[0] / zz[0]))
        wt_all.append(abs(zz[0] / zf[0]))
    if broadband:
        fs = records[broadband[0].run].sample_rate_hz
        nper = int(min(min(s.n for s in broadband), max(256, 2 ** round(math.log2(8 * fs)))))
        s_ff = s_fz = s_zz = None
        for seg in broadband:
            rec = records[seg.run]
            if rec.sample_rate_hz != fs:
                continue
            z = _axis_response(rec, axis)
            assert z is not None
            f = rec.force_n[axis, seg.start:seg.stop]
            zz = z[seg.start:seg.stop]
            fa, pff = welch(f - f.mean(), fs, nperseg=nper)
            _, pfz = csd(f - f.mean(), zz - zz.mean(), fs, nperseg=nper)
            _, pzz = welch(zz - zz.mean(), fs, nperseg=nper)
            s_ff = pff if s_ff is None else s_ff + pff
            s_fz = pfz if s_fz is None else s_fz + pfz
            s_zz = pzz if s_zz is None else s_zz + pzz
        if s_ff is not None and s_fz is not None and s_zz is not None:
            coh = np.abs(s_fz) ** 2 / np.maximum(s_ff * s_zz, 1e-300)
            good = (coh >= 0.5) & (fa > 0) & (s_ff > 1e-6 * np.max(s_ff))
            h = s_fz[good] / s_ff[good]  # response per force, H1
            w_all += list(2 * math.pi * fa[good])
            d_all += list(1.0 / h)
            wt_all += list(np.abs(h) * np.sqrt(coh[good]))
    return np.array(w_all), np.array(d_all), np.array(wt_all)


def fit_one_mode(w: np.ndarray, d: np.ndarray,
                 wt: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(K, M, C) of ``D(w) = K - w^2 M + i w C`` by weighted least squares, and their
    covariance from the fit's residual (None where it is singular)."""
    # real part: K - w^2 M; imaginary part: w C (weighted least squares, stacked)
    a = np.zeros((2 * w.size, 3))
    a[: w.size, 0] = 1.0
    a[: w.size, 1] = -(w**2)
    a[w.size:, 2] = w
    b = np.concatenate([d.real, d.imag])
    ww = np.concatenate([wt, wt])
    aw, bw = a * ww[:, None], b * ww
    sol, *_ = np.linalg.lstsq(aw, bw, rcond=None)
    s2 = float(np.sum((aw @ sol - bw) ** 2)) / max(1, bw.size - 3)
    try:
        cov = s2 * np.linalg.inv(aw.T @ aw)
    except np.linalg.LinAlgError:
        cov = None
    return sol, cov


def one_mode_estimate(records: list[RunRecord], segs: list[Segment], axis: int = 0,
                      added_mass_kg: float = 0.0,
                      added_damping_ns_per_m: float = 0.0) -> OneMode | None:
    """Structure mass, damping and stiffness of ``axis`` from the data alone (None: no data).

    ``added_mass_kg`` and ``added_damping_ns_per_m`` are known parts of the measured dynamic
    stiffness that are not the structure's (the film's added mass and damping): they are taken
    off the estimate.
    """
    w, d, wt = _points(records, segs, axis)
    if w.size < 3:
        return None
    sol, _ = fit_one_mode(w, d, wt)
    k, m, c = (float(v) for v in sol)
    m -= added_mass_kg
    c -= added_damping_ns_per_m
    if not (k > 0 and m > 0):
        return None
    return OneMode(m, max(c, 0.0), k, int(w.size))


def dynamic_stiffness_points(records: list[RunRecord], segs: list[Segment],
                             axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fit's points of ``axis`` on ``segs``: angular frequencies [rad/s], dynamic
    stiffness F/Z [N/m] (complex) and the weights |Z/F| (per dwell, or H1 where coherent)."""
    return _points(records, segs, axis)
