"""Test programmes other than the sine sweep: static load steps, eddy-current probe calibration and
a pump pressure ramp (the impact test is `control.run.programs.impact`). Each streams every block
to a listener
(contract A), usually a `storage.RunWriter` of the matching kind, so every analysis runs on real
run files.

A person is in the loop through an `control.run.programs.operator.OperatorDesk`: the programme asks
(take the
journal out, accept this steady point, read the dial gauge, set this pressure) and keeps the DAQ
streaming while it waits; the answer may repeat or skip a point or abort the programme (the drives
fade, the run keeps the points so far). What the person's hands do that the simulated rig must do
in software is the optional ``hands`` (`RigHands`), given only for the simulated rig. Points are
recorded only when their signals are steady (`program_stream.hold_steady`).

Drives always end ramped to zero, whatever happens (`program_stream.run_program`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from control.run.listener import Listener
from control.run.programs.impact import run_impact_test
from control.run.programs.operator import Entry, OperatorDesk, Question
from control.run.programs.specs import FlowSpec, ImpactSpec, ProbeCalSpec, StaticSpec
from control.run.programs.static_by_hand import static_levels_by_hand
from control.run.programs.stream import (
    ProgramError,
    ProgramOutcome,
    RigHands,
    Steadiness,
    Stream,
    ask,
    ask_unsteady,
    hold_steady,
    journal_out,
    point_step,
    run_program,
    signal,
)
from daq.backend import DaqBackend
from daq.channels import ChannelMap
from storage.records import JsonValue, StepRecord

DIAL_GAUGE_RANGE_M = 2.5e-3  # a dial gauge reading beyond +/-0.1 in is a typing error here
SUPPLY_PRESSURE_RANGE_PA = (0.0, 500e3)  # the regulator's gauge


#: what a held point adds: its target value and further keys
Held = tuple[float, dict[str, JsonValue]]
AfterHold = Callable[[str, float, str], "Held | str | None"]


def _drive_for(cm: ChannelMap, axis: str, force_n: float, gain: Mapping[str, float]) -> np.ndarray:
    v = np.zeros(len(cm.ao))
    v[cm.ao_for_axis(axis)] = force_n / gain[axis]
    return v


def _static_levels(stream: Stream, steps: list[StepRecord], spec: StaticSpec | ProbeCalSpec,
                   passes: int, kind: str, target_kind: str,
                   after_hold: AfterHold | None = None) -> None:
    """Shared by the static and the calibration programmes: hold DC forces, record each once
    steady; ``after_hold(axis, force, label)`` gives the step's target value and further keys,
    or says "repeat" or None (skip the point)."""
    cm = stream.cm
    gain = {ao.axis: ao.nominal_force_n_per_v for ao in cm.ao}
    n_points = len(spec.axes) * passes * len(spec.forces_n)
    for axis in spec.axes:
        checks = [Steadiness("f" + axis, spec.steady_force_n),
                  Steadiness(axis, spec.steady_displacement_m)]
        for p in range(passes):
            for force in spec.forces_n:
                point = len(steps) + 1
                while True:  # until recorded or skipped
                    where = f"{kind} step {len(steps) + 1} ({axis}, {force:g} N, pass {p + 1})"
                    stream.where = where
                    step = _one_level(stream, spec, axis, force, gain, checks, where,
                                      f"{kind} {axis} {force:+g} N pass {p + 1}, point "
                                      f"{point}/{n_points}", after_hold, target_kind, steps)
                    if step != "repeat":
                        break
                if isinstance(step, StepRecord):
                    stream.listener.on_step(step)
                    steps.append(step)


def _one_level(stream: Stream, spec: StaticSpec | ProbeCalSpec, axis: str, force: float,
               gain: Mapping[str, float], checks: list[Steadiness], where: str, label: str,
               after_hold: AfterHold | None,
               target_kind: str, steps: list[StepRecord]) -> StepRecord | str:
    """One static point: the step dict, "repeat" or "skip"."""
    cm = stream.cm
    drive = _drive_for(cm, axis, force, gain)
    _, ai = stream.hold(drive, spec.settle_s, spec.ramp_s)
    updates = 0
    corrections = getattr(spec, "corrections", 1)
    for _ in range(corrections):
        measured = float(np.mean(signal(cm, ai, "f" + axis)[-stream.block:]))
        if abs(force) < 1e-9 or abs(measured - force) < 0.005 * max(abs(force), 1):
            break
        drive = drive + _drive_for(cm, axis, force - measured, gain)
        _, ai = stream.hold(drive, spec.settle_s, spec.ramp_s)
        updates += 1
    first, ai, moving = hold_steady(stream, drive, spec.record_s, spec.ramp_s, checks,
                                    spec.steady_timeout_s)
    f_mean = float(signal(cm, ai, "f" + axis).mean())
    d_mean = float(signal(cm, ai, axis).mean())
    measured_text = (f"load cell f{axis} {f_mean:+.2f} N, probes {axis} {d_mean * 1e6:+.2f} um "
                     f"over {spec.record_s:g} s")
    if moving:
        if stream.operator is None:
            raise ProgramError(f"{where}: not steady within {spec.steady_timeout_s:g} s: "
                               f"{moving}")
        return ask_unsteady(stream, label, moving, spec.steady_timeout_s, drive, spec.ramp_s,
                            [measured_text])
    last = stream.sample
    held = after_hold(axis, force, label) if after_hold else (force, {})
    if held is None:
        return "skip"
    if isinstance(held, str):
        return held
    value, extra = held
    if after_hold is None and stream.operator is not None and spec.confirm_points:
        answer = ask(stream, Question(
            id=0, where=label, prompt=f"Load {force:+g} N along {axis} held by the shaker, "
                                      "steady: accept this point?",
            info=[measured_text]), drive, spec.ramp_s)
        assert answer is not None
        if answer.choice != "ok":
            return answer.choice
    return point_step(len(steps), target_kind, value, axis, first, last, updates,
                      extra={"force_n": force, **extra})


def run_static_test(backend: DaqBackend, listener: Listener, spec: StaticSpec | None = None, *,
                    operator: OperatorDesk | None = None,
                    hands: RigHands | None = None) -> ProgramOutcome:
    """Static load steps per axis: DC force levels, each held and recorded once steady,
    ``repeats`` passes. Without an operator every steady point is kept (unattended).
    ``spec.load_by="hand"``: the operator pushes with a force gauge instead of the shakers
    (`control.run.programs.static_by_hand`; an operator is needed).

    Each step: ``target_kind="load"``, ``target_value`` the force asked [N], ``motion`` the axis,
    ``freq_hz=0``; the analysis uses the measured means over the span.
    """
    spec = spec or StaticSpec()

    def body(stream: Stream, steps: list[StepRecord]) -> None:
        journal_out(stream, hands, "static",
                    "hand" if spec.load_by == "hand" else "shakers")
        if spec.load_by == "hand":
            static_levels_by_hand(stream, steps, spec, hands)
        else:
            _static_levels(stream, steps, spec, spec.repeats, "static", "load")

    return run_program("static", backend, listener, spec, body, operator)


def run_probe_calibration(backend: DaqBackend, listener: Listener, operator: OperatorDesk,
                          spec: ProbeCalSpec | None = None, *,
                          hands: RigHands | None = None) -> ProgramOutcome:
    """Static displacement steps (the shaker moves the housing), each read by the operator on
    the dial gauge once the probes are steady (Appendix A).

    Each step: ``target_kind="displacement"``, ``target_value`` = ``reference_m`` = the gauge
    reading typed [m].
    """
    spec = spec or ProbeCalSpec()
    gauge_unit = spec.gauge_unit

    def read(axis: str, force: float, label: str) -> Held | str | None:
        stream = current[0]
        hold = stream.level_v.copy()
        k_nominal = 800e3  # only to say roughly where the housing is [N/m]
        entry = Entry(name="gauge", label=f"dial gauge {axis}", quantity="length",
                      unit=gauge_unit, min_si=-DIAL_GAUGE_RANGE_M, max_si=DIAL_GAUGE_RANGE_M)
        shows = ""
        if hands is not None:
            shows = entry.show(hands.gauge_reading_m(axis))
        z = float(signal(stream.cm, stream.last_ai, axis).mean())
        answer = ask(stream, Question(
            id=0, where=label, entry=entry, shows=shows,
            prompt=f"The shaker holds the housing about {force / k_nominal * 1e6:+.0f} um along "
                   f"{axis}, probes steady: read the dial gauge on {axis} and type it",
            info=[f"probes {axis} {z * 1e6:+.2f} um"]), hold, spec.ramp_s)
        assert answer is not None
        if answer.choice != "ok":
            return None if answer.choice == "skip" else answer.choice  # "repeat"
        assert answer.value_si is not None
        return answer.value_si, {"reference_m": answer.value_si, "gauge_text": answer.text}

    current: list[Stream] = []

    def body(stream: Stream, steps: list[StepRecord]) -> None:
        current.append(stream)
        journal_out(stream, hands, "probe_calibration", "shakers")
        _static_levels(stream, steps, spec, 1, "probe_calibration", "displacement",
                       read)

    return run_program("probe_calibration", backend, listener, spec, body, operator)


def run_flow_test(backend: DaqBackend, listener: Listener, operator: OperatorDesk,
                  spec: FlowSpec | None = None, *, hands: RigHands | None = None,
                  set_pump: Callable[[bool], None] | None = None) -> ProgramOutcome:
    """Pump on; for each supply pressure: the operator sets it and types the regulator's
    reading, the inlet pressure settles, p_in, p_rec, q_in, t_oil are recorded once steady.

    Each step: ``target_kind="pressure"``, ``target_value`` = ``supply_pressure_pa`` = the
    setting typed [Pa], ``freq_hz=0``, no motion. The pump is switched off at the end, also on
    an abort (shakers at rest throughout).
    """
    spec = spec or FlowSpec()
    pump = set_pump or (lambda on: backend.set_do(spec.pump_relay, on))

    def point(stream: Stream, n_steps: int, pa: float, label: str) -> StepRecord | str:
        """One pressure: the step dict, "repeat" or "skip"."""
        zero = np.zeros(stream.n_ao)
        entry = Entry(name="pressure", label="supply pressure", unit="kPa", quantity="pressure",
                      min_si=SUPPLY_PRESSURE_RANGE_PA[0], max_si=SUPPLY_PRESSURE_RANGE_PA[1])
        answer = ask(stream, Question(
            id=0, where=label, entry=entry, shows=entry.show(pa) if hands is not None else "",
            prompt=f"Set the supply pressure to {entry.show(pa)} ({pa / 6894.757:.2f} psi) "
                   "with the regulator, then type the regulator gauge's reading"),
            zero, spec.ramp_s)
        assert answer is not None
        if answer.choice != "ok":
            return answer.choice
        assert answer.value_si is not None
        setting = answer.value_si
        if hands is not None:
            hands.set_supply_pressure(setting)
        stream.hold(zero, spec.settle_s, spec.ramp_s)
        first, _, moving = hold_steady(stream, zero, spec.record_s, spec.ramp_s,
                                       [Steadiness("p_in", spec.steady_pressure_pa, 0.01)],
                                       spec.steady_timeout_s)
        if moving:
            return ask_unsteady(stream, label, moving, spec.steady_timeout_s, zero, spec.ramp_s)
        return point_step(n_steps, "pressure", setting, "", first, stream.sample,
                          extra={"supply_pressure_pa": setting,
                                 "supply_pressure_asked_pa": pa})

    def body(stream: Stream, steps: list[StepRecord]) -> None:
        pump(True)
        listener.on_event("pump", "pump on", stream.sample)
        n_points = spec.repeats * len(spec.supply_pressures_pa)
        try:
            for p in range(spec.repeats):
                for pa in spec.supply_pressures_pa:
                    step: StepRecord | str = "repeat"
                    while step == "repeat":
                        stream.where = f"flow step {len(steps) + 1} ({pa:g} Pa, pass {p + 1})"
                        step = point(stream, len(steps), pa, f"flow {pa / 1e3:g} kPa pass "
                                     f"{p + 1}, point {len(steps) + 1}/{n_points}")
                    if isinstance(step, StepRecord):
                        listener.on_step(step)
                        steps.append(step)
        finally:
            pump(False)
            listener.on_event("pump", "pump off", stream.sample)

    return run_program("flow", backend, listener, spec, body, operator)


__all__: Sequence[str] = [
    "FlowSpec", "ImpactSpec", "ProbeCalSpec", "ProgramError", "ProgramOutcome", "StaticSpec",
    "journal_out", "run_flow_test", "run_impact_test",
    "run_probe_calibration", "run_static_test",
]
