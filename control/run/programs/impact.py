"""The impact test as modal-test software runs it.

Per axis, until ``strikes`` hits are accepted: wait for the housing to come to rest, arm the
acquisition on the hammer channel (level and slope, with a pre-trigger), ask the operator to
strike, take a fixed record from ``pretrigger_s`` before the trigger to ``window_s`` after it,
reject it automatically for an overload (a channel at its input range) or a double hit (a second
pulse after the hammer left the structure), and otherwise show the hit and the averaged H1
estimate with its coherence and let the operator accept or reject it. Every hit is a step of the
run (``accepted``, ``rejection``), so the per-hit data stay in the file; the analysis averages the
accepted ones (`analysis.structure.identify_impact`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from control.run.listener import Listener
from control.run.programs.operator import OperatorDesk, Question
from control.run.programs.specs import ImpactSpec
from control.run.programs.stream import (
    ProgramError,
    ProgramOutcome,
    RigHands,
    Stream,
    ai_row,
    ask,
    journal_out,
    point_step,
    run_program,
    signal,
)
from daq.backend import DaqBackend
from daq.channels import ChannelMap
from storage.records import JsonValue, StepRecord

REST_DISPLACEMENT_M = 5e-6  # peak-to-peak over 0.1 s below which the housing is at rest
REST_TIMEOUT_S = 20.0
BAND_HZ = (5.0, 150.0)  # where the coherence is shown


@dataclass
class HitCheck:
    """One recorded hit: its hammer peak [N], pulse width [s] and why it was rejected ("")."""

    peak_n: float
    pulse_s: float
    rejection: str


def input_limits(cm: ChannelMap) -> dict[str, tuple[float, float]]:
    """Each AI channel's input range in engineering units."""
    out = {}
    for ch in cm.ai:
        lo, hi = ((v - ch.offset_v) / ch.gain_v_per_unit for v in ch.range_v)
        out[ch.name] = (min(lo, hi), max(lo, hi))
    return out


def check_hit(cm: ChannelMap, record: np.ndarray, pre: int, fs: float,
              spec: ImpactSpec) -> HitCheck:
    """Overload and double-hit checks of one record (AI rows, trigger at column ``pre``)."""
    h = ai_row(cm, record, spec.hammer_channel)
    h = h if spec.slope == "rising" else -h
    after = h[pre:]
    k_peak = int(np.argmax(after))
    peak = float(after[k_peak])
    threshold = spec.double_hit_fraction * peak
    above = after > threshold
    end = k_peak + int(np.argmax(~above[k_peak:])) if not above[k_peak:].all() else after.size
    start = k_peak - int(np.argmax(~above[k_peak::-1])) if not above[:k_peak + 1].all() else 0
    pulse_s = (end - start) / fs
    limits = input_limits(cm)
    over = []
    for i, name in enumerate(cm.ai_names):
        lo, hi = limits[name]
        x = record[i]
        worst = float(np.max(x)) if np.max(x) >= -np.min(x) else float(np.min(x))
        bound = hi if worst >= 0 else lo
        if bound != 0 and worst / bound >= spec.overload_fraction:
            over.append((name != spec.hammer_channel, f"{name} reached {worst:.4g} "
                         f"{cm.ai[i].units}, {100 * worst / bound:.0f} % of its input range"))
    if over:
        return HitCheck(peak, pulse_s, "overload: " + "; ".join(t for _, t in sorted(over)))
    later = np.nonzero(above[end:])[0]
    if later.size:
        k2 = end + int(later[0])
        peak2 = float(np.max(after[k2:]))
        return HitCheck(peak, pulse_s, f"double hit: a second pulse of {peak2:.0f} N "
                        f"{(k2 - start) / fs * 1e3:.0f} ms after the first ({peak:.0f} N)")
    return HitCheck(peak, pulse_s, "")


