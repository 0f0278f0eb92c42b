"""The operator's hands on the simulated rig, and a stand-in operator for unattended runs.

On the real rig a person strikes the housing with the impact hammer, reads the dial gauges, turns
the pump's pressure regulator, pushes the housing with a force gauge and takes the journal out. On
the simulated rig `SimulatedHands` does these to the rig model when the operator's answer asks for
them (`control.run.programs.stream.RigHands`). `StandInOperator` answers every question at once the
way a careful technician would (the demo, `sfdrig structure --unattended`);
`SimulatedCommissioner` is the person at the rig for `sfdrig commission --backend sim`. This
wiring lives in the composition root, so `control` never imports `simulated_hw`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from control.run.programs.operator import OperatorDesk, Question
from simulated_hw.backend import SimulatedBackend

DIAL_GAUGE_RESOLUTION_M = 0.0001 * 0.0254  # +/- 0.0001 in dial gauges (Appendix A)
DOUBLE_HIT_DELAY_S = 0.03  # the hammer bounces back onto the housing
OVERLOAD_FACTOR = 1.25  # an overload hit: this much beyond the hammer channel's range
FORCE_GAUGE_RESOLUTION_N = 0.1 * 4.4482216152605  # a hand force gauge showing 0.1 lbf
PUSH_SCATTER = 0.03  # a hand holds the asked force to a few percent (1 sigma)


@dataclass
class SimulatedHands:
    backend: SimulatedBackend
    gauge_resolution_m: float = DIAL_GAUGE_RESOLUTION_M
    hammer_channel: str = "hammer"
    seed: int = 0
    force_gauge_resolution_n: float = FORCE_GAUGE_RESOLUTION_N
    push_scatter: float = PUSH_SCATTER
    _pushed: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)

    def strike(self, axis: str, peak_force_n: float, kind: str = "ok") -> None:
        """Hit the housing along ``axis`` with a 2 ms half-sine pulse; ``kind`` "double" adds a
        bounce 30 ms later at half the peak, "overload" hits beyond the hammer's input range."""
        rig = self._rig()
        if kind == "overload":
            ch = next(c for c in self.backend.channel_map.ai if c.name == self.hammer_channel)
            peak_force_n = OVERLOAD_FACTOR * (ch.range_v[1] - ch.offset_v) / ch.gain_v_per_unit
        rig.schedule_impact(axis, peak_force_n, duration_s=0.002)
        if kind == "double":
            rig.schedule_impact(axis, 0.5 * peak_force_n, duration_s=0.002,
                                delay_s=DOUBLE_HIT_DELAY_S)

    def gauge_reading_m(self, axis: str) -> float:
        """The dial gauge on ``axis``: the true displacement to the gauge's resolution [m]."""
        truth = self._rig().last_truth
        if truth is None:
            raise RuntimeError("the gauge is read before the rig has moved: acquire first")
        z = float((truth.x_m if axis == "x" else truth.y_m)[-1])
        return self.gauge_resolution_m * math.floor(z / self.gauge_resolution_m + 0.5)

    def push(self, axis: str, force_n: float) -> None:
        """Push the housing with the force gauge: the asked force, off by a seeded few percent
        as a hand holds it, as an external force on the housing (0: let go)."""
        applied = float(force_n) * (1.0 + self.push_scatter * float(self._rng.standard_normal()))
        self._rig().push(axis, applied)
        self._pushed[axis] = applied

    def force_gauge_reading_n(self, axis: str) -> float:
        """The force gauge pushing along ``axis``: the force applied, to its resolution [N]."""
        f = self._pushed.get(axis, 0.0)
        return self.force_gauge_resolution_n * math.floor(f / self.force_gauge_resolution_n + 0.5)

    def set_supply_pressure(self, pressure_pa: float) -> None:
        """Turn the regulator: the pump's supply pressure when it runs [Pa]."""
        self._rig().params.oil.supply_pressure_pa = float(pressure_pa)

    def set_journal(self, installed: bool) -> None:
        """Journal out: no seal, no wall at the clearance; back in: as configured."""
        self._rig().set_journal(installed)

    def _rig(self):  # noqa: ANN202
        if self.backend.rig is None:
            raise RuntimeError("the simulated backend is not configured")
        return self.backend.rig


class StandInOperator(OperatorDesk):
    """Answers each question as it is asked: accepts steady points and clean hits, types what
    the simulated instrument shows, repeats an unsteady point, strikes cleanly."""

    def post(self, question: Question) -> Question:
        q = super().post(question)
        if q.entry is not None:
            self.submit(q.id, "ok", q.shows)
        elif "ok" in q.choices:
            self.submit(q.id, "ok")
        else:
            self.submit(q.id, "repeat" if "repeat" in q.choices else q.choices[0])
        return q


@dataclass
class SimulatedCommissioner:
    """The person at the simulated rig during `sfdrig commission` (a
    `control.commissioning.procedure.Operator`): presses and releases the emergency stop when asked,
    lets the pump run while the tool tests its relay (the damper closed), takes the journal out
    before the drives (its oil with it), and reports the pump relay as the rig has it. ``say``
    shows what the hands do."""

    backend: SimulatedBackend
    say: Callable[[str], None] = print

    def instruct(self, action: str, text: str) -> None:
        self.say(f"operator: {text}")
        if action in ("press_estop", "release_estop"):
            self.backend.press_estop(action == "press_estop")
            done = "pressed" if action == "press_estop" else "released"
            self.say(f"  (simulated hands: the button {done})")

    def confirm(self, action: str, question: str) -> bool:
        rig = self.backend.rig
        assert rig is not None
        if action == "drive":
            rig.set_journal(False)
            self.say(f"operator: {question} yes (simulated hands: journal out)")
            return True
        answer = not rig.pump_on if action == "relay_off" else True
        self.say(f"operator: {question} {'yes' if answer else 'no'}")
        return answer
