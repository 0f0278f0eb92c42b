"""Test programmes other than the sine sweep: static load steps, impact capture, eddy-current probe
calibration and a pump pressure ramp. Each streams every block to a sweep listener (contract A),
usually a `storage.RunWriter` of the matching kind, so every analysis runs on real run files.

What the programme cannot do itself is injected, so the same code drives the simulated and the real
rig: ``strike(axis, peak_force_n)`` (an operator with a hammer; in simulation
``RigModel.schedule_impact``), ``reference(axis) -> m`` (a dial gauge; in simulation the true
displacement read to the gauge's resolution) and ``set_supply_pressure(pa)`` (the pump's regulator;
in simulation ``RigParams.oil.supply_pressure_pa``).

Drives always end ramped to zero, whatever happens (the ``finally`` of `_Stream.run_program`).
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from daq.backend import DaqBackend
from storage import RunWriter


class Listener(Protocol):
    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None: ...
    def on_step(self, step: dict) -> None: ...
    def on_event(self, kind: str, message: str, sample: int) -> None: ...


FAULT_RAMP_S = 0.04  # drive fade on a fault [s]


class ProgramError(RuntimeError):
    """A test programme that had to stop: the message says which step and why."""


@dataclass
class ProgramOutcome:
    """What a programme did: steps recorded, and why it stopped if it did not complete."""

    kind: str
    steps: int
    completed: bool
    reason: str = ""
    samples: int = 0
    step_dicts: list[dict[str, Any]] = field(default_factory=list)


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    block_samples: int = Field(
        100, ge=10, le=100_000,
        description="samples per AI/AO block; two blocks are queued ahead, so on a trip the drive "
        "reaches zero within 2 blocks + the 40 ms fault ramp (60 ms at 10 kS/s)",
    )
    ramp_s: float = Field(0.1, gt=0, le=5, description="drive ramp between levels [s]")
    max_force_n: float = Field(448.0, gt=0, description="measured force limit (shaker rating)")


class StaticSpec(_Spec):
    """Static load steps (report IV.1: -89 N to 89 N, each level repeated)."""

    axes: tuple[str, ...] = ("x", "y")
    forces_n: tuple[float, ...] = (-80.0, -40.0, 0.0, 40.0, 80.0)
    repeats: int = Field(3, ge=1, le=20, description="passes over the levels (eq. B.6)")
    settle_s: float = Field(0.3, gt=0, description="hold before recording [s]")
    record_s: float = Field(0.5, gt=0, description="recorded hold [s]")
    corrections: int = Field(2, ge=0, le=10, description="drive corrections toward the force")


class ImpactSpec(_Spec):
    axes: tuple[str, ...] = ("x", "y")
    strikes: int = Field(3, ge=1, le=50, description="strikes per axis (averaged FRF)")
    peak_force_n: float = Field(300.0, gt=0, description="requested hammer peak [N]")
    pretrigger_s: float = Field(0.02, ge=0, description="kept before the trigger [s]")
    window_s: float = Field(1.0, gt=0, description="recorded after the trigger [s]")
    trigger_n: float = Field(10.0, gt=0, description="hammer force that marks a strike [N]")
    wait_s: float = Field(30.0, gt=0, description="longest wait for a strike [s]")
    quiet_s: float = Field(0.3, ge=0, description="free decay allowed between strikes [s]")
    hammer_channel: str = "hammer"


class ProbeCalSpec(_Spec):
    """Static displacement steps read against a reference gauge (Appendix A)."""

    axes: tuple[str, ...] = ("x", "y")
    forces_n: tuple[float, ...] = (-60.0, -40.0, -20.0, 0.0, 20.0, 40.0, 60.0)
    settle_s: float = Field(0.3, gt=0)
    record_s: float = Field(0.3, gt=0)


class FlowSpec(_Spec):
    """Pump on, a ladder of supply pressures, each held and recorded (section V)."""

    supply_pressures_pa: tuple[float, ...] = (8e3, 12e3, 15.5e3, 20e3, 25e3)
    repeats: int = Field(2, ge=1, le=10)
    settle_s: float = Field(3.0, gt=0, description="pressure settling at each level [s]")
    record_s: float = Field(1.0, gt=0)
    pump_relay: str = "pump"


class _Stream:
    """AO written two blocks ahead, AI read block by block, every block passed to the listener.

    The drive is a DC level per shaker that moves by linear ramps; ``level_v`` is the level the
    next written block ends at.
    """

    def __init__(self, backend: DaqBackend, listener: Listener, block: int,
                 max_force_n: float = float("inf")) -> None:
        self.backend = backend
        self.max_force_n = max_force_n
        self.where = ""  # what the programme is doing, for the trip message
        self._fading = False  # set while ramping to zero at the end: no more trips
        self.listener = listener
        self.cm = backend.channel_map
        self.fs = backend.sample_rate_hz
        self.block = block
        self.n_ao = len(self.cm.ao)
        self.level_v = np.zeros(self.n_ao)
        self._written: deque[np.ndarray] = deque()
        self._target: np.ndarray | None = None
        self._rate = np.zeros(self.n_ao)  # ramp rate toward the target [V per sample]
        self.sample = 0  # next AI sample to read
        self._started = False

    def _write(self, target_v: np.ndarray, ramp_samples: int) -> None:
        """Write one block moving linearly toward ``target_v``: a new target sets the rate so
        that the whole change takes ``ramp_samples``; the level then arrives exactly."""
        n = self.block
        target_v = np.asarray(target_v, dtype=float)
        if self._target is None or not np.array_equal(target_v, self._target):
            self._target = target_v.copy()
            self._rate = np.abs(target_v - self.level_v) / max(int(ramp_samples), 1)
        delta = self._target - self.level_v
        k = np.arange(1, n + 1)[None, :]
        moved = np.minimum(self._rate[:, None] * k, np.abs(delta)[:, None])
        blk = self.level_v[:, None] + np.sign(delta)[:, None] * moved
        for row, ch in enumerate(self.cm.ao):
            lo, hi = ch.range_v
            np.clip(blk[row], lo, hi, out=blk[row])
        self.backend.write_ao(blk)
        self._written.append(blk)
        self.level_v = blk[:, -1].copy()

    def start(self) -> None:
        for _ in range(2):
            self._write(self.level_v, 1)
        self.backend.start()
        self._started = True

    def step(self, target_v: np.ndarray, ramp_s: float) -> np.ndarray:
        """Write one block moving toward ``target_v``, read one block; AI in engineering units."""
        remaining = np.max(np.abs(target_v - self.level_v)) if self.n_ao else 0.0
        ramp = int(ramp_s * self.fs) if remaining > 0 else 1
        self._write(target_v, ramp)
        volts = self.backend.read_ai(self.block)
        ai = self.cm.to_engineering(volts)
        ao = self._written.popleft()
        self.listener.on_block(self.sample, ai, ao)
        self.sample += self.block
        if not self._fading:
            self._check_force(ai)  # every block: a trip is seen within one block
        return ai

    def _check_force(self, ai: np.ndarray) -> None:
        for name in ("fx", "fy"):
            if name in self.cm.ai_names:
                peak = float(np.max(np.abs(_ai(self.cm, ai, name))))
                if peak > self.max_force_n:
                    raise ProgramError(f"{self.where or 'programme'}: {name} reached "
                                       f"{peak:.1f} N, over the {self.max_force_n:g} N limit")

    def hold(self, target_v: np.ndarray, seconds: float, ramp_s: float) -> tuple[int, np.ndarray]:
        """Hold ``target_v`` for ``seconds``; returns (first sample, AI (n_ai, n)).

        The blocks already queued (written before this call) and the ramp are let out first, so
        every returned sample was generated at the target level.
        """
        lead = len(self._written) + int(np.ceil(ramp_s * self.fs / self.block))
        if np.max(np.abs(target_v - self.level_v), initial=0.0) > 0 or lead:
            for _ in range(lead):
                self.step(target_v, ramp_s)
        first = self.sample
        n_blocks = max(int(np.ceil(seconds * self.fs / self.block)), 1)
        blocks = [self.step(target_v, ramp_s) for _ in range(n_blocks)]
        return first, np.concatenate(blocks, axis=1)

    def finish(self, ramp_s: float) -> None:
        """Ramp to zero, let the queued blocks out, stop (always called)."""
        if not self._started:
            return
        zero = np.zeros(self.n_ao)
        self._fading = True
        try:
            n_blocks = int(np.ceil(ramp_s * self.fs / self.block)) + 3
            for _ in range(n_blocks):
                self.step(zero, ramp_s)
        finally:
            self.backend.stop()


def _ai(cm: Any, ai: np.ndarray, name: str) -> np.ndarray:
    return ai[cm.ai_index(name)]


def _signal(cm: Any, ai: np.ndarray, name: str) -> np.ndarray:
    """Canonical signal from a block: the channel, or the mean of probes x1, x2..."""
    if name in cm.ai_names:
        return _ai(cm, ai, name)
    rows = [i for i, n in enumerate(cm.ai_names) if n.startswith(name) and n[len(name):].isdigit()]
    if not rows:
        raise ProgramError(f"no channel or probes for signal {name!r} (have {cm.ai_names})")
    return ai[rows].mean(axis=0)


def _step_dict(index: int, target_kind: str, target_value: float, motion: str, first: int,
               last: int, updates: int = 0, converged: bool = True, reason: str = "",
               **extra: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "index": index, "freq_hz": 0.0, "target_kind": target_kind,
        "target_value": float(target_value), "motion": motion, "first_sample": int(first),
        "last_sample": int(last), "updates": int(updates), "converged": bool(converged),
        "reason": reason, "harmonics": {}, "drive_v": {},
    }
    d.update(extra)
    return d


def _run(kind: str, backend: DaqBackend, listener: Listener, spec: _Spec,
         body: Callable[[_Stream, list[dict[str, Any]]], None]) -> ProgramOutcome:
    stream = _Stream(backend, listener, spec.block_samples, spec.max_force_n)
    steps: list[dict[str, Any]] = []
    listener.on_event("state", f"{kind} programme started: {spec.model_dump_json()}", 0)
    outcome = ProgramOutcome(kind, 0, True)
    clean = False
    try:
        stream.start()
        body(stream, steps)
        clean = True
    except ProgramError as err:
        outcome.completed, outcome.reason = False, str(err)
        listener.on_event("abort", str(err), stream.sample)
    finally:
        # a fault (ProgramError or anything unexpected) fades the drives fast
        stream.finish(spec.ramp_s if clean else FAULT_RAMP_S)
    state = "completed" if outcome.completed else "aborted"
    listener.on_event("state", f"{kind} programme {state}", stream.sample)
    outcome.steps, outcome.samples, outcome.step_dicts = len(steps), stream.sample, steps
    return outcome


def _drive_for(cm: Any, axis: str, force_n: float, gain: Mapping[str, float]) -> np.ndarray:
    v = np.zeros(len(cm.ao))
    v[cm.ao_for_axis(axis)] = force_n / gain[axis]
    return v


def _static_levels(stream: _Stream, steps: list[dict[str, Any]], spec: StaticSpec | ProbeCalSpec,
                   passes: int, kind: str, target_kind: str,
                   after_hold: Callable[[str, float], dict[str, Any]] | None = None) -> None:
    """Shared by the static and the calibration programmes: hold DC forces, record each."""
    cm = stream.cm
    gain = {ao.axis: ao.nominal_force_n_per_v for ao in cm.ao}
    for axis in spec.axes:
        for p in range(passes):
            for force in spec.forces_n:
                where = f"{kind} step {len(steps)} ({axis}, {force:g} N, pass {p + 1})"
                stream.where = where
                drive = _drive_for(cm, axis, force, gain)
                _, ai = stream.hold(drive, spec.settle_s, spec.ramp_s)
                updates = 0
                corrections = getattr(spec, "corrections", 1)
                for _ in range(corrections):
                    measured = float(np.mean(_signal(cm, ai, "f" + axis)[-stream.block:]))
                    if abs(force) < 1e-9 or abs(measured - force) < 0.005 * max(abs(force), 1):
                        break
                    drive = drive + _drive_for(cm, axis, force - measured, gain)
                    _, ai = stream.hold(drive, spec.settle_s, spec.ramp_s)
                    updates += 1
                first, ai = stream.hold(drive, spec.record_s, spec.ramp_s)
                extra = after_hold(axis, force) if after_hold else {}
                value = extra.pop("target_value", force)
                step = _step_dict(len(steps), target_kind, value, axis, first, stream.sample,
                                  updates, force_n=force, **extra)
                stream.listener.on_step(step)
                steps.append(step)


def run_static_test(backend: DaqBackend, listener: Listener,
                    spec: StaticSpec | None = None) -> ProgramOutcome:
    """Static load steps per axis: DC force levels, each held and recorded, ``repeats`` passes.

    Each step: ``target_kind="load"``, ``target_value`` the force asked [N], ``motion`` the axis,
    ``freq_hz=0``; the analysis uses the measured means over the span.
    """
    spec = spec or StaticSpec()

    def body(stream: _Stream, steps: list[dict[str, Any]]) -> None:
        _static_levels(stream, steps, spec, spec.repeats, "static", "load")

    return _run("static", backend, listener, spec, body)


def run_probe_calibration(backend: DaqBackend, listener: Listener,
                          reference: Callable[[str], float],
                          spec: ProbeCalSpec | None = None) -> ProgramOutcome:
    """Static displacement steps, each read by the reference gauge ``reference(axis) -> m``.

    Each step: ``target_kind="displacement"``, ``target_value`` = ``reference_m`` = the gauge
    reading [m] taken at the end of the recorded hold.
    """
    spec = spec or ProbeCalSpec()

    def read(axis: str, force: float) -> dict[str, Any]:
        ref = float(reference(axis))
        return {"target_value": ref, "reference_m": ref}

    def body(stream: _Stream, steps: list[dict[str, Any]]) -> None:
        _static_levels(stream, steps, spec, 1, "probe_calibration", "displacement", read)

    return _run("probe_calibration", backend, listener, spec, body)


def run_impact_test(backend: DaqBackend, listener: Listener,
                    strike: Callable[[str, float], None],
                    spec: ImpactSpec | None = None) -> ProgramOutcome:
    """Strike each axis ``strikes`` times; record the pulse and the free decay of each.

    The strike is found on the hammer channel (first sample over ``trigger_n``), so an operator's
    strike at any moment is captured the same way as the simulator's. Each step: ``motion`` the
    axis, ``target_kind="load"``, ``target_value`` the measured peak [N], span from
    ``pretrigger_s`` before the trigger to ``window_s`` after.
    """
    spec = spec or ImpactSpec()

    def body(stream: _Stream, steps: list[dict[str, Any]]) -> None:
        cm = stream.cm
        if spec.hammer_channel not in cm.ai_names:
            raise ProgramError(f"impact: no hammer channel {spec.hammer_channel!r} in the "
                               f"channel map ({cm.ai_names})")
        zero = np.zeros(stream.n_ao)
        pre = int(spec.pretrigger_s * stream.fs)
        post = int(spec.window_s * stream.fs)
        for axis in spec.axes:
            for k in range(spec.strikes):
                q_first, q_ai = stream.hold(zero, spec.quiet_s, spec.ramp_s)
                hist: deque[tuple[int, np.ndarray]] = deque(maxlen=pre // stream.block + 2)
                for k0 in range(0, q_ai.shape[1], stream.block):  # pre-trigger history
                    hist.append((q_first + k0, q_ai[:, k0:k0 + stream.block]))
                strike(axis, spec.peak_force_n)
                trig = None
                waited = 0
                while trig is None:
                    first = stream.sample
                    ai = stream.step(zero, spec.ramp_s)
                    hist.append((first, ai))
                    hit = np.nonzero(_ai(cm, ai, spec.hammer_channel) > spec.trigger_n)[0]
                    if hit.size:
                        trig = first + int(hit[0])
                    waited += stream.block
                    if trig is None and waited > spec.wait_s * stream.fs:
                        raise ProgramError(f"impact step {len(steps)} ({axis}, strike {k + 1}):"
                                           f" no strike over {spec.trigger_n:g} N on "
                                           f"{spec.hammer_channel} within {spec.wait_s:g} s")
                h = _ai(cm, hist[-1][1], spec.hammer_channel)
                peak = float(np.max(h))
                while stream.sample < trig + post:
                    ai = stream.step(zero, spec.ramp_s)
                    peak = max(peak, float(np.max(_ai(cm, ai, spec.hammer_channel))))
                start = max(trig - pre, hist[0][0])
                step = _step_dict(len(steps), "load", peak, axis, start, trig + post,
                                  trigger_sample=trig)
                stream.listener.on_step(step)
                steps.append(step)

    return _run("impact", backend, listener, spec, body)


def run_flow_test(backend: DaqBackend, listener: Listener,
                  set_supply_pressure: Callable[[float], None],
                  spec: FlowSpec | None = None) -> ProgramOutcome:
    """Pump on; for each supply pressure: set it, settle, record p_in, p_rec, q_in, t_oil.

    Each step: ``target_kind="pressure"``, ``target_value`` = ``supply_pressure_pa`` [Pa],
    ``freq_hz=0``, no motion. The pump is switched off at the end (shakers are at rest).
    """
    spec = spec or FlowSpec()

    def body(stream: _Stream, steps: list[dict[str, Any]]) -> None:
        zero = np.zeros(stream.n_ao)
        backend.set_do(spec.pump_relay, True)
        listener.on_event("pump", "pump on", stream.sample)
        try:
            for p in range(spec.repeats):
                for pa in spec.supply_pressures_pa:
                    set_supply_pressure(pa)
                    listener.on_event("operator", f"supply pressure set to {pa:g} Pa (pass "
                                      f"{p + 1})", stream.sample)
                    stream.hold(zero, spec.settle_s, spec.ramp_s)
                    first, _ = stream.hold(zero, spec.record_s, spec.ramp_s)
                    step = _step_dict(len(steps), "pressure", pa, "", first, stream.sample,
                                      supply_pressure_pa=pa)
                    listener.on_step(step)
                    steps.append(step)
        finally:
            backend.set_do(spec.pump_relay, False)
            listener.on_event("pump", "pump off", stream.sample)

    return _run("flow", backend, listener, spec, body)


def create_run_writer(path: str | Path, kind: str, backend: DaqBackend, *, run_id: str,
                      rig_config: Any = None, test_spec: Any = None, lubricated: bool = False,
                      operator: str = "", notes: str = "", overwrite: bool = False) -> RunWriter:
    """A `RunWriter` for ``backend``'s channel map (AI and AO metadata from the map)."""
    cm = backend.channel_map
    cmd = cm.to_json_dict()
    spec_json = test_spec.model_dump(mode="json") if hasattr(test_spec, "model_dump") else test_spec
    return RunWriter.create(
        path, run_id, kind, cmd["ai"], [ao.name for ao in cm.ao], cm.sample_rate_hz,
        operator=operator, notes=notes, channel_map=json.dumps(cmd), rig_config=rig_config,
        test_spec=spec_json, lubricated=lubricated, overwrite=overwrite,
    )


__all__: Sequence[str] = [
    "FlowSpec", "ImpactSpec", "ProbeCalSpec", "ProgramError", "ProgramOutcome", "StaticSpec",
    "create_run_writer", "run_flow_test", "run_impact_test", "run_probe_calibration",
    "run_static_test",
]
