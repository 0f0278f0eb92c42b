"""The sweep request (pydantic, loadable from TOML): what a client writes and the daemon validates
again at start. Here in the wire so that clients check a sweep with the same model; re-exported
by `control.run.sweep.engine`.

Example (the report's lubricated tests, section VI.1)::

    name = "lubricated X, 13-38 um"
    motion = "x"
    lubricated = true
    amplitude_m = [13e-6, 19e-6, 25e-6, 32e-6, 38e-6]
    freq_start_hz = 20.0
    freq_stop_hz = 60.0
    freq_step_hz = 10.0
    settle_cycles = 10
    record_cycles = 40

Frequencies are either a list (``freq_hz``, run in the order given) or a range from
``freq_start_hz`` to ``freq_stop_hz`` (downwards when start > stop) with ``freq_step_hz``
(linear) or ``freq_points`` (linear or log ``spacing``). Targets: ``amplitude_m`` (hold the
displacement) or ``load_n`` (hold the load), one or more values; each value is a whole sweep over
the frequencies (``order = "amplitude_major"``) or each frequency runs every value
(``"frequency_major"``).

The models are strict (a boolean is JSON true/false, a number is a number, never a string) and
every number is finite. Every number field states its SI unit once, in its metadata (`unit`;
`field_units` lists them): the page's form shows each field in it. The work a sweep asks for is
bounded before anything is enumerated: at most `MAX_STEPS` dwells and `MAX_SWEEP_S` of settling
and recording.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic.json_schema import JsonDict

from control.signal.controller import Tolerance, motion_shape
from control.wire.errors import SpecError
from control.wire.step_plan import StepPlan
from control.wire.text import Text
from daq.config_files import read_toml, validate

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]


def unit(symbol: str) -> JsonDict:
    """A number field's SI unit, kept in its JSON schema as ``"unit"`` (`field_units` reads it): the
    one place a field's unit is written ("" for a pure number: a count, a ratio, a gain). The
    page's sweep form shows and converts each field by it."""
    return {"unit": symbol}


#: Most dwells one sweep may have (targets x frequencies); the report's plan has 39.
MAX_STEPS = 10_000
#: Longest a sweep may settle and record, summed over its dwells [s] (24 h).
MAX_SWEEP_S = 24 * 3600.0


