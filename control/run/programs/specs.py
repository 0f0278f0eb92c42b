"""The settings of the non-sweep test programmes (pydantic, with units and limits)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    block_samples: int = Field(
        100, ge=10, le=100_000,
        description="samples per AI/AO block; two blocks are queued ahead. A force trip is seen "
        "at the end of the block it happens in, and the queue is cut there: the drives are at 0 V "
        "from then (or fade in 40 ms where the backend cannot stop its AO)",
    )
    ramp_s: float = Field(0.1, gt=0, le=5, description="drive ramp between levels [s]")
    max_force_n: float = Field(448.0, gt=0, description="measured force limit (shaker rating)")


class _Steady(_Spec):
    steady_timeout_s: float = Field(5.0, gt=0, description="longest wait for steady signals; "
                                    "then the operator repeats or skips the point [s]")
    steady_force_n: float = Field(0.5, gt=0, description="load-cell mean may move by this "
                                  "(plus 0.5 %) over the record [N]")
    steady_displacement_m: float = Field(0.25e-6, gt=0, description="probe mean may move by "
                                         "this (plus 0.5 %) over the record [m]")
    confirm_points: bool = Field(True, description="the operator accepts each recorded point")


class StaticSpec(_Steady):
    """Static load steps (report IV.1: -89 N to 89 N, each level repeated)."""

    axes: tuple[str, ...] = ("x", "y")
    forces_n: tuple[float, ...] = (-80.0, -40.0, 0.0, 40.0, 80.0)
    repeats: int = Field(3, ge=1, le=20, description="passes over the levels (eq. B.6)")
    settle_s: float = Field(0.3, gt=0, description="hold before recording [s]")
    record_s: float = Field(0.5, gt=0, description="recorded hold [s]")
    corrections: int = Field(2, ge=0, le=10, description="drive corrections toward the force")
    load_by: Literal["shaker", "hand"] = Field(
        "shaker", description="'shaker': the shakers hold each load, the load cells read it; "
        "'hand': the operator pushes the housing with a force gauge and types its reading, "
        "shakers at 0 V (the report's way, IV.1)")
    force_gauge_unit: Literal["N", "lbf", "lb"] = Field(
        "lbf", description="the hand force gauge's unit (IV.1: +/- 0.5 lb)")
    force_gauge_range_n: float = Field(
        222.4, gt=0, description="the force gauge's range, +/- [N] (a 50 lbf gauge)")


class ImpactSpec(_Spec):
    """Impact tests as modal-test software runs them: armed on the hammer channel (level and
    slope) with a pre-trigger, a fixed record per hit, automatic rejection of double hits and
    overloads, the operator's accept or reject, ``strikes`` accepted hits per axis averaged (H1)."""

    axes: tuple[str, ...] = ("x", "y")
    strikes: int = Field(3, ge=1, le=50, description="accepted hits per axis (averaged FRF)")
    max_hits: int = Field(20, ge=1, le=200, description="hits per axis before giving up")
    peak_force_n: float = Field(300.0, gt=0, description="hammer peak to aim at [N]")
    pretrigger_s: float = Field(0.02, ge=0, description="kept before the trigger [s]")
    window_s: float = Field(1.0, gt=0, description="recorded after the trigger [s]")
    trigger_n: float = Field(10.0, gt=0, description="trigger level on the hammer [N]")
    slope: Literal["rising", "falling"] = "rising"
    double_hit_fraction: float = Field(
        0.1, gt=0, lt=1, description="a second pulse above this fraction of the first's peak, "
        "after the hammer fell below it, is a double hit")
    overload_fraction: float = Field(0.98, gt=0, le=1, description="a channel at this fraction "
                                     "of its input range is overloaded")
    wait_s: float = Field(600.0, gt=0, description="longest wait for a strike [s]")
    quiet_s: float = Field(0.3, ge=0, description="free decay allowed between strikes [s]")
    hammer_channel: str = "hammer"


class ProbeCalSpec(_Steady):
    """Static displacement steps read against a reference gauge (Appendix A)."""

    axes: tuple[str, ...] = ("x", "y")
    forces_n: tuple[float, ...] = (-60.0, -40.0, -20.0, 0.0, 20.0, 40.0, 60.0)
    settle_s: float = Field(0.3, gt=0)
    record_s: float = Field(0.3, gt=0)
    gauge_unit: str = Field("in", description="the dial gauge's unit (Appendix A: 0.0001 in)")


class FlowSpec(_Spec):
    """Pump on, a ladder of supply pressures, each held and recorded (section V)."""

    supply_pressures_pa: tuple[float, ...] = (8e3, 12e3, 15.5e3, 20e3, 25e3)
    repeats: int = Field(2, ge=1, le=10)
    settle_s: float = Field(3.0, gt=0, description="pressure settling at each level [s]")
    record_s: float = Field(1.0, gt=0)
    steady_pressure_pa: float = Field(100.0, gt=0, description="inlet pressure mean may move "
                                      "by this (plus 1 %) over the record [Pa]")
    steady_timeout_s: float = Field(10.0, gt=0, description="longest wait for a steady "
                                    "pressure [s]")
    pump_relay: str = "pump"


#: every programme's spec
ProgramSpec = StaticSpec | ImpactSpec | ProbeCalSpec | FlowSpec

__all__ = ["FlowSpec", "ImpactSpec", "ProbeCalSpec", "ProgramSpec", "StaticSpec"]
