"""Read the dwells of a run file and compute their synchronous components from the raw channels.

Every check that can fail names the run, the step and the channel: a signal missing from the run,
a dwell with too few whole cycles, NaN samples, samples at the ADC's range (saturation). A dwell
whose signal fails is kept with that signal left out; the failure is recorded as `Skipped`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from analysis.errors import Skipped
from analysis.sync import N_HARMONICS, harmonics, whole_cycle_span
from storage import RunData

MIN_CYCLES = 3
#: Canonical signals the dynamic analyses use.
DYNAMIC_SIGNALS = ("fx", "fy", "x", "y", "ax", "ay")


@dataclass
class Dwell:
    """One dwell of a run: its step description and the harmonics of its signals.

    ``harmonics[name]`` is complex, shape (n,), n >= 5: 1X..nX, ``Z = z_c - i z_s`` (eq. 12-13),
    in SI.
    """

    run_id: str
    step: int
    freq_hz: float
    motion: str
    target_kind: str
    target_value: float
    first_sample: int
    last_sample: int
    cycles: float
    converged: bool
    harmonics: dict[str, np.ndarray] = field(default_factory=dict)
    means: dict[str, float] = field(default_factory=dict)

    @property
    def omega(self) -> float:
        return 2 * np.pi * self.freq_hz

    def z1(self, name: str) -> complex:
        return complex(self.harmonics[name][0])


def run_label(run: RunData) -> str:
    """How messages name a run: its id and file name."""
    return f"{run.run_id} ({run.path.name})"


def signal_channels(run: RunData, name: str) -> list[str]:
    """The raw channels behind a canonical signal (the probes x1, x2 for "x")."""
    if name in run.channel_names:
        return [name]
    if name in ("x", "y"):
        return [c for c in run.channel_names if re.fullmatch(rf"{name}\d+", c)]
    return []


def _range_limits(run: RunData, channel: str) -> tuple[float, float] | None:
    """The channel's input range in engineering units, from the channel map, if known."""
    cmap = run.channel_map or {}
    for ch in cmap.get("ai", []):
        if ch.get("name") == channel and "range_v" in ch and ch.get("gain_v_per_unit"):
            gain = float(ch["gain_v_per_unit"])
            off = float(ch.get("offset_v", 0.0))
            lo_v, hi_v = (float(v) for v in ch["range_v"])
            # the ADC clips just inside the range: allow two codes of margin
            lsb = 2 * 10.0 / 2**16
            lo, hi = (lo_v + 2 * lsb - off) / gain, (hi_v - 2 * lsb - off) / gain
            return (min(lo, hi), max(lo, hi))
    return None


def read_channel(run: RunData, channel: str, start: int, stop: int) -> np.ndarray:
    """Samples ``[start, stop)`` of a recorded channel, read straight from its dataset.

    (`RunData.channel` re-measures every dataset's length on each call, which dominates the
    cost of reading a run dwell by dwell; the caller checks the span against ``n_samples``.)
    """
    ds = run.h5[f"channels/{channel}"]
    return np.asarray(ds[start:min(stop, ds.shape[0])], dtype=np.float64)


def check_channel(run: RunData, channel: str, data: np.ndarray) -> str:
    """'' if the samples are usable, else why not (NaN or saturated samples)."""
    bad = ~np.isfinite(data)
    if bad.any():
        return f"{int(bad.sum())} NaN/inf sample(s) of {data.size}"
    lim = _range_limits(run, channel)
    if lim is not None and data.size:
        lo, hi = lim
        sat = (data <= lo) | (data >= hi)
        if sat.any():
            units = run.units(channel) if channel in run.channel_names else ""
            return (f"saturated: {int(sat.sum())} sample(s) at the input range "
                    f"({lo:.4g} .. {hi:.4g} {units})")
    return ""


