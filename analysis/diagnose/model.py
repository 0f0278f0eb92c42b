"""The candidate model and its replay: measured force through the rig simulation.

A `Model` is the rig configuration (`RigParams`, the same object the simulator loads) plus the
parts of the measurement chain a diagnosis may change: per-channel recorded/true gain and time
delay, a viscosity drift over the data, and a force offset (imported data). `Evaluator` replays
the measured force of every run through `rig_model.simulate_response` (the simulator's own
kernel), windowed around the segments it is asked about, and returns predicted response channels.

Replay details, stated:
- Sweep runs of the rig replay at the run's sample rate with the configured substeps, exactly as
  the simulator integrates its own force samples.
- Imported runs (low sample rates, e.g. 610 Hz) replay on a force oversampled by an integer
  factor with a band-limited polyphase interpolator, one integration step per oversampled sample:
  a linear or held force between samples 1.6 ms apart would distort a 60 Hz response by percent.
- Each window starts ``warmup_s`` before its first segment from rest; the transient of starting
  from rest is not scored (segments start after the warm-up). A model with memory (a sticking
  seal, a micro-slipping joint: `remembers`) replays from ``warmup_s`` before the run's drive
  starts instead (`Evaluator._memory_start`).
  With ``steady_state_dwells``, a dwell is replayed after whole periods of its own force
  instead (its initial state is then the steady state the dwell was recorded in, whatever came
  before it in the file), for as long as the model takes to forget its start (``lead.py``).
- Each response channel's mean offset (probe gap, amplifier offset) is fitted in closed form on
  the training segments and applied unchanged to held-out segments.
- Data from elsewhere (a run without a rig description) come from accelerometers behind an
  anti-alias filter: with dry friction in the model, whose switching and sticking make the
  kernel's acceleration jump, a sample of that acceleration at an instant aliases the jumps
  (its 1X 0.2-2 % off the derivative of its own displacement at 10-35 um, 20-60 Hz, 10 N,
  5 kS/s) where the instrument's does not; there the replayed acceleration is the second
  derivative of the replayed displacement, band-limited by the sampling
  (`sampled_acceleration`).
- Every measured response is compared (`RunRecord.objective_channels`): displacement (the
  simulated relative displacement), velocity and acceleration (the simulated absolute housing
  acceleration), each through its own gain and delay. Residuals of channels of different
  quantities are weighted by their noise (``Evaluator.weights``: the displacement channels' noise
  over the channel's own), so the objective and every error reported stay in metres of
  displacement-equivalent noise and a quieter sensor counts more.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.signal import resample_poly

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.extra_modes import ExtraMode, modal_response
from analysis.diagnose.lead import steady_lead
from analysis.diagnose.oil import DriftCourse
from analysis.diagnose.periodic import StepMap, step_map
from rig_model import physics
from rig_model.params import VISCOSITY_SLOPE_PER_C, RigParams
from rig_model.rig import kernel_params, simulate_response


@dataclass(frozen=True)
class Model:
    """Rig configuration plus measurement-chain terms (see module doc)."""

    rig: RigParams
    gain: dict[str, float] = field(default_factory=dict)  # channel -> recorded / true
    delay_s: dict[str, float] = field(default_factory=dict)  # channel -> delay [s]
    visc_relative_change: float = 0.0  # film damping change from start to end of the data
    force_offset_n: tuple[float, float] = (0.0, 0.0)
    #: linear modes added at the output beyond the kernel's (``extra_modes``): the fitted
    #: baseline's higher order where the band holds several modes per axis
    extra_modes: tuple[ExtraMode, ...] = ()

def set_path(model: Model, path: str, value: Any) -> Model:
    """A copy of ``model`` with the RigParams field at dotted ``path`` set to ``value``."""
    data = model.rig.model_dump(mode="python")
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = value
    return replace(model, rig=RigParams.model_validate(data))


def get_path(model: Model, path: str) -> Any:
    node: Any = model.rig
    for k in path.split("."):
        node = getattr(node, k)
    return node


@dataclass(frozen=True)
class Param:
    """One fitted number: JSON name, how to read and write it on a Model, and its scale."""

    name: str
    get: Callable[[Model], float]
    set: Callable[[Model, float], Model]
    scale: float
    lo: float = -math.inf
    hi: float = math.inf
    #: lo and hi are models of their own (the joint's law at Dahl's end or the elastic one),
    #: not a fit held on a bound
    ends_are_models: bool = False


def rig_param(name: str, path: str, scale: float, lo: float = -math.inf,
              hi: float = math.inf) -> Param:
    return Param(name, lambda m: float(get_path(m, path)),
                 lambda m, v: set_path(m, path, float(v)), scale, lo, hi)


@dataclass
class Prediction:
    """Predicted response channels per segment (before offsets)."""

    channels: dict[Segment, dict[str, np.ndarray]]


class Evaluator:
    """Replays runs under a Model; caches simulations (measurement-only changes are free).

    Parameters
    ----------
    records : list of RunRecord
    warmup_s : float
        Simulated time before each window's first segment [s].
    steady_state_dwells : bool
        Replay each dwell in steady state: whole periods of its own force repeated for at
        least ``warmup_s`` before it (the data before a dwell need not be its settling: imported
        files hold dwells back to back).
    oversample : dict of int -> int
        Per run index: the force oversampling factor (1: replay at the run's rate).
    weights : dict of str -> float
        Per objective channel: the factor applied to its residual (`noise_weights`).
    drift : DriftCourse or None
        What a viscosity drift follows (``oil.drift_course``: the recorded oil temperature or
        time); None: time.
    """

    def __init__(self, records: list[RunRecord], warmup_s: float = 0.5,
                 oversample: dict[int, int] | None = None,
                 steady_state_dwells: bool = False,
                 weights: dict[str, float] | None = None,
                 drift: DriftCourse | None = None) -> None:
        self.records = records
        self.drift = drift or DriftCourse((), None, None)
        #: channel -> factor to displacement-equivalent units (absent: 1)
        self.weights = dict(weights or {})
        self.warmup_s = warmup_s
        self.steady_state_dwells = steady_state_dwells
        # dwell frequency of each steady-state window, so truth(run, a, b) can find its periods
        self._freq: dict[tuple[int, int, int], float | None] = {
            (s.run, s.start, s.stop): s.freq_hz for r in records for s in r.segments}
        self.oversample = oversample or {}
        self.duration_s = max(r.n_samples / r.sample_rate_hz for r in records)
        self._cache: dict[tuple[bytes, tuple, int, int, int], np.ndarray] = {}
        self._cache_bytes = 0
        self.cache_limit_bytes = 400 * 2**20  # simulations kept for measurement-only changes
        self._up_cache: dict[tuple[int, int, int, int], np.ndarray] = {}
        # per steady-state window: the oversampled force the extra modes see (`_modal_force`)
        self._modal_up: dict[tuple[int, int, int, int], np.ndarray] = {}
        # per run: its whole force oversampled, and the extra modes' response over the whole
        # run of the last models asked about (`_extra_over_run`)
        self._run_force_up: dict[tuple[int, int], np.ndarray] = {}
        self._extra_runs: dict[tuple, np.ndarray] = {}
        # per window and lead: its force with the lead (a few leads a window: `lead.py`)
        self._force_cache: dict[tuple[int, int, int, int], np.ndarray] = {}
        self._memory_starts: dict[int, int] = {}  # per run: `_memory_start`
        self._visc_cache: dict[tuple, np.ndarray] = {}  # `_viscosity_scale`
        # per steady window: the spectrum of its force's whole periods (`_periodic_truth`)
        self._spectra: dict[tuple[int, int, int], np.ndarray] = {}
        # per kernel parameters, fill and viscosity: a linear model's step (`periodic`)
        self._step_maps: dict[tuple[bytes, float, float], StepMap | None] = {}
        # the replay inputs of the last model asked about (a prediction asks per window)
        self._inputs_of: tuple[Model, dict[int, tuple[np.ndarray, tuple]]] | None = None
        self.simulations = 0

    # --- windows --------------------------------------------------------------------------
    def periodic_chunk(self, seg: Segment) -> int:
        """Samples of the longest whole number of periods of dwell ``seg`` that fits in it and
        spans a whole number of samples (0: not a dwell, or no such span)."""
        if not seg.freq_hz or not self.steady_state_dwells:
            return 0
        per = self.records[seg.run].sample_rate_hz / seg.freq_hz
        for k in range(int(seg.n / per), 0, -1):
            if abs(k * per - round(k * per)) < 1e-6 * per:
                return int(round(k * per))
        return 0

    def windows(self, segs: list[Segment],
                from_run_start: bool = False) -> list[tuple[int, int, int, list[Segment]]]:
        """Merge segments into simulation windows (run, start, stop, segments).

        A dwell replayed in steady state (``periodic_chunk`` > 0) is a window of its own. The
        others start ``warmup_s`` before their first segment, or with ``from_run_start`` (a
        model with memory: `remembers`) where the run's drive starts (`_memory_start`), one
        window a run up to its last segment asked for."""
        out: list[tuple[int, int, int, list[Segment]]] = []
        for seg in sorted(segs, key=lambda s: (s.run, s.start)):
            self._freq.setdefault((seg.run, seg.start, seg.stop), seg.freq_hz)
            if self.periodic_chunk(seg):
                out.append((seg.run, seg.start, seg.stop, [seg]))
                continue
            warm = int(self.warmup_s * self.records[seg.run].sample_rate_hz)
            a = max(0, seg.start - warm)
            if from_run_start:
                # from the drive's start, or a warm-up before a segment that lies before it
                # (a record whose drive grows from nothing: the silverbox's first held-out
                # block started before it, and its replay held no samples)
                if out and out[-1][0] == seg.run and out[-1][3][0].start < seg.start \
                        and not self.periodic_chunk(out[-1][3][-1]):
                    run, wa, wb, lst = out[-1]
                    out[-1] = (run, wa, max(wb, seg.stop), [*lst, seg])
                else:
                    out.append((seg.run, min(self._memory_start(seg.run), a), seg.stop, [seg]))
                continue
            if (out and out[-1][0] == seg.run and a <= out[-1][2]
                    and not self.periodic_chunk(out[-1][3][-1])):
                run, wa, wb, lst = out[-1]
                out[-1] = (run, wa, max(wb, seg.stop), [*lst, seg])
            else:
                out.append((seg.run, a, seg.stop, [seg]))
        return out

    def _memory_start(self, run: int) -> int:
        """Where a model with memory starts its replay of run ``run``: ``warmup_s`` before the
        force first rises above ``QUIET_FACTOR`` times its level over the run's first
        ``QUIET_S`` (a rig run's lead-in, the pump filling the film with nothing driven, moves
        nothing a seal or a joint remembers; the warm-up forgets the rest), else its first
        sample."""
        hit = self._memory_starts.get(run)
        if hit is None:
            rec = self.records[run]
            fs = rec.sample_rate_hz
            f = np.max(np.abs(rec.force_n), axis=0)
            quiet = float(np.sqrt(np.mean(f[:max(1, int(QUIET_S * fs))] ** 2)))
            above = np.flatnonzero(f > QUIET_FACTOR * quiet)
            first = int(above[0]) if above.size else 0
            hit = max(0, first - int(self.warmup_s * fs))
            self._memory_starts[run] = hit
        return hit

    def _lead(self, run: int, a: int, b: int) -> int:
        """Samples of periodic lead-in before window [a, b) (0: replay from rest at a): whole
        periods spanning the warm-up (the extra modes', and the most the kernel's takes:
        `_kernel_truth`)."""
        seg = Segment(run, a, b, "", self._freq.get((run, a, b)))
        chunk = self.periodic_chunk(seg)
        if not chunk:
            return 0
        fs = self.records[run].sample_rate_hz
        return chunk * max(1, math.ceil(self.warmup_s * fs / chunk))

    # --- simulation -----------------------------------------------------------------------
    def _fill(self, rec: RunRecord) -> float:
        return 1.0 if rec.lubricated else 0.0

    def _viscosity_scale(self, model: Model, run: int, a: int, b: int) -> np.ndarray:
        """The film's viscosity scale over [a, b) under ``model``: the same for every model of
        one viscosity law (`_inputs`), so kept per window and law."""
        key = (run, a, b, self._inputs(model, run)[1][0])
        hit = self._visc_cache.get(key)
        if hit is None:
            if len(self._visc_cache) >= 4 * max(1, len(self._freq)):
                self._visc_cache.clear()
            hit = self._visc_cache[key] = self._viscosity_law(model, run, a, b)
        return hit

    def _viscosity_law(self, model: Model, run: int, a: int, b: int) -> np.ndarray:
        rec = self.records[run]
        t = np.arange(a, b) / rec.sample_rate_hz
        oil = model.rig.oil
        _, t_ref = model.rig.film.reference_viscosity()
        warming = oil.warming_c_per_hour / 3600.0 if rec.lubricated else 0.0
        drift = model.rig.effects.viscosity_drift
        if drift.enabled:
            warming += drift.warming_c_per_s
        temp = oil.initial_temperature_c + warming * t
        scale = np.exp(-VISCOSITY_SLOPE_PER_C * (temp - t_ref))
        if model.visc_relative_change != 0.0:
            u = self.drift.share(run, t, self.duration_s) - self.drift_anchor(model)
            scale = scale * (1.0 + model.visc_relative_change) ** u
        return scale

    def drift_anchor(self, model: Model) -> float:
        """The share of the viscosity drift at which ``model``'s film is (``DriftCourse``)."""
        return self.drift.model_share(model.rig.oil.initial_temperature_c)

    def _window_force(self, run: int, a: int, b: int, lead: int) -> np.ndarray:
        """The measured force of [a, b) with ``lead`` samples of its first whole periods
        repeated before it (steady state: the repeats' last ``lead`` samples, which run on
        into the window's first), shape (2, lead + b - a); made once per window and lead."""
        key = (run, a, b, lead)
        hit = self._force_cache.get(key)
        if hit is not None:
            return hit
        f = self.records[run].force_n[:, a:b]
        if lead:
            chunk = self.periodic_chunk(Segment(run, a, b, "", self._freq.get((run, a, b))))
            reps = -(-lead // chunk)
            f = np.hstack([np.tile(f[:, :chunk], (1, reps))[:, reps * chunk - lead:], f])
        f = np.ascontiguousarray(f, dtype=np.float64)
        self._force_cache[key] = f
        return f

    def _inputs(self, model: Model, run: int) -> tuple[np.ndarray, tuple]:
        """The kernel's parameter vector for run ``run`` under ``model`` and what else of the
        model a replay reads (the viscosity's law, the force offset): made once per model and
        run, not per window."""
        if self._inputs_of is None or self._inputs_of[0] is not model:
            self._inputs_of = (model, {})
        per_run = self._inputs_of[1]
        hit = per_run.get(run)
        if hit is None:
            rec = self.records[run]
            up = self.oversample.get(run, 1)
            rig = model.rig if up <= 1 else model.rig.model_copy(update={"substeps": 1})
            oil, drift = model.rig.oil, model.rig.effects.viscosity_drift
            visc = (oil.initial_temperature_c, oil.warming_c_per_hour,
                    model.rig.film.reference_viscosity()[1], drift.enabled,
                    drift.warming_c_per_s, model.visc_relative_change)
            hit = (kernel_params(rig, rec.sample_rate_hz * up),
                   (visc, tuple(model.force_offset_n)))
            per_run[run] = hit
        return hit

    def truth(self, model: Model, run: int, a: int, b: int) -> np.ndarray:
        """Simulated response (6, b - a) of run ``run`` over [a, b): relative displacement x, y
        [m], relative velocity [m/s], absolute housing acceleration [m/s^2]; from rest
        at ``a``, or, for a dwell replayed in steady state, after whole periods of its own
        force (the viscosity of its first sample)."""
        lead = self._lead(run, a, b)
        # what the replay reads of the model: equal keys, equal responses (a model that
        # differs only where the kernel does not look, an effect enabled at 0, is a hit)
        kp, rest = self._inputs(model, run)
        key = (kp.tobytes(), rest, run, a, b)
        hit = self._cache.get(key)
        if hit is None:
            hit = self._kernel_truth(model, run, a, b, lead, kp)
            self._cache[key] = hit
            self._cache_bytes += hit.nbytes
            while self._cache_bytes > self.cache_limit_bytes and len(self._cache) > 1:
                oldest = next(iter(self._cache))  # first inserted
                self._cache_bytes -= self._cache.pop(oldest).nbytes
        # the extra modes are outside the kernel (and its cache): a fit of their parameters
        # alone replays no kernel
        return self._plus_extra_modes(model, run, a, b, lead, hit)

    def _kernel_truth(self, model: Model, run: int, a: int, b: int, lead: int,
                      kp: np.ndarray) -> np.ndarray:
        """The kernel's response (6, b - a) of window [a, b) (`truth`, without extra modes)."""
        rec = self.records[run]
        visc = self._viscosity_scale(model, run, a, b)
        if lead:
            exact = self._periodic_truth(model, run, a, b, kp, visc)
            if exact is not None:
                return exact
            # the kernel's own lead: as long as the model takes to forget its start (`lead.py`)
            per = rec.sample_rate_hz / (self._freq.get((run, a, b)) or rec.sample_rate_hz)
            lead = steady_lead(kp, self._fill(rec), float(visc[0]), rec.sample_rate_hz, per,
                               lead)
            visc = np.concatenate([np.full(lead, visc[0]), visc])
        up = self.oversample.get(run, 1)
        self.simulations += 1
        if up <= 1:
            force = self._window_force(run, a, b, lead)
            if any(model.force_offset_n):
                force = force + np.asarray(model.force_offset_n)[:, None]
            tr, _ = simulate_response(force, model.rig, rec.sample_rate_hz, self._fill(rec), visc,
                                      kernel=kp)
            idx: slice | np.ndarray = slice(None)
        else:
            fup = self._upsampled(run, a, b, up, lead)
            fup = fup + np.asarray(model.force_offset_n)[:, None]
            rig1 = model.rig.model_copy(update={"substeps": 1})
            vup = np.repeat(visc, up)
            tr, _ = simulate_response(fup, rig1, rec.sample_rate_hz * up, self._fill(rec), vup,
                                      kernel=kp)
            # Sample i of the run is oversampled index i*up; the kernel reports the state at
            # the end of each step (linear-force kernel) or after it (held-force kernel).
            shift = 0 if hasattr(physics, "S_FPX") else -1
            idx = np.arange(lead + b - a) * up + shift
            idx[idx < 0] = 0
        # the lead is replayed but not returned; the stack is a copy, so the cache does not keep
        # the whole replay (lead included) alive while counting only its own bytes (a 30 s lead
        # before 1 s dwells held 31x the cache's limit: 12 GB)
        x, y = tr.x_m[idx], tr.y_m[idx]
        if rec.rig is None and _jumps(model):
            acc = [sampled_acceleration(x, tr.ax_m_per_s2[idx], rec.sample_rate_hz),
                   sampled_acceleration(y, tr.ay_m_per_s2[idx], rec.sample_rate_hz)]
        else:
            acc = [tr.ax_m_per_s2[idx], tr.ay_m_per_s2[idx]]
        rows = [x, y, tr.vx_m_per_s[idx], tr.vy_m_per_s[idx], *acc]
        return np.vstack([r[lead:] for r in rows])

    def _periodic_truth(self, model: Model, run: int, a: int, b: int, kp: np.ndarray,
                        visc: np.ndarray) -> np.ndarray | None:
        """The kernel's response (6, b - a) of steady dwell [a, b) after an endless lead of its
        whole periods at its first sample's viscosity, where the model is linear (`periodic`):
        its whole periods from their spectrum where the viscosity holds over the window, the
        rest replayed from their periodic state. None where the model is not linear or the
        force is oversampled for the replay: the lead is replayed."""
        rec = self.records[run]
        if self.oversample.get(run, 1) > 1:
            return None
        fill = self._fill(rec)
        key = (kp.tobytes(), fill, float(visc[0]))
        if key not in self._step_maps:
            if len(self._step_maps) >= 64:
                self._step_maps.clear()
            self._step_maps[key] = step_map(kp, fill, float(visc[0]))
        sm = self._step_maps[key]
        if sm is None:
            return None
        self.simulations += 1
        chunk = self.periodic_chunk(Segment(run, a, b, "", self._freq.get((run, a, b))))
        force = self._window_force(run, a, b, 0)
        offset = np.asarray(model.force_offset_n)
        if any(model.force_offset_n):
            force = force + offset[:, None]
        parts = []
        if np.ptp(visc) == 0.0:
            spectrum = self._spectra.get((run, a, b))
            if spectrum is None:
                spectrum = self._spectra[(run, a, b)] = np.fft.rfft(
                    self._window_force(run, a, b, 0)[:, :chunk], axis=1)
            if any(model.force_offset_n):
                spectrum = spectrum.copy()
                spectrum[:, 0] += chunk * offset
            parts.append(sm.periodic(spectrum, chunk))
        done = chunk if parts else 0
        if done < b - a:
            # the samples after the last whole period, or the whole window where the viscosity
            # changes over it: replayed from the periodic state
            tr, _ = simulate_response(force[:, done:], model.rig, rec.sample_rate_hz, fill,
                                      visc[done:], state=sm.periodic_state(force[:, :chunk]),
                                      kernel=kp)
            parts.append(np.vstack([tr.x_m, tr.y_m, tr.vx_m_per_s, tr.vy_m_per_s,
                                    tr.ax_m_per_s2, tr.ay_m_per_s2]))
        return parts[0] if len(parts) == 1 else np.hstack(parts)

    def _plus_extra_modes(self, model: Model, run: int, a: int, b: int, lead: int,
                          xy: np.ndarray) -> np.ndarray:
        """``xy`` with the response of ``model.extra_modes`` added to their axes' rows, driven
        by the force the kernel saw (oversampled where the kernel's was), from the exact
        periodic steady state of a steady-state dwell's whole periods, else over the whole
        run from its first sample."""
        if not model.extra_modes:
            return xy
        up = self.oversample.get(run, 1)
        shift = 0 if up <= 1 or hasattr(physics, "S_FPX") else -1
        if not lead:
            # not a steady dwell: the extra modes are linear filters of the measured force, so
            # they run over the whole run and are in their true state at a (from rest at a, a
            # lightly damped mode would not forget its start within the kernel's warm-up: 4.3 s
            # for 0.5 % at 7.3 Hz against a warm-up sized for the kernel's mode)
            whole = self._extra_over_run(model, run, up)
            out = xy.copy()
            out += whole[:, np.maximum((a + np.arange(b - a)) * up + shift, 0)]
            return out
        chunk = self.periodic_chunk(Segment(run, a, b, "", self._freq.get((run, a, b))))
        force, first = self._modal_force(run, a, b, up, lead, chunk)
        force = force + np.asarray(model.force_offset_n)[:, None]
        # the run's sample a + i is the force's sample first + (lead + i) * up (where the
        # kernel reports it)
        idx = np.maximum((lead + np.arange(b - a)) * up + shift, 0)
        fs = self.records[run].sample_rate_hz * up
        out = xy.copy()
        for axis in (0, 1):
            modes = [md for md in model.extra_modes if md.axis == axis]
            if modes:
                resp = modal_response(force[axis, first:], fs, modes,
                                      periodic=chunk * up if lead else 0)
                out[axis::2] += resp[:, idx]
        return out

    def _extra_over_run(self, model: Model, run: int, up: int) -> np.ndarray:
        """The extra modes' response (6 rows as the kernel's, oversampled by ``up``) over the
        whole of run ``run``, driven by its measured force plus the model's offset, from rest
        at the run's first sample (as the kernel's first window). Kept for the last few models:
        a fit asks for every window of one model in turn."""
        key = (run, up, model.extra_modes, tuple(model.force_offset_n))
        hit = self._extra_runs.get(key)
        if hit is not None:
            return hit
        force = self._run_force_up.get((run, up))
        if force is None:
            force = self.records[run].force_n
            if up > 1:
                force = resample_poly(force, up, 1, axis=1)
            self._run_force_up[(run, up)] = force
        force = force + np.asarray(model.force_offset_n)[:, None]
        fs = self.records[run].sample_rate_hz * up
        hit = np.zeros((6, force.shape[1]))
        for axis in (0, 1):
            modes = [md for md in model.extra_modes if md.axis == axis]
            if modes:
                hit[axis::2] = modal_response(force[axis], fs, modes)
        if len(self._extra_runs) >= 2 * len(self.records):
            self._extra_runs.clear()
        self._extra_runs[key] = hit
        return hit

    def _modal_force(self, run: int, a: int, b: int, up: int, lead: int,
                     chunk: int) -> tuple[np.ndarray, int]:
        """The force the extra modes are driven by over window [a, b) with its lead, and the
        index of its sample where the lead starts. Oversampled, a steady-state dwell's force
        has one more whole-period chunk before its lead, so the interpolator's start-up
        transient falls there and the chunk the periodic state is taken from is clean."""
        force = self._window_force(run, a, b, lead)
        if up <= 1:
            return force, 0
        if not lead:
            return self._upsampled(run, a, b, up, lead), 0
        key = (run, a, b, lead)
        hit = self._modal_up.get(key)
        if hit is None:
            hit = resample_poly(np.hstack([force[:, :chunk], force]), up, 1, axis=1)
            self._modal_up[key] = hit
        return hit, chunk * up

    def _upsampled(self, run: int, a: int, b: int, up: int, lead: int = 0) -> np.ndarray:
        key = (run, a, b, lead)
        hit = self._up_cache.get(key)
        if hit is None:
            hit = resample_poly(self._window_force(run, a, b, lead), up, 1, axis=1)
            self._up_cache[key] = hit
        return hit

    def predict(self, model: Model, segs: list[Segment]) -> dict[Segment, dict[str, np.ndarray]]:
        """Predicted response channels (without offsets) for each segment [m]."""
        out: dict[Segment, dict[str, np.ndarray]] = {}
        for run, a, b, lst in self.windows(segs, from_run_start=remembers(model)):
            rec = self.records[run]
            xy = self.truth(model, run, a, b)
            chans: dict[str, np.ndarray] = {}
            pge, cde = model.rig.effects.probe_gain_error, model.rig.effects.channel_delay
            for ch, (axis, quantity) in rec.objective_channels().items():
                sig = xy[_ROW[quantity] + axis]
                d = model.delay_s.get(ch, 0.0)
                if cde.enabled and cde.channel == ch:
                    d += cde.delay_s
                if d != 0.0:
                    sig = self._delayed(sig, run, a, b, d)
                g = model.gain.get(ch, 1.0)
                if pge.enabled and pge.channel == ch:
                    g *= pge.gain_ratio
                chans[ch] = sig * g
            for seg in lst:
                i0, i1 = seg.start - a, seg.stop - a
                out[seg] = {ch: v[i0:i1] for ch, v in chans.items()}
        return out

    def _delayed(self, sig: np.ndarray, run: int, a: int, b: int, d: float) -> np.ndarray:
        """``sig`` (window [a, b)) seen ``d`` seconds late: before the window, the rest it
        started from, or, for a dwell replayed in steady state, its own periodic past."""
        fs = self.records[run].sample_rate_hz
        t_win = np.arange(a, b) / fs
        chunk = self.periodic_chunk(Segment(run, a, b, "", self._freq.get((run, a, b))))
        m = int(math.ceil(d * fs)) + 1
        if chunk and m < chunk:
            past = np.concatenate([sig[chunk - m:chunk], sig])
            return np.interp(t_win - d, np.arange(a - m, b) / fs, past)
        return np.interp(t_win - d, t_win, sig, left=0.0)

    def measured(self, seg: Segment) -> dict[str, np.ndarray]:
        rec = self.records[seg.run]
        return {ch: rec.signal(ch)[seg.start:seg.stop] for ch in rec.objective_channels()}


def _jumps(model: Model) -> bool:
    """Whether the kernel's acceleration jumps under ``model``: dry friction switching or
    sticking, where the absolute acceleration is the relative one's (no frame mode)."""
    return _dry_friction(model.rig) and not model.rig.effects.second_mode.enabled


def _dry_friction(rig: RigParams) -> bool:
    """The seal rubs: its friction switches with the velocity and sticks."""
    return rig.seal.enabled and rig.seal.friction_force_n > 0.0


def sampled_acceleration(z: np.ndarray, at_instants: np.ndarray, fs: float) -> np.ndarray:
    """The acceleration a sampled instrument behind its anti-alias filter reads of the
    displacement samples ``z`` (sample rate ``fs``): their fourth-order central second
    difference, whose gain is ``1 - (w / fs)^4 / 90`` (2.6e-4 at a sixteenth of ``fs``, where
    60 Hz's 5X lies at 5 kS/s; 4.2e-3 at an eighth); the two samples at each end, which have
    no neighbours on one side, keep the acceleration at their instants ``at_instants``.

    A displacement is smooth where its acceleration jumps, so its samples hardly alias; the
    second difference then holds only what lies below Nyquist, as the instrument's samples do.
    """
    out = np.array(at_instants, dtype=float, copy=True)
    if z.size >= 5:
        out[2:-2] = (-z[4:] + 16 * z[3:-1] - 30 * z[2:-2] + 16 * z[1:-3] - z[:-4]) * (fs * fs
                                                                                     / 12)
    return out


#: row of `Evaluator.truth` of each quantity's x axis
_ROW = {"displacement": 0, "velocity": 2, "acceleration": 4}


@dataclass
class Residuals:
    """Measured minus predicted, per segment and channel [m], with the offsets applied."""

    per_segment: dict[Segment, dict[str, np.ndarray]]
    predicted: dict[Segment, dict[str, np.ndarray]]
    offsets: dict[tuple[int, str], float]
    weights: dict[str, float] = field(default_factory=dict)  # channel -> factor (absent: 1)

    def sse(self, seg: Segment) -> tuple[float, int]:
        """Weighted sum of squares [m^2] and sample count; inf where a trial model diverged."""
        chans = self.per_segment[seg]
        w = self.weights
        with np.errstate(over="ignore", invalid="ignore"):
            total = float(sum(w.get(ch, 1.0) ** 2 * np.dot(v, v) for ch, v in chans.items()))
        return (total if math.isfinite(total) else math.inf,
                int(sum(v.size for v in chans.values())))

    def rms(self, segs: list[Segment] | None = None) -> float:
        segs = list(self.per_segment) if segs is None else segs
        s = n = 0.0
        for seg in segs:
            a, b = self.sse(seg)
            s += a
            n += b
        return math.sqrt(s / n) if n else float("nan")

    def vector(self, step: int = 1) -> np.ndarray:
        """The weighted residuals of every segment and channel, end to end."""
        w = self.weights
        return np.concatenate([w.get(ch, 1.0) * v[::step] for chans in self.per_segment.values()
                               for ch, v in chans.items()])


#: the start of a run over which its force's level is taken (`Evaluator._memory_start`) [s]
QUIET_S = 0.1
#: how far above that level the force rises where the drive starts
QUIET_FACTOR = 10.0


def remembers(model: Model) -> bool:
    """Whether ``model``'s state depends on its whole history, not on the last ``warmup_s``:
    a sticking seal (its slider's position) or a micro-slipping joint (its force) carries
    the offset of every earlier slip, and a motion smaller than the slip never wipes it out. A
    window replayed from rest a warm-up before a segment misses that offset: replayed with
    the true rig 0.5 s before each held-out dwell, the hidden effects' micro-slip (seed 11)
    left one dwell 4.8x its noise off and a sticking seal (coulomb_friction, seed 21) one 54x
    (from the run's start: 0.75-0.93x)."""
    return bool(_dry_friction(model.rig) or model.rig.effects.joint_microslip.enabled)


def residuals(ev: Evaluator, model: Model, train: list[Segment],
              segs: list[Segment] | None = None,
              offsets: dict[tuple[int, str], float] | None = None) -> Residuals:
    """Residuals on ``segs`` (default: ``train``) with per-channel offsets fitted on ``train``."""
    segs = train if segs is None else segs
    if offsets is None:
        pred_train = ev.predict(model, train)
        acc: dict[tuple[int, str], list[float]] = {}
        for seg, chans in pred_train.items():
            meas = ev.measured(seg)
            for ch, p in chans.items():
                a = acc.setdefault((seg.run, ch), [0.0, 0.0])
                a[0] += float(np.sum(meas[ch] - p))
                a[1] += p.size
        offsets = {k: v[0] / v[1] for k, v in acc.items()}
        pred = pred_train if segs is train else ev.predict(model, segs)
    else:
        pred = ev.predict(model, segs)
    per: dict[Segment, dict[str, np.ndarray]] = {}
    for seg, chans in pred.items():
        meas = ev.measured(seg)
        per[seg] = {ch: meas[ch] - p - offsets.get((seg.run, ch), 0.0)
                    for ch, p in chans.items()}
    return Residuals(per, pred, offsets, ev.weights)
