"""The rig's channel map and sensor calibration: pydantic models loadable from TOML.

Maps read from files are read strictly (`load_channel_map`; `rig_map_problems`): every input
carries one of the names the software knows (`KNOWN_INPUTS`: the sweep, the safety trips, the
simulated rig and the analysis find their signals by name), of its kind; the only relay is
``pump``; and a map the software runs with has what the daemon and the commissioning need to
drive the rig: a drive, and for each axis driven its load cell and a probe
(`REQUIRED_PER_AXIS`), and the pump relay.
A wiring map (the simulated rig's real wiring) may lack any of them: a missing sensor is an
empty terminal.

Calibration convention, for every analog channel: ``volts = gain_v_per_unit * value + offset_v``,
so ``value = (volts - offset_v) / gain_v_per_unit``, in the channel's engineering units (SI, except
flow in L/min and temperature in degC, as the rig's instruments read).
"""

from __future__ import annotations

import difflib
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from daq.board import grpc_target_problem
from daq.config_files import read_toml, to_toml, validate
from daq.errors import ChannelConfigError


class ChannelKind(StrEnum):
    LOAD_CELL = "load_cell"
    EDDY_CURRENT_PROBE = "eddy_current_probe"
    ACCELEROMETER = "accelerometer"
    PRESSURE_4_20MA = "pressure_4_20mA"
    FLOW = "flow"
    THERMOCOUPLE = "thermocouple"
    SHAKER_DRIVE = "shaker_drive"
    RELAY = "relay"


#: Engineering units each kind of channel may carry.
UNITS_BY_KIND: dict[ChannelKind, tuple[str, ...]] = {
    ChannelKind.LOAD_CELL: ("N",),
    ChannelKind.EDDY_CURRENT_PROBE: ("m",),
    ChannelKind.ACCELEROMETER: ("m/s^2",),
    ChannelKind.PRESSURE_4_20MA: ("Pa",),
    ChannelKind.FLOW: ("L/min",),
    ChannelKind.THERMOCOUPLE: ("degC",),
    ChannelKind.SHAKER_DRIVE: ("V",),
    ChannelKind.RELAY: ("bool",),
}

class TerminalConfig(StrEnum):
    """How an analog input is referenced (DAQmx ``TerminalConfiguration``). ``default`` leaves
    it to the device (differential where the channel can be, on NI's multifunction boards)."""

    DEFAULT = "default"
    DIFFERENTIAL = "differential"
    RSE = "rse"
    NRSE = "nrse"
    PSEUDO_DIFFERENTIAL = "pseudo_differential"


AI_KINDS = {
    ChannelKind.LOAD_CELL,
    ChannelKind.EDDY_CURRENT_PROBE,
    ChannelKind.ACCELEROMETER,
    ChannelKind.PRESSURE_4_20MA,
    ChannelKind.FLOW,
    ChannelKind.THERMOCOUPLE,
}

Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]{0,31}$")]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DeviceSpec(_Strict):
    """What the DAQ board can do. Default: an NI PXIe-6358 (16 simultaneous AI, 1.25 MS/s/ch)."""

    name: str = Field("Dev1", pattern=r"^[A-Za-z][A-Za-z0-9_]*$")
    product: str = "PXIe-6358"
    ai_count: int = Field(16, ge=1, le=256)
    ao_count: int = Field(2, ge=0, le=64)
    do_ports: int = Field(1, ge=0, le=8)
    do_lines_per_port: int = Field(8, ge=0, le=32)
    max_rate_hz: float = Field(1.25e6, gt=0, description="max AI sample rate per channel [S/s]")
    min_rate_hz: float = Field(10.0, gt=0, description="min sample clock rate [S/s]")
    ai_range_v: float = Field(10.0, gt=0, le=10.0, description="largest AI input range [V]")
    ao_range_v: float = Field(10.0, gt=0, le=10.0, description="largest AO output range [V]")
    ai_bits: int = Field(16, ge=8, le=24)
    ao_idle_output_zero: bool = Field(
        True, description="AO channels can be set to generate 0 V when no generation runs "
                          "(DAQmx ao_idle_output_behavior = ZERO_VOLTS)")
    ao_watchdog: bool = Field(
        True, description="the watchdog timer can set AO channels (AO expiration states)")

    def ai_channels(self) -> list[str]:
        return [f"{self.name}/ai{i}" for i in range(self.ai_count)]

    def ao_channels(self) -> list[str]:
        return [f"{self.name}/ao{i}" for i in range(self.ao_count)]

    def do_lines(self) -> list[str]:
        return [
            f"{self.name}/port{p}/line{i}"
            for p in range(self.do_ports)
            for i in range(self.do_lines_per_port)
        ]