def read_signal(run: RunData, name: str, start: int, stop: int, analysis: str, step: int | None,
                skipped: list[Skipped]) -> np.ndarray | None:
    """A canonical signal over ``[start, stop)``, from the channels that pass the checks.

    A probe pair (x1, x2) falls back to the good probe when one fails. None (and a `Skipped`
    entry per failing channel) when nothing usable is left.
    """
    label = run_label(run)
    chans = signal_channels(run, name)
    if not chans:
        present = ", ".join(run.channel_names)
        skipped.append(Skipped(label, analysis, f"signal {name!r} is not in the run "
                               f"(channels {present})", step, name,
                               cause=f"signal not in the run (channels {present})"))
        return None
    good = []
    for ch in chans:
        data = read_channel(run, ch, start, stop)
        if data.size < stop - start:
            skipped.append(Skipped(label, analysis, f"only {data.size} of {stop - start} samples "
                                   "recorded", step, ch))
            continue
        why = check_channel(run, ch, data)
        if why:
            skipped.append(Skipped(label, analysis, why, step, ch))
            continue
        good.append(data)
    if not good:
        return None
    return np.mean(good, axis=0) if len(good) > 1 else good[0]


def load_dwells(run: RunData, analysis: str, signals: tuple[str, ...] = DYNAMIC_SIGNALS,
                skipped: list[Skipped] | None = None, min_cycles: int = MIN_CYCLES,
                require: tuple[str, ...] = (), n_harmonics: int = N_HARMONICS) -> list[Dwell]:
    """The periodic dwells of a run with the harmonics of ``signals`` over whole cycles.

    Parameters
    ----------
    run : RunData
        An open run file.
    analysis : str
        Name of the analysis asking (for the messages).
    signals : tuple of str
        Canonical signals to decompose.
    skipped : list of Skipped
        Receives one entry per dwell or signal left out.
    min_cycles : int
        Fewest whole cycles a dwell must hold.
    require : tuple of str
        Signals without which a dwell is dropped altogether.
    n_harmonics : int
        Harmonics to resolve (at least 5; fewer than asked where they would pass 0.45 fs).
    """
    skipped = [] if skipped is None else skipped
    label = run_label(run)
    fs = run.sample_rate_hz
    out: list[Dwell] = []
    steps = run.steps
    if not steps:
        skipped.append(Skipped(label, analysis, "the run has no steps (no dwells recorded)"))
    for st in steps:
        idx = int(st["index"])
        f = float(st["freq_hz"])
        if not f > 0:
            skipped.append(Skipped(label, analysis, f"frequency {f} Hz is not positive", idx))
            continue
        first, last, cycles = whole_cycle_span(int(st["first_sample"]), int(st["last_sample"]),
                                               f, fs)
        if cycles < min_cycles:
            skipped.append(Skipped(label, analysis, f"only {cycles:g} whole cycle(s) at {f:g} Hz "
                                   f"(at least {min_cycles} needed)", idx))
            continue
        if last > run.n_samples:
            skipped.append(Skipped(label, analysis, f"span [{first}, {last}) runs past the "
                                   f"{run.n_samples} recorded samples", idx))
            continue
        dw = Dwell(label, idx, f, str(st.get("motion", "")), str(st.get("target_kind", "")),
                   float(st.get("target_value", float("nan"))), first, last, cycles,
                   bool(st.get("converged", True)))
        if not dw.converged:
            skipped.append(Skipped(label, analysis, "dwell did not converge "
                                   f"({st.get('reason') or 'no reason given'}); kept, flagged",
                                   idx))
        rows, names = [], []
        for name in signals:
            data = read_signal(run, name, first, last, analysis, idx, skipped)
            if data is not None:
                rows.append(data)
                names.append(name)
        missing = [r for r in require if r not in names]
        if missing:
            skipped.append(Skipped(label, analysis, f"dwell dropped: no usable {missing}", idx,
                                   ",".join(missing)))
            continue
        if rows:
            nh = max(N_HARMONICS, min(n_harmonics, int(0.45 * fs / f)))
            amps, means = harmonics(np.vstack(rows), first, f, fs, nh)
            for i, name in enumerate(names):
                dw.harmonics[name] = amps[i]
                dw.means[name] = float(means[i])
        out.append(dw)
    return out
