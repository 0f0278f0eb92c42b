"""Static load steps applied by hand, as the report made them (IV.1): for each load the operator
pushes the housing with a hand force gauge along the axis, the probes are recorded once steady,
and the operator types the gauge's reading. The shakers stay at 0 V; a point pairs the typed force
with the measured displacement (``gauge_force_n``, which `analysis.structure.identify_static`
uses instead of the load cell). On the simulated rig ``hands`` push (`RigHands.push`)."""

from __future__ import annotations

import numpy as np

from control.run.programs.operator import UNITS, Entry, Question
from control.run.programs.specs import StaticSpec
from control.run.programs.stream import (
    ProgramError,
    RigHands,
    Steadiness,
    Stream,
    ask,
    ask_unsteady,
    hold_steady,
    point_step,
    signal,
)
from storage.records import StepRecord


def static_levels_by_hand(stream: Stream, steps: list[StepRecord], spec: StaticSpec,
                          hands: RigHands | None) -> None:
    """Every planned load on every axis, ``repeats`` passes; each point once recorded, or
    skipped by the operator."""
    if stream.operator is None:
        raise ProgramError("static loads by hand need an operator to push and read the gauge")
    n_points = len(spec.axes) * spec.repeats * len(spec.forces_n)
    for axis in spec.axes:
        try:
            for p in range(spec.repeats):
                for force in spec.forces_n:
                    point = len(steps) + 1
                    step: StepRecord | str = "repeat"
                    while step == "repeat":
                        stream.where = (f"static step {len(steps) + 1} ({axis}, {force:g} N "
                                        f"by hand, pass {p + 1})")
                        step = _hand_point(stream, spec, hands, axis, force, len(steps),
                                           f"static {axis} {force:+g} N by hand pass {p + 1}, "
                                           f"point {point}/{n_points}")
                    if isinstance(step, StepRecord):
                        stream.listener.on_step(step)
                        steps.append(step)
        finally:
            if hands is not None:
                hands.push(axis, 0.0)  # the operator lets go


def _hand_point(stream: Stream, spec: StaticSpec, hands: RigHands | None, axis: str,
                force: float, index: int, label: str) -> StepRecord | str:
    """One load: the step dict, "repeat" or "skip"."""
    zero = np.zeros(stream.n_ao)
    r = spec.force_gauge_range_n
    entry = Entry(name="force_gauge", label=f"force gauge {axis}", quantity="force",
                  unit=spec.force_gauge_unit, min_si=-r, max_si=r)
    if abs(force) < 1e-9:
        prompt = f"Load 0 N on {axis}: take the force gauge off the housing; ok when hands off"
    else:
        prompt = (f"Push the housing along {'+' if force > 0 else '-'}{axis} with the force "
                  f"gauge to about {abs(force) / UNITS['force'][entry.unit]:.1f} {entry.unit} "
                  f"({abs(force):g} N) and hold it "
                  "there; ok when pushing")
    answer = ask(stream, Question(id=0, where=label, prompt=prompt), zero, spec.ramp_s)
    assert answer is not None
    if answer.choice != "ok":
        return answer.choice
    if hands is not None:
        hands.push(axis, force)
    stream.hold(zero, spec.settle_s, spec.ramp_s)
    first, ai, moving = hold_steady(stream, zero, spec.record_s, spec.ramp_s,
                                    [Steadiness(axis, spec.steady_displacement_m)],
                                    spec.steady_timeout_s)
    probes = (f"probes {axis} {float(signal(stream.cm, ai, axis).mean()) * 1e6:+.2f} um over "
              f"{spec.record_s:g} s")
    if moving:
        return ask_unsteady(stream, label, moving, spec.steady_timeout_s, zero, spec.ramp_s,
                            [probes])
    last = stream.sample
    answer = ask(stream, Question(
        id=0, where=label, entry=entry, info=[probes],
        shows=entry.show(hands.force_gauge_reading_n(axis)) if hands is not None else "",
        prompt=f"Probes steady: keep pushing, read the force gauge on {axis} and type it"),
        zero, spec.ramp_s)
    assert answer is not None
    if answer.choice != "ok":
        return answer.choice
    assert answer.value_si is not None
    return point_step(index, "load", force, axis, first, last, extra={
        "force_n": force, "gauge_force_n": answer.value_si, "gauge_text": answer.text,
        "load_by": "hand"})