class AnalogInput(_Strict):
    """One analog input channel and its sensor calibration."""

    name: Name
    physical_channel: str = Field(description="e.g. Dev1/ai0")
    kind: ChannelKind
    units: str
    gain_v_per_unit: float = Field(gt=0, description="sensitivity [V per engineering unit]")
    offset_v: float = Field(0.0, description="output at zero of the measurand [V]")
    range_v: tuple[float, float] = Field((-10.0, 10.0), description="input range [V]")
    terminal_config: TerminalConfig = Field(
        TerminalConfig.DEFAULT, description="input terminal configuration (the device's "
                                            "default, differential, rse, nrse, ...)")
    sensor: str = Field("", description="make, model or serial number")

    @field_validator("kind")
    @classmethod
    def _ai_kind(cls, kind: ChannelKind) -> ChannelKind:
        if kind not in AI_KINDS:
            raise ValueError(f"kind {kind.value!r} is not an analog-input kind")
        return kind

    @model_validator(mode="after")
    def _units_and_range(self) -> AnalogInput:
        allowed = UNITS_BY_KIND[self.kind]
        if self.units not in allowed:
            raise ValueError(
                f"units {self.units!r} not allowed for kind {self.kind.value!r} (use {allowed})"
            )
        lo, hi = self.range_v
        if not lo < hi:
            raise ValueError(f"range_v {self.range_v} must be (min, max) with min < max")
        return self

    def to_units(self, volts: np.ndarray) -> np.ndarray:
        return (volts - self.offset_v) / self.gain_v_per_unit

    def to_volts(self, value: np.ndarray) -> np.ndarray:
        return self.gain_v_per_unit * value + self.offset_v


class AnalogOutput(_Strict):
    """One shaker-drive output; the nominal force gain is the controller's first guess only."""

    name: Name
    physical_channel: str = Field(description="e.g. Dev1/ao0")
    kind: ChannelKind = ChannelKind.SHAKER_DRIVE
    units: str = "V"
    range_v: tuple[float, float] = (-10.0, 10.0)
    nominal_force_n_per_v: float = Field(50.0, gt=0, description="amplifier+shaker gain [N/V]")
    axis: str = Field(pattern=r"^[xy]$")

    @model_validator(mode="after")
    def _check(self) -> AnalogOutput:
        if self.kind is not ChannelKind.SHAKER_DRIVE:
            raise ValueError(f"kind {self.kind.value!r} is not an analog-output kind")
        if self.units != "V":
            raise ValueError(f"units {self.units!r} not allowed for an analog output (use 'V')")
        lo, hi = self.range_v
        if not lo < hi:
            raise ValueError(f"range_v {self.range_v} must be (min, max) with min < max")
        return self


class DigitalOutput(_Strict):
    name: Name
    physical_channel: str = Field(description="e.g. Dev1/port0/line0")
    kind: ChannelKind = ChannelKind.RELAY
    units: str = "bool"

    @model_validator(mode="after")
    def _check(self) -> DigitalOutput:
        if self.kind is not ChannelKind.RELAY:
            raise ValueError(f"kind {self.kind.value!r} is not a digital-output kind")
        if self.units != "bool":
            raise ValueError(f"units {self.units!r} not allowed for a relay (use 'bool')")
        return self


class EmergencyStopInput(_Strict):
    """The emergency-stop input: a digital line read once per block (software-timed)."""

    name: Name = "estop"
    physical_channel: str = Field(description="e.g. Dev1/port0/line1")
    pressed_level: bool = Field(
        False, description="the level that means pressed; False (default) suits a normally "
                           "closed loop, so a broken wire reads as pressed")


