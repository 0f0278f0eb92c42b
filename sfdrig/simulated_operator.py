"""The operator's hands on the simulated rig: what the test programmes cannot do through the DAQ.

On the real rig a person strikes the housing with the impact hammer, reads the dial gauges and
turns the pump's pressure regulator. On the simulated rig these act on the rig model directly.
This wiring lives in the composition root, so `control` never imports `simulated_hw`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from simulated_hw.backend import SimulatedBackend

DIAL_GAUGE_RESOLUTION_M = 0.0001 * 0.0254  # +/- 0.0001 in dial gauges (Appendix A)


@dataclass
class SimulatedOperator:
    backend: SimulatedBackend
    gauge_resolution_m: float = DIAL_GAUGE_RESOLUTION_M

    def strike(self, axis: str, peak_force_n: float) -> None:
        """Hit the housing along ``axis`` with a 2 ms half-sine hammer pulse."""
        self._rig().schedule_impact(axis, peak_force_n, duration_s=0.002)

    def read_gauge(self, axis: str) -> float:
        """The dial gauge on ``axis``: the true displacement to the gauge's resolution [m]."""
        truth = self._rig().last_truth
        if truth is None:
            raise RuntimeError("the gauge is read before the rig has moved: acquire first")
        z = float((truth.x_m if axis == "x" else truth.y_m)[-1])
        return self.gauge_resolution_m * math.floor(z / self.gauge_resolution_m + 0.5)

    def set_supply_pressure(self, pressure_pa: float) -> None:
        """Turn the regulator: the pump's supply pressure when it runs [Pa]."""
        self._rig().params.oil.supply_pressure_pa = float(pressure_pa)

    def _rig(self):  # noqa: ANN202
        if self.backend.rig is None:
            raise RuntimeError("the simulated backend is not configured")
        return self.backend.rig