class ControlSettings(BaseModel):
    """How the controller works a step (defaults suit the report's rig)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    window_cycles: int = Field(2, ge=1, le=100, description="lock-in window per update",
                               json_schema_extra=unit("cycles"))
    wait_cycles: int = Field(2, ge=0, le=100, description="wait after a drive change",
                             json_schema_extra=unit("cycles"))
    min_ramp_s: float = Field(0.02, ge=0.0, le=2.0, description="shortest ramp",
                               json_schema_extra=unit("s"))
    settle_tolerance_pct: float = Field(
        0.3, gt=0, le=10, description="settled when successive windows agree within this",
        json_schema_extra=unit("%"),
    )
    max_settle_cycles: int = Field(
        100, ge=1, le=100_000,
        description="record anyway (with a warning) after this many cycles",
        json_schema_extra=unit("cycles"),
    )
    initial_stiffness_n_per_m: float = Field(
        1.0e6, ge=1.0e3, le=1.0e10,
        description="first guess of |force / displacement| (first displacement step), and the "
                    "stiffness of the plant estimate at a new frequency",
        json_schema_extra=unit("N/m"),
    )
    aim_fraction: float = Field(
        0.5, gt=0, le=1,
        description="stop correcting once inside this fraction of the tolerance band (the "
                    "recording must be inside the whole band)",
        json_schema_extra=unit(""),
    )
    max_growth: float = Field(2.0, gt=0, le=10, description="largest relative drive change",
                               json_schema_extra=unit(""))
    breakaway_growth: float = Field(
        0.1, gt=0, le=1,
        description="while the housing does not move, largest relative drive raise per "
                    "latency (AO lead plus one cycle): bounds the jump from stick to slip",
        json_schema_extra=unit(""),
    )
    start_growth: float = Field(
        0.2, gt=0, le=1,
        description="largest relative drive raise per latency when a displacement step starts "
                    "at a new frequency (from 80 % of the predicted drive) or a correction "
                    "raises the drive, watching the response block by block",
        json_schema_extra=unit(""),
    )
    nominal_mass_kg: float = Field(
        9.7, gt=0, le=1e4,
        description="moving mass of the 1-DOF plant estimate that sets the first drive at a new "
                    "frequency (the housing; the film's added mass below when lubricated)",
        json_schema_extra=unit("kg"),
    )
    lubricated_added_mass_kg: float = Field(
        8.2, ge=0, le=1e4,
        description="the film's added mass in the plant estimate of a lubricated sweep "
                    "(plenum oil M_f plus eq. 15's D)",
        json_schema_extra=unit("kg"),
    )
    nominal_damping_ns_per_m: float = Field(
        370.0, gt=0, le=1e7,
        description="damping of the plant estimate: the lightest the rig has (dry, no film), so "
                    "the estimate overstates the orbit near the resonance",
        json_schema_extra=unit("N.s/m"),
    )
    lubricated_damping_ns_per_m: float = Field(
        2500.0, ge=0, le=1e7,
        description="the film's damping counted in the plant estimate of a lubricated sweep: "
                    "half eq. 16's 5,060 N.s/m at the centre (a film not yet full, air "
                    "entrained)",
        json_schema_extra=unit("N.s/m"),
    )
    plant_uncertainty: float = Field(
        0.3, ge=0, lt=1,
        description="the plant estimate's stiffness and mass may each be off by this fraction: "
                    "its compliance is the largest over that band (the resonance widened)",
        json_schema_extra=unit(""),
    )
    algorithm: Literal["newton_broyden", "proportional"] = Field(
        "newton_broyden",
        description="2x2 Newton-Broyden (default) or a plain per-axis proportional level loop",
    )
    proportional_gain: float = Field(
        1.0, gt=0, le=1, description="gain of the proportional loop (1: D <- D x target/measured)",
        json_schema_extra=unit(""),
    )
    predict: bool = Field(
        True, description="start each step from the drive predicted by the steps already run "
                          "(else from the previous step's drive)",
    )
    block_s: float = Field(0.01, ge=0.001, le=0.02, description="AO/AI block length",
                            json_schema_extra=unit("s"))
    ahead_blocks: int = Field(
        3, ge=1, le=5, description="AO blocks written ahead of the generation (slack for the "
                                   "loop; block_s x (1 + ahead_blocks) + fade_s <= 100 ms)",
        json_schema_extra=unit(""))


class SweepSpec(BaseModel):
    """A multi-frequency, multi-amplitude sweep (see the module docstring for the TOML form)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    name: Text = Field("", max_length=200)
    motion: Literal["x", "y", "circular_forward", "circular_backward", "elliptical"] = "x"
    lubricated: bool = Field(False, description="needs the pump on and inlet pressure")
    amplitude_m: list[PositiveFloat] | None = Field(
        None, min_length=1, max_length=MAX_STEPS,
        description="displacement amplitudes to hold (of X; Y for 'y')",
        json_schema_extra=unit("m"),
    )
    load_n: list[PositiveFloat] | None = Field(
        None, min_length=1, max_length=MAX_STEPS,
        description="load amplitudes to hold (of X; Y for 'y')",
        json_schema_extra=unit("N"),
    )
    ellipse_ratio: PositiveFloat = Field(1.0, description="elliptical: |Y| / |X|",
                                         json_schema_extra=unit(""))
    ellipse_phase_deg: float = Field(
        -90.0, ge=-180, le=180, description="elliptical: phase of Y relative to X",
        json_schema_extra=unit("deg"),
    )
    freq_hz: list[PositiveFloat] | None = Field(
        None, min_length=1, max_length=MAX_STEPS, description="frequencies, run in this order",
        json_schema_extra=unit("Hz"))
    freq_start_hz: PositiveFloat | None = Field(None, json_schema_extra=unit("Hz"))
    freq_stop_hz: PositiveFloat | None = Field(None, json_schema_extra=unit("Hz"))
    freq_step_hz: PositiveFloat | None = Field(None, json_schema_extra=unit("Hz"))
    freq_points: int | None = Field(None, ge=2, le=10_000, json_schema_extra=unit(""))
    spacing: Literal["linear", "log"] = "linear"
    order: Literal["amplitude_major", "frequency_major"] = "amplitude_major"
    settle_cycles: int = Field(10, ge=1, le=100_000, description="after the last change",
                               json_schema_extra=unit("cycles"))
    record_cycles: int = Field(40, ge=1, le=100_000, description="recorded per step",
                               json_schema_extra=unit("cycles"))
    tolerance_amplitude_pct: float = Field(1.0, gt=0, le=50, json_schema_extra=unit("%"))
    tolerance_phase_deg: float = Field(1.0, gt=0, le=45, json_schema_extra=unit("deg"))
    max_updates: int = Field(10, ge=1, le=1000, description="controller updates per step",
                             json_schema_extra=unit(""))
    on_not_converged: Literal["abort", "continue"] = "abort"
    control: ControlSettings = ControlSettings()

    @model_validator(mode="after")
    def _one_target_one_frequency_form(self) -> Self:
        if (self.amplitude_m is None) == (self.load_n is None):
            raise ValueError("give exactly one of amplitude_m (hold displacement) or load_n "
                             "(hold load)")
        ranged = [self.freq_start_hz, self.freq_stop_hz]
        if self.freq_hz is not None:
            if any(v is not None for v in [*ranged, self.freq_step_hz, self.freq_points]):
                raise ValueError("give either freq_hz (a list) or a range "
                                 "(freq_start_hz, freq_stop_hz, ...), not both")
        else:
            if any(v is None for v in ranged):
                raise ValueError("give freq_hz (a list) or both freq_start_hz and freq_stop_hz")
            if ((self.freq_step_hz is None) == (self.freq_points is None)
                    and self.freq_start_hz != self.freq_stop_hz):
                raise ValueError("a frequency range needs exactly one of freq_step_hz or "
                                 "freq_points")
            if self.spacing == "log" and self.freq_points is None:
                raise ValueError("log spacing needs freq_points")
        n_steps = len(self.targets) * self.frequency_count()
        if n_steps > MAX_STEPS:
            raise ValueError(f"the sweep has {n_steps:.4g} steps ({len(self.targets)} targets x "
                             f"{self.frequency_count():.4g} frequencies); at most {MAX_STEPS:,}")
        duration = len(self.targets) * sum(
            (self.settle_cycles + self.record_cycles) / f for f in self.frequencies())
        if duration > MAX_SWEEP_S:
            raise ValueError(f"the sweep settles and records for {duration / 3600:.4g} h; at most "
                             f"{MAX_SWEEP_S / 3600:g} h")
        return self

    # --- derived ----------------------------------------------------------------------------
    @property
    def target_kind(self) -> Literal["displacement", "load"]:
        return "displacement" if self.amplitude_m is not None else "load"

    @property
    def targets(self) -> list[float]:
        vals = self.amplitude_m if self.amplitude_m is not None else self.load_n
        assert vals is not None
        return list(vals)

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_amplitude_pct / 100.0, self.tolerance_phase_deg)

    def frequency_count(self) -> float:
        """How many frequencies `frequencies` gives, counted without listing them (a float: a
        range with a tiny step counts past any integer worth building)."""
        if self.freq_hz is not None:
            return len(self.freq_hz)
        f0, f1 = self.freq_start_hz, self.freq_stop_hz
        assert f0 is not None and f1 is not None
        if f0 == f1:
            return 1
        if self.freq_points is not None:
            return self.freq_points
        assert self.freq_step_hz is not None
        return math.floor(abs(f1 - f0) / self.freq_step_hz + 1e-9) + 1.0

    def frequencies(self) -> list[float]:
        """The excitation frequencies in the order they run [Hz] (at most `MAX_STEPS`)."""
        if self.freq_hz is not None:
            return list(self.freq_hz)
        f0, f1 = self.freq_start_hz, self.freq_stop_hz
        assert f0 is not None and f1 is not None
        if f0 == f1:
            return [f0]
        if self.freq_points is not None:
            if self.spacing == "log":
                return [float(v) for v in np.geomspace(f0, f1, self.freq_points)]
            return [float(v) for v in np.linspace(f0, f1, self.freq_points)]
        step = self.freq_step_hz
        assert step is not None
        n = int(math.floor(abs(f1 - f0) / step + 1e-9))
        sign = 1.0 if f1 > f0 else -1.0
        return [round(f0 + sign * i * step, 9) for i in range(n + 1)]

    def steps(self) -> list[StepPlan]:
        """Every dwell of the sweep, in running order."""
        freqs = self.frequencies()
        pairs = (
            [(a, f) for a in self.targets for f in freqs] if self.order == "amplitude_major"
            else [(a, f) for f in freqs for a in self.targets]
        )
        return [
            StepPlan(i, f, self.target_kind, a, self.motion,
                     motion_shape(self.motion, a, self.ellipse_ratio, self.ellipse_phase_deg),
                     len(pairs))
            for i, (a, f) in enumerate(pairs)
        ]

    def ideal_step_s(self, freq_hz: float) -> float:
        """Settling plus recording time of one step at ``freq_hz`` [s] (benchmark reference)."""
        return (self.settle_cycles + self.record_cycles) / freq_hz


def field_units(model: type[BaseModel] | None = None, prefix: str = "") -> dict[str, str]:
    """Every number field of the sweep (`SweepSpec`, its ``control`` table by dotted path, e.g.
    ``control.block_s``) and its unit as `unit` gave it."""
    out: dict[str, str] = {}
    for name, f in (model or SweepSpec).model_fields.items():
        if isinstance(f.annotation, type) and issubclass(f.annotation, BaseModel):
            out.update(field_units(f.annotation, f"{prefix}{name}."))
        elif isinstance(f.json_schema_extra, dict) and "unit" in f.json_schema_extra:
            out[prefix + name] = str(f.json_schema_extra["unit"])
    return out


def sweep_spec_from_dict(data: dict[str, Any], source: str = "<dict>") -> SweepSpec:
    """Validate a sweep description; `SpecError` (a `TargetError`) names each bad field."""
    return validate(SweepSpec, data, "sweep spec", source, SpecError)


def load_sweep_spec(path: str | Path) -> SweepSpec:
    """Load a sweep description from TOML; `SpecError` names the file, field and value."""
    return sweep_spec_from_dict(read_toml(path, SpecError), str(path))