class ChannelMap(_Strict):
    """The whole acquisition configuration: board, sample clock and every channel."""

    device: DeviceSpec = DeviceSpec()
    sample_rate_hz: float = Field(10_000.0, gt=0, description="shared AI/AO sample clock [S/s]")
    grpc_target: str | None = Field(
        None, description="host:port of an NI gRPC Device Server; None for the local driver"
    )
    ai: tuple[AnalogInput, ...]
    ao: tuple[AnalogOutput, ...]
    do: tuple[DigitalOutput, ...] = ()
    estop: EmergencyStopInput | None = Field(
        None, description="optional emergency-stop input: pressed ramps the drives down and "
                          "latches a fault until reset")

    @field_validator("grpc_target")
    @classmethod
    def _grpc_target(cls, target: str | None) -> str | None:
        if target is not None and (problem := grpc_target_problem(target)):
            raise ValueError(f"{problem}; leave grpc_target out for the local driver")
        return target

    @model_validator(mode="after")
    def _consistent(self) -> ChannelMap:
        dev = self.device
        if not dev.min_rate_hz <= self.sample_rate_hz <= dev.max_rate_hz:
            raise ValueError(
                f"sample_rate_hz = {self.sample_rate_hz:g} is outside what the {dev.product} "
                f"can do ({dev.min_rate_hz:g} to {dev.max_rate_hz:g} S/s)"
            )
        problems: list[str] = []
        names: set[str] = set()
        physical: dict[str, str] = {}
        valid = {
            "ai": set(dev.ai_channels()),
            "ao": set(dev.ao_channels()),
            "do": set(dev.do_lines()),
        }
        groups: dict[str, tuple[Any, ...]] = {"ai": self.ai, "ao": self.ao, "do": self.do,
                                              "estop": (self.estop,) if self.estop else ()}
        valid["estop"] = valid["do"]  # port lines are inputs or outputs
        for group, chans in groups.items():
            for i, ch in enumerate(chans):
                where = f"{group}[{i}] ({ch.name})"
                if ch.name in names:
                    problems.append(f"{where}: duplicate channel name {ch.name!r}")
                names.add(ch.name)
                if ch.physical_channel in physical:
                    problems.append(
                        f"{where}: duplicate physical_channel {ch.physical_channel!r} "
                        f"(also {physical[ch.physical_channel]})")
                physical.setdefault(ch.physical_channel, where)
                if ch.physical_channel not in valid[group]:
                    problems.append(
                        f"{where}: physical_channel {ch.physical_channel!r} is not a "
                        f"{'digital line' if group == 'estop' else group.upper() + ' channel'} "
                        f"of device {dev.name} ({dev.product})"
                    )
                rng = dev.ai_range_v if group == "ai" else dev.ao_range_v
                if group not in ("do", "estop") and (ch.range_v[0] < -rng or ch.range_v[1] > rng):
                    problems.append(
                        f"{where}: range_v {ch.range_v} exceeds the board's +/-{rng:g} V"
                    )
        driven: dict[str, str] = {}
        for i, ao in enumerate(self.ao):
            if ao.axis in driven:
                problems.append(f"ao[{i}] ({ao.name}): axis {ao.axis!r} is driven by "
                                f"{driven[ao.axis]} already: one drive per axis")
            driven.setdefault(ao.axis, f"ao[{i}] ({ao.name})")
        if problems:
            raise ValueError("\n".join(problems))
        return self

    # --- lookups -------------------------------------------------------------------------
    @property
    def ai_names(self) -> list[str]:
        return [c.name for c in self.ai]

    @property
    def ao_names(self) -> list[str]:
        return [c.name for c in self.ao]

    def ai_index(self, name: str) -> int:
        for i, c in enumerate(self.ai):
            if c.name == name:
                return i
        raise KeyError(f"no analog input named {name!r} (have {self.ai_names})")

    def ai_channel(self, name: str) -> AnalogInput:
        return self.ai[self.ai_index(name)]

    def ai_of_kind(self, kind: ChannelKind) -> list[AnalogInput]:
        return [c for c in self.ai if c.kind is kind]

    def ao_for_axis(self, axis: str) -> int:
        for i, c in enumerate(self.ao):
            if c.axis == axis:
                return i
        raise KeyError(f"no shaker drive for axis {axis!r}")

    def relay(self, name: str = "pump") -> DigitalOutput:
        for c in self.do:
            if c.name == name:
                return c
        raise KeyError(f"no relay named {name!r} (have {[c.name for c in self.do]})")

    def to_engineering(self, volts: np.ndarray) -> np.ndarray:
        """Convert an AI block of shape (n_ai, n) from volts to engineering units."""
        gains = np.array([c.gain_v_per_unit for c in self.ai])[:, None]
        offsets = np.array([c.offset_v for c in self.ai])[:, None]
        return (volts - offsets) / gains

    def to_json_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json")

    def to_toml(self) -> str:
        """The map as TOML; `load_channel_map` reads it back to an equal map."""
        return to_toml(self.model_dump(mode="json", exclude_none=True))


# Probe gains from Table A1 (mV/mil -> V/m): 202, 195, 204 mV/mil; Y2 not given, nominal 200.
_MIL = 25.4e-6