def h1_coherence(hits: list[tuple[np.ndarray, np.ndarray]], fs: float,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(freq [Hz], H1 = S_xf / S_ff [m/N], coherence |S_xf|^2 / (S_ff S_xx)) over the hits
    (force, response), each record's mean before the strike removed."""
    n = min(f.size for f, _ in hits)
    sxf: np.ndarray = np.zeros(n // 2 + 1, complex)
    sff: np.ndarray = np.zeros(n // 2 + 1)
    sxx: np.ndarray = np.zeros(n // 2 + 1)
    for f, x in hits:
        ff = np.fft.rfft(f[:n] - np.median(f[:n]))
        xx = np.fft.rfft(x[:n] - np.mean(x[: max(n // 50, 2)]))
        sxf += xx * np.conj(ff)
        sff += np.abs(ff) ** 2
        sxx += np.abs(xx) ** 2
    freq = np.fft.rfftfreq(n, 1.0 / fs)
    with np.errstate(invalid="ignore", divide="ignore"):
        return freq, sxf / sff, np.abs(sxf) ** 2 / (sff * sxx)


def describe_average(hits: list[tuple[np.ndarray, np.ndarray]], fs: float) -> str:
    """One line on the averaged FRF: its peak and the coherence in the band."""
    freq, h1, coh = h1_coherence(hits, fs)
    band = (freq >= BAND_HZ[0]) & (freq <= BAND_HZ[1])
    f_peak = float(freq[band][np.argmax(np.abs(h1[band]))])
    text = f"H1 of {len(hits)} hit(s): peak at {f_peak:.1f} Hz"
    if len(hits) > 1:
        c = coh[band]
        text += (f"; coherence {BAND_HZ[0]:g}-{BAND_HZ[1]:g} Hz: mean {float(np.mean(c)):.3f}, "
                 f"min {float(np.min(c)):.3f} at {float(freq[band][np.argmin(c)]):.1f} Hz")
    return text


def run_impact_test(backend: DaqBackend, listener: Listener, operator: OperatorDesk,
                    spec: ImpactSpec | None = None, *,
                    hands: RigHands | None = None) -> ProgramOutcome:
    """Impact test of each axis (see the module's description); ``operator`` an `OperatorDesk`.

    Each step is one hit: ``motion`` the axis, ``target_kind="load"``, ``target_value`` the
    hammer peak [N], span the fixed record, ``trigger_sample``, ``accepted``, ``rejection``,
    ``hit`` (its number on the axis), ``pulse_ms``.
    """
    spec = spec or ImpactSpec()

    def body(stream: Stream, steps: list[StepRecord]) -> None:
        cm = stream.cm
        if spec.hammer_channel not in cm.ai_names:
            raise ProgramError(f"impact: no hammer channel {spec.hammer_channel!r} in the "
                               f"channel map ({cm.ai_names})")
        journal_out(stream, hands, "impact", "hammer")
        for axis in spec.axes:
            _impact_axis(stream, steps, spec, axis, hands)

    return run_program("impact", backend, listener, spec, body, operator)


def _wait_at_rest(stream: Stream, axis: str, spec: ImpactSpec,
                  history: deque[tuple[int, np.ndarray]]) -> None:
    zero = np.zeros(stream.n_ao)
    window = max(int(0.1 * stream.fs / stream.block), 1)
    recent: deque[np.ndarray] = deque(maxlen=window)
    waited = 0
    while True:
        first = stream.sample
        ai = stream.step(zero, spec.ramp_s)
        history.append((first, ai))
        recent.append(signal(stream.cm, ai, axis))
        waited += stream.block
        if waited < spec.quiet_s * stream.fs or len(recent) < window:
            continue
        z = np.concatenate(recent)
        if float(np.ptp(z)) < REST_DISPLACEMENT_M or waited > REST_TIMEOUT_S * stream.fs:
            return


class _Armed:
    """The armed acquisition: sees every block, keeps the pre-trigger history, finds the first
    crossing of the trigger level with the set slope (also across block boundaries)."""

    def __init__(self, stream: Stream, spec: ImpactSpec,
                 history: deque[tuple[int, np.ndarray]]) -> None:
        self.stream, self.spec, self.history = stream, spec, history
        self.sign = 1.0 if spec.slope == "rising" else -1.0
        self.prev = float(self.sign * ai_row(stream.cm, history[-1][1], spec.hammer_channel)[-1])
        self.waited = 0
        self.trigger = -1

    def __call__(self, first: int, ai: np.ndarray) -> bool:
        spec = self.spec
        self.history.append((first, ai))
        h = self.sign * ai_row(self.stream.cm, ai, spec.hammer_channel)
        before = np.concatenate([[self.prev], h[:-1]])
        self.prev = float(h[-1])
        cross = np.nonzero((before < spec.trigger_n) & (h >= spec.trigger_n))[0]
        if cross.size:
            self.trigger = first + int(cross[0])
            return True
        self.waited += ai.shape[1]
        if self.waited > spec.wait_s * self.stream.fs:
            raise ProgramError(f"{self.stream.where}: no strike over {spec.trigger_n:g} N "
                               f"({spec.slope}) on {spec.hammer_channel} within "
                               f"{spec.wait_s:g} s")
        return False


def _impact_axis(stream: Stream, steps: list[StepRecord], spec: ImpactSpec, axis: str,
                 hands: RigHands | None) -> None:
    cm, fs = stream.cm, stream.fs
    zero = np.zeros(stream.n_ao)
    pre = int(round(spec.pretrigger_s * fs))
    post = int(round(spec.window_s * fs))
    accepted: list[tuple[np.ndarray, np.ndarray]] = []
    last_news = ""
    for hit in range(1, spec.max_hits + 1):
        if len(accepted) >= spec.strikes:
            return
        label = f"impact {axis} hit {hit} ({len(accepted)} of {spec.strikes} accepted)"
        stream.where = f"impact step {len(steps) + 1} ({axis}, hit {hit})"
        history: deque[tuple[int, np.ndarray]] = deque(maxlen=pre // stream.block + 3)
        _wait_at_rest(stream, axis, spec, history)
        armed = _Armed(stream, spec, history)
        choices = ["ok", "double", "overload", "skip", "abort"] if hands is not None \
            else ["skip", "abort"]
        info = [f"armed: {spec.hammer_channel} {spec.slope} through {spec.trigger_n:g} N, "
                f"{spec.pretrigger_s * 1e3:g} ms pre-trigger, {spec.window_s:g} s record"]
        if last_news:
            info.append(last_news)
        answer = ask(stream, Question(
            id=0, where=label, choices=choices, trigger=True, info=info,
            prompt=f"Strike the housing along {axis} with the hammer (about "
                   f"{spec.peak_force_n:g} N)" + (": on the simulated rig 'ok' strikes, "
                                                  "'double' and 'overload' make a bad hit"
                                                  if hands is not None else "")),
            zero, spec.ramp_s, armed)
        if answer is not None:
            if answer.choice == "skip":
                stream.listener.on_event("operator", f"impact {axis}: rest of the axis skipped "
                                         f"with {len(accepted)} accepted hit(s)", stream.sample)
                return
            assert hands is not None
            hands.strike(axis, spec.peak_force_n, answer.choice)
            while not armed(stream.sample, stream.step(zero, spec.ramp_s)):
                pass
        t = armed.trigger
        blocks = [b for _, b in history]  # the pre-trigger history ends with the trigger
        h0 = history[0][0]
        while stream.sample < t + post:
            blocks.append(stream.step(zero, spec.ramp_s))
        record_all = np.concatenate(blocks, axis=1)
        start = max(t - pre, h0)
        record = record_all[:, start - h0:t + post - h0]
        check = check_hit(cm, record, t - start, fs, spec)
        base: dict[str, JsonValue] = {"trigger_sample": t, "hit": hit,
                                "pulse_ms": round(check.pulse_s * 1e3, 3)}
        force, resp = ai_row(cm, record, spec.hammer_channel), signal(cm, record, axis)
        if check.rejection:
            decision, why = False, check.rejection
        else:
            trial = [*accepted, (force, resp)]
            review = ask(stream, Question(
                id=0, where=label, choices=["ok", "reject", "abort"],
                prompt=f"Hit {hit} on {axis}: accept it into the average?",
                info=[f"peak {check.peak_n:.0f} N, pulse {check.pulse_s * 1e3:.1f} ms",
                      "with it, " + describe_average(trial, fs)]), zero, spec.ramp_s)
            assert review is not None
            decision = review.choice == "ok"
            why = "" if decision else "rejected by the operator"
        step = point_step(len(steps), "load", check.peak_n, axis, start, t + post,
                          extra={**base, "accepted": decision, "rejection": why})
        stream.listener.on_step(step)
        steps.append(step)
        if decision:
            accepted.append((force, resp))
            last_news = f"hit {hit} accepted; " + describe_average(accepted, fs)
        else:
            last_news = f"hit {hit} rejected: {why}"
            stream.listener.on_event("operator", f"impact {axis} hit {hit} rejected: {why}",
                                     stream.sample)
    if len(accepted) < spec.strikes:
        raise ProgramError(f"impact {axis}: {len(accepted)} of {spec.strikes} hits accepted "
                           f"after {spec.max_hits} hits")


__all__ = ["HitCheck", "check_hit", "describe_average", "h1_coherence", "input_limits",
           "run_impact_test"]
