"""The oil's temperature over the data, and the course a viscosity drift follows.

The film's damping scales with the oil's viscosity (report eq. 16), and the viscosity with its
temperature (eq. 1: mu ~ exp(-0.01665 T)). Where the runs record the oil temperature and it
changes over the data by more than its own noise, a drift of the film's damping follows that
temperature: with ``relative_change`` r (film damping at the end of the data over the start,
minus 1) the damping is scaled by ``(1 + r) ** (u(t) - u_model)``, ``u`` the smoothed
temperature's share of its change from the start of the data to its end and ``u_model`` the
share at the temperature the model's film is at. Eq. 1 is exponential in the temperature, so
this course is the law itself, whatever the temperature does in between (a linear warming in
time is a special case). Without a recorded change ``u`` is the time's share of the data
(``t / duration``), the drift starting from the model's film (``u_model`` = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.diagnose.data import RunRecord

#: blocks a record's oil temperature is averaged over: a temperature follows heating and
#: losses with time constants of minutes, so a 64th of a record resolves its course, and each
#: block's mean keeps the channel's noise out of the film's damping
SMOOTH_BLOCKS = 64


@dataclass(frozen=True)
class Smoothed:
    """A record's oil temperature smoothed: block means at their centres [s] (the ends
    extrapolated linearly from the first and last two), and the standard deviation of the
    course at the record's ends (from the scatter about it)."""

    times_s: np.ndarray
    temps_c: np.ndarray
    end_sd_c: float

    def at(self, t_s: np.ndarray) -> np.ndarray:
        return np.interp(t_s, self.times_s, self.temps_c)


def smoothed_temperature(rec: RunRecord) -> Smoothed | None:
    """The record's oil temperature smoothed (None: not recorded, or too short to smooth)."""
    temp = rec.t_oil_c
    blocks = min(SMOOTH_BLOCKS, 0 if temp is None else temp.size // 16)
    if temp is None or blocks < 2:
        return None
    per = temp.size // blocks
    means = temp[:blocks * per].reshape(blocks, per).mean(axis=1)
    centres = (np.arange(blocks) * per + 0.5 * (per - 1)) / rec.sample_rate_hz
    t_end = (temp.size - 1) / rec.sample_rate_hz
    first = means[0] - (means[1] - means[0]) * centres[0] / (centres[1] - centres[0])
    last = means[-1] + (means[-1] - means[-2]) * (t_end - centres[-1]) / (centres[-1] - centres[-2])
    course = Smoothed(np.concatenate([[0.0], centres, [t_end]]),
                      np.concatenate([[first], means, [last]]), 0.0)
    scatter = float(np.std(temp - course.at(np.arange(temp.size) / rec.sample_rate_hz)))
    # an end extrapolated half a block from two block means: 1.5 m1 - 0.5 m2
    return Smoothed(course.times_s, course.temps_c, scatter * math.sqrt(2.5 / per))


def mean_temperature(records: list[RunRecord]) -> float | None:
    """The mean recorded oil temperature over every record that has one [degC] (None: none
    does)."""
    temps = [r.t_oil_c for r in records if r.t_oil_c is not None and r.t_oil_c.size]
    if not temps:
        return None
    return float(np.mean(np.concatenate(temps)))


@dataclass(frozen=True)
class DriftCourse:
    """What a viscosity drift follows over the data: the recorded oil temperature, where its
    change from the first record's start to the last record's end stands ``z`` standard
    deviations above the smoothing's noise, else time (see the module doc)."""

    smoothed: tuple[Smoothed | None, ...]  # per record
    first_c: float | None  # the smoothed temperature at the start of the data
    last_c: float | None  # ... and at its end (both None: the drift follows time)

    @property
    def follows_temperature(self) -> bool:
        return self.first_c is not None and self.last_c is not None

    def describe(self) -> str:
        if self.first_c is None or self.last_c is None:
            return "time"
        return f"oil temperature {self.first_c:.4g} -> {self.last_c:.4g} C"

    def share(self, run: int, t_s: np.ndarray, duration_s: float) -> np.ndarray:
        """``u`` at times ``t_s`` [s] of record ``run``: the share of the drift reached."""
        sm = self.smoothed[run] if run < len(self.smoothed) else None
        if self.first_c is None or self.last_c is None or sm is None:
            return t_s / duration_s
        return (sm.at(t_s) - self.first_c) / (self.last_c - self.first_c)

    def model_share(self, model_temperature_c: float) -> float:
        """``u`` of a model's film held at ``model_temperature_c``, within the data's range
        (0 where the drift follows time: it starts from the model's film)."""
        if self.first_c is None or self.last_c is None:
            return 0.0
        u = (model_temperature_c - self.first_c) / (self.last_c - self.first_c)
        return float(min(max(u, 0.0), 1.0))


def drift_course(records: list[RunRecord], z: float) -> DriftCourse:
    """The course a viscosity drift follows on ``records`` (``z``: the standard deviations
    the temperature's change must stand above its smoothing's noise)."""
    smoothed = tuple(smoothed_temperature(r) for r in records)
    first, last = smoothed[0], smoothed[-1]
    if first is None or last is None:
        return DriftCourse(smoothed, None, None)
    t_end = (records[-1].n_samples - 1) / records[-1].sample_rate_hz
    t0, t1 = float(first.at(np.array([0.0]))[0]), float(last.at(np.array([t_end]))[0])
    if not abs(t1 - t0) > z * math.hypot(first.end_sd_c, last.end_sd_c):
        return DriftCourse(smoothed, None, None)
    return DriftCourse(smoothed, t0, t1)