def default_channel_map() -> ChannelMap:
    """The report's rig: 14 AI channels, two shaker drives and the pump relay on Dev1."""

    def ai(i: int, name: str, kind: ChannelKind, units: str, gain: float, offset: float = 0.0,
           sensor: str = "") -> AnalogInput:
        return AnalogInput(name=name, physical_channel=f"Dev1/ai{i}", kind=kind, units=units,
                           gain_v_per_unit=gain, offset_v=offset, sensor=sensor)

    k = ChannelKind
    # 4-20 mA across 250 ohm = 1-5 V over 0-206.8 kPa (0-30 psig): 4 V / 206.8 kPa.
    p_gain = 4.0 / 206_843.0
    return ChannelMap(
        ai=(
            ai(0, "fx", k.LOAD_CELL, "N", 0.02, sensor="load cell X, 20 mV/N"),
            ai(1, "fy", k.LOAD_CELL, "N", 0.02, sensor="load cell Y, 20 mV/N"),
            ai(2, "x1", k.EDDY_CURRENT_PROBE, "m", 0.202 / _MIL, sensor="H-108912"),
            ai(3, "x2", k.EDDY_CURRENT_PROBE, "m", 0.195 / _MIL, sensor="H-108877"),
            ai(4, "y1", k.EDDY_CURRENT_PROBE, "m", 0.204 / _MIL, sensor="H-108913"),
            ai(5, "y2", k.EDDY_CURRENT_PROBE, "m", 0.200 / _MIL, sensor="H-108914 (nominal)"),
            ai(6, "ax", k.ACCELEROMETER, "m/s^2", 0.1 / 9.80665, sensor="100 mV/g"),
            ai(7, "ay", k.ACCELEROMETER, "m/s^2", 0.1 / 9.80665, sensor="100 mV/g"),
            ai(8, "p_in", k.PRESSURE_4_20MA, "Pa", p_gain, 1.0, sensor="Omega PX-215, 250 ohm"),
            ai(9, "p_rec", k.PRESSURE_4_20MA, "Pa", p_gain, 1.0, sensor="Omega PX-215, 250 ohm"),
            ai(10, "q_in", k.FLOW, "L/min", 10.0 / 11.36, sensor="turbine 0.3-3 GPM, 0-10 V"),
            ai(11, "q_out", k.FLOW, "L/min", 10.0 / 11.36, sensor="turbine 0.3-3 GPM, 0-10 V"),
            ai(12, "t_oil", k.THERMOCOUPLE, "degC", 0.01, sensor="type K, 10 mV/degC"),
            ai(13, "hammer", k.LOAD_CELL, "N", 0.0023, sensor="impact hammer, 2.3 mV/N"),
        ),
        ao=(
            AnalogOutput(name="shaker_x", physical_channel="Dev1/ao0", axis="x"),
            AnalogOutput(name="shaker_y", physical_channel="Dev1/ao1", axis="y"),
        ),
        do=(DigitalOutput(name="pump", physical_channel="Dev1/port0/line0"),),
    )


_K = ChannelKind
#: The analog inputs the software knows, and what each is. The sweep's control and trips read
#: fx, fy and the probes x1, x2, y1, y2 (`control.run.safety.AxisSignals`); the lubricated
#: sweep waits for p_in; the simulated rig wires each sensor by its name
#: (`rig_model.rig._source_for`); the analysis reads the rest by name.
KNOWN_INPUTS: dict[str, ChannelKind] = {
    "fx": _K.LOAD_CELL, "fy": _K.LOAD_CELL,
    "x1": _K.EDDY_CURRENT_PROBE, "x2": _K.EDDY_CURRENT_PROBE,
    "y1": _K.EDDY_CURRENT_PROBE, "y2": _K.EDDY_CURRENT_PROBE,
    "ax": _K.ACCELEROMETER, "ay": _K.ACCELEROMETER,
    "p_in": _K.PRESSURE_4_20MA, "p_rec": _K.PRESSURE_4_20MA,
    "q_in": _K.FLOW, "q_out": _K.FLOW,
    "t_oil": _K.THERMOCOUPLE,
    "hammer": _K.LOAD_CELL,
}
#: The relays the software switches (`control.run.pump.PumpRelay`).
KNOWN_RELAYS = ("pump",)
#: What a map the software runs with must have, per axis it drives (x, y): the axis's load cell
#: (the force control and the load trip read f<axis>) and a probe (the displacement trip reads
#: <axis>1, <axis>2); and the pump relay (the daemon holds it: its interlock). A one-axis map
#: (one drive) is allowed: the daemon, the structure tests and the commissioning run on it, and
#: a sweep refuses it at its start (it drives both axes).
REQUIRED_PER_AXIS: tuple[tuple[str, str], ...] = (
    ("f{axis}", "the {AXIS} load cell (force control, load trip)"),
    ("{axis}1|{axis}2", "an eddy-current probe on {AXIS} (displacement trip)"),
)
REQUIRED_RELAY = ("pump", "the pump relay (the daemon's interlock)")


def _did_you_mean(name: str, known: list[str], missing: list[str]) -> str:
    """`` (did you mean 'x2'?)``: the closest known name, those the map lacks first."""
    for pool in (missing, known):
        close = difflib.get_close_matches(name, pool, n=1, cutoff=0.5)
        if close:
            return f" (did you mean {close[0]!r}?)"
    return ""


def rig_map_problems(cm: ChannelMap, wiring: bool = False) -> list[str]:
    """What makes ``cm`` unusable as the rig's map, one line per entry: an input name the
    software does not know (with the closest known name), a known name of another kind, a relay
    other than ``pump``; and (unless ``wiring``: the simulated rig's real wiring, where a
    missing sensor is an empty terminal) a required channel missing (`REQUIRED_PER_AXIS`,
    `REQUIRED_RELAY`)."""
    problems: list[str] = []
    names = set(cm.ai_names)
    missing_inputs = [n for n in KNOWN_INPUTS if n not in names]
    for i, ch in enumerate(cm.ai):
        where = f"ai[{i}] ({ch.name})"
        kind = KNOWN_INPUTS.get(ch.name)
        if kind is None:
            same_kind = [n for n in missing_inputs if KNOWN_INPUTS[n] is ch.kind]
            problems.append(
                f"{where}: unknown input name {ch.name!r}"
                f"{_did_you_mean(ch.name, list(KNOWN_INPUTS), same_kind or missing_inputs)}; "
                f"the software knows {', '.join(KNOWN_INPUTS)}")
        elif kind is not ch.kind:
            problems.append(f"{where}: kind {ch.kind.value!r}, but {ch.name} must be kind "
                            f"{kind.value!r}")
    relays = [d.name for d in cm.do]
    for i, d in enumerate(cm.do):
        if d.name not in KNOWN_RELAYS:
            problems.append(
                f"do[{i}] ({d.name}): unknown relay {d.name!r}"
                f"{_did_you_mean(d.name, list(KNOWN_RELAYS), [])}; the software switches "
                f"only {', '.join(KNOWN_RELAYS)}")
    if wiring:
        return problems
    if not cm.ao:
        problems.append("ao: no shaker drive: add one per axis driven ([[ao]] with axis = 'x' "
                        "or 'y')")
    for axis in sorted({ao.axis for ao in cm.ao}):
        drive = next(f"ao[{i}] ({ao.name})" for i, ao in enumerate(cm.ao) if ao.axis == axis)
        for pattern, what in REQUIRED_PER_AXIS:
            wanted = pattern.format(axis=axis).split("|")
            if not names & set(wanted):
                problems.append(f"ai: missing {what.format(AXIS=axis.upper())} for {drive}: "
                                f"add an input named {' or '.join(wanted)}")
    relay, what = REQUIRED_RELAY
    if relay not in relays:
        problems.append(f"do: missing {what}: add a relay named {relay}")
    return problems


def channel_map_from_dict(data: dict[str, Any], source: str = "<dict>", *,
                          strict: bool = False, wiring: bool = False) -> ChannelMap:
    """The map in ``data``; ``strict``: also `rig_map_problems` (``wiring``: as a wiring map),
    raising `ChannelConfigError` with one line per problem, each led by ``source``."""
    cm = validate(ChannelMap, data, "channel map", source, ChannelConfigError)
    if strict:
        problems = rig_map_problems(cm, wiring)
        if problems:
            err = ChannelConfigError("\n".join([f"invalid channel map in {source}:"]
                                                + [f"  {p}" for p in problems]))
            err.problems = tuple(f"{source}: {p}" for p in problems)
            raise err
    return cm


def load_channel_map(path: str | Path, *, wiring: bool = False) -> ChannelMap:
    """Load a channel map from TOML, strictly (`rig_map_problems`); raise `ChannelConfigError`
    naming the file, the entry and the value. ``wiring``: the simulated rig's real wiring (a
    sim-server's ``--channels``, commission's ``--wiring``), where any channel may be missing."""
    return channel_map_from_dict(read_toml(path, ChannelConfigError), str(path), strict=True,
                                 wiring=wiring)
