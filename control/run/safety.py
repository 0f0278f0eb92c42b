"""Safety limits, the per-block limit monitor and the check of targets before a run.

Limits (all configurable, `SafetyLimits`): drive volts, load (the shaker's 448 N rating or lower),
displacement (default half the 127 um radial clearance), the drive's envelope rate and its
sample-to-sample slew, the permitted frequency range, the fade time of a safe shutdown, the
open-loop check and the pump interlock. A trip anywhere makes the sweep engine stop both drives:
the AO already queued is dropped and the drives are at 0 V from the end of the block the trip was
seen in (`DriveStream.shutdown` with ``cut``). Where the board cannot drop it (no AO idle output
0 V), the queue plays out and the fade follows, so ``block_s * (1 + ahead_blocks) + fade_s`` must
stay within the 100 ms budget.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from control.run.errors import LimitTrip
from control.signal.controller import orbit_peak_radius
from control.wire.errors import TargetError
from control.wire.step_plan import StepPlan
from daq.channels import ChannelKind, ChannelMap

#: Time from a trip to zero drive that the engine guarantees [s].
SHUTDOWN_BUDGET_S = 0.1
#: An orbit radius at this fraction of the radial clearance is journal-housing contact: a fault.
CONTACT_FRACTION = 0.97
#: A block whose orbit and loads stay under this fraction of their trip levels leaves room to
#: read the next ones several at a time while the drive is held (`SafetyMonitor.headroom`,
#: `control.run.stream.HELD_READ_BLOCKS`): each sample is still checked, up to 40 ms later, and
#: an outside change that triples the response (bench_trip's amplifier knob, at once or over
#: a ramp) still leaves it under the limits. At 85 % of them, through the 2 s ring, a x3 over
#: 0.1 s peaked at 1.99x the displacement limit (X 30 um, 40 Hz) where block by block it stops
#: at 1.03x.
HEADROOM_FRACTION = 1 / 3


class SafetyLimits(BaseModel):
    """Every safety limit of a sweep; defaults are the report's rig."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    shaker_rating_n: float = Field(448.0, gt=0, description="shaker force rating (100 lbf) [N]")
    max_load_n: float = Field(448.0, gt=0, description="trip when |fx| or |fy| exceeds it [N]")
    radial_clearance_m: float = Field(127e-6, gt=0, description="SFD radial clearance c [m]")
    max_displacement_m: float | None = Field(
        None, gt=0, description="trip on the orbit radius; None: half the clearance [m]"
    )
    max_drive_v: float = Field(9.0, gt=0, le=10.0, description="largest drive amplitude [V]")
    max_drive_rate_v_per_s: float = Field(
        50.0, gt=0, description="largest rate of change of a drive's amplitude (ramps) [V/s]"
    )
    max_drive_slew_v_per_s: float | None = Field(
        None, gt=0,
        description="trip when a drive moves faster than this between samples; None: "
                    "1.25 x 2 pi max_freq_hz max_drive_v [V/s]",
    )
    min_freq_hz: float = Field(5.0, gt=0, description="lowest permitted excitation [Hz]")
    max_freq_hz: float = Field(500.0, gt=0, description="highest permitted excitation [Hz]")
    fade_s: float = Field(
        0.04, gt=0, le=0.08,
        description="ramp to zero on a stop (abort, pause, an error); on a trip only where "
                    "the board cannot drop its queued AO (overrides max_drive_rate_v_per_s) [s]",
    )
    open_loop_min_ratio: float = Field(
        0.2, gt=0, lt=1, description="open loop when measured load < ratio x nominal load"
    )
    open_loop_min_load_n: float = Field(
        2.0, gt=0, description="the open-loop check needs at least this nominal load [N]"
    )
    min_inlet_pressure_pa: float = Field(
        10e3, gt=0, description="interlock: inlet pressure p_in a lubricated sweep needs [Pa]"
    )
    pressure_wait_s: float = Field(
        10.0, gt=0, le=120, description="interlock: longest wait for the pressure to build [s]"
    )
    min_running_pressure_pa: float = Field(
        5e3, gt=0, description="interlock: a lubricated sweep trips when the inlet pressure "
                               "(block mean) falls below this while running [Pa]"
    )
    film_prime_s: float = Field(
        5.0, ge=0, le=120, description="zero-drive time after the pressure is reached, for the "
                                       "film to fill [s]"
    )

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        if self.max_load_n > self.shaker_rating_n:
            raise ValueError(
                f"max_load_n = {self.max_load_n:g} N exceeds the shaker rating "
                f"{self.shaker_rating_n:g} N"
            )
        if self.displacement_limit_m >= CONTACT_FRACTION * self.radial_clearance_m:
            raise ValueError(
                f"max_displacement_m = {self.displacement_limit_m * 1e6:.4g} um reaches the "
                f"journal (contact at {CONTACT_FRACTION * self.radial_clearance_m * 1e6:.4g} um "
                f"of the {self.radial_clearance_m * 1e6:.4g} um clearance)"
            )
        if self.min_freq_hz >= self.max_freq_hz:
            raise ValueError(
                f"min_freq_hz = {self.min_freq_hz:g} must be below max_freq_hz = "
                f"{self.max_freq_hz:g}"
            )
        return self

    @property
    def displacement_limit_m(self) -> float:
        """The displacement trip level [m]."""
        if self.max_displacement_m is not None:
            return self.max_displacement_m
        return 0.5 * self.radial_clearance_m

    @property
    def slew_limit_v_per_s(self) -> float:
        """The drive slew trip level [V/s]."""
        if self.max_drive_slew_v_per_s is not None:
            return self.max_drive_slew_v_per_s
        return 1.25 * 2 * math.pi * self.max_freq_hz * self.max_drive_v


def validate_targets(
    steps: Sequence[StepPlan], limits: SafetyLimits, channel_map: ChannelMap
) -> None:
    """Refuse a sweep that must not run, before any output is written.

    Raises
    ------
    TargetError
        Naming every offending step and why: non-positive amplitude, frequency above a quarter
        of the sample rate or outside [min_freq_hz, max_freq_hz], displacement over the limit,
        load over the shaker rating or the configured maximum.
    """
    fs = channel_map.sample_rate_hz
    problems: list[str] = []
    if not steps:
        problems.append("the sweep has no steps")
    for st in steps:
        where = st.describe()
        amps = np.abs(st.shape)
        if not math.isfinite(st.target_value) or st.target_value <= 0:
            problems.append(f"{where}: amplitude must be positive, got {st.target_value!r}")
            continue
        if not math.isfinite(st.freq_hz) or st.freq_hz <= 0:
            problems.append(f"{where}: frequency must be positive, got {st.freq_hz!r} Hz")
            continue
        if st.freq_hz > fs / 4:
            problems.append(
                f"{where}: {st.freq_hz:g} Hz is above a quarter of the sample rate "
                f"({fs / 4:g} Hz at {fs:g} S/s)"
            )
        if not limits.min_freq_hz <= st.freq_hz <= limits.max_freq_hz:
            problems.append(
                f"{where}: {st.freq_hz:g} Hz is outside the permitted range "
                f"{limits.min_freq_hz:g}-{limits.max_freq_hz:g} Hz"
            )
        if st.target_kind == "displacement":
            lim = limits.displacement_limit_m
            peak = orbit_peak_radius(st.shape)
            if peak > lim:
                problems.append(
                    f"{where}: displacement {peak * 1e6:.4g} um exceeds the limit "
                    f"{lim * 1e6:.4g} um"
                )
        else:
            peak = float(amps.max())
            if peak > limits.shaker_rating_n:
                problems.append(
                    f"{where}: load {peak:.4g} N exceeds the shaker rating "
                    f"{limits.shaker_rating_n:.4g} N"
                )
            elif peak > limits.max_load_n:
                problems.append(
                    f"{where}: load {peak:.4g} N exceeds the configured limit "
                    f"{limits.max_load_n:.4g} N"
                )
    if problems:
        raise TargetError("sweep refused:\n  " + "\n  ".join(problems))


class SafetyMonitor:
    """Checks every block against the limits: AO before it is written, AI as it arrives.

    Parameters
    ----------
    limits : SafetyLimits
    channel_map : ChannelMap
        Finds the load cells (kind load_cell, names fx/fy) and the probes (x*, y*).
    """

    def __init__(self, limits: SafetyLimits, channel_map: ChannelMap) -> None:
        self.limits = limits
        self.fs = channel_map.sample_rate_hz
        self.signals = AxisSignals.from_channel_map(channel_map)
        self._last_ao: np.ndarray | None = None
        #: row of p_in, set (by the engine) once a lubricated run is primed: pressure is watched
        self.pressure_row: int | None = None
        #: the last AI block checked kept its orbit and loads under `HEADROOM_FRACTION` of
        #: their trip levels (False until a block is checked, and after any limit trip)
        self.headroom = False

    @property
    def last_ao(self) -> np.ndarray | None:
        """The last drive sample checked, shape (n_ao, 1): the slew check's reference for the
        next block (a stream that drops blocks it had written sets it back)."""
        return self._last_ao

    @last_ao.setter
    def last_ao(self, value: np.ndarray | None) -> None:
        self._last_ao = None if value is None else np.asarray(value)[:, -1:].copy()

    def check_ao(self, block: np.ndarray, first_sample: int) -> None:
        """Raise `LimitTrip` if a drive block to be written breaks the volt or slew limit."""
        self.check_ao_after(block, first_sample, self._last_ao)
        self._last_ao = block[:, -1:].copy()

    def check_ao_after(self, block: np.ndarray, first_sample: int,
                       prev: np.ndarray | None) -> None:
        """`check_ao` for a block that follows ``prev`` (the drive before it, or None),
        leaving the monitor's own reference alone: a prediction written ahead of the lead."""
        lim = self.limits
        peak = np.abs(block).max(axis=1)
        if np.any(peak > lim.max_drive_v + 1e-9):
            row = int(np.argmax(peak))
            k = int(np.argmax(np.abs(block[row]) > lim.max_drive_v + 1e-9))
            raise LimitTrip(
                f"drive {row} would reach {peak[row]:.3f} V, above the {lim.max_drive_v:g} V "
                "limit", first_sample + k, "drive_v",
            )
        ext = block if prev is None else np.concatenate([prev[:, -1:], block], axis=1)
        if ext.shape[1] > 1:
            slew = np.abs(np.diff(ext, axis=1)) * self.fs
            smax = float(slew.max())
            if smax > lim.slew_limit_v_per_s:
                idx = np.unravel_index(int(np.argmax(slew)), slew.shape)
                row, k = int(idx[0]), int(idx[1])
                raise LimitTrip(
                    f"drive {row} would slew at {smax:.4g} V/s, above the "
                    f"{lim.slew_limit_v_per_s:.4g} V/s limit",
                    first_sample + k - (0 if prev is None else 1), "drive_slew",
                )

    def contact(self, eng: np.ndarray, first_sample: int) -> tuple[int, str] | None:
        """(sample, message) of the first journal-housing contact in the block, or None.

        Contact: the measured orbit radius reaches `CONTACT_FRACTION` of the radial clearance
        (the probes' gain and the journal's runout leave a few percent of doubt)."""
        disp = self.signals.displacement(eng)
        radius = np.hypot(disp[0], disp[1])
        level = CONTACT_FRACTION * self.limits.radial_clearance_m
        hit = np.flatnonzero(radius >= level)
        if hit.size == 0:
            return None
        k = int(hit[0])
        return first_sample + k, (
            f"journal-housing contact: orbit radius {radius[k] * 1e6:.1f} um at the "
            f"{self.limits.radial_clearance_m * 1e6:.4g} um clearance")

    def check_ai(self, eng: np.ndarray, first_sample: int) -> None:
        """Raise `LimitTrip` at the first sample whose load or orbit radius is over its limit,
        or when the inlet pressure of a lubricated run is lost (`pressure_row` set)."""
        lim = self.limits
        sig = self.signals
        self.headroom = False
        if self.pressure_row is not None:
            p = float(np.mean(eng[self.pressure_row]))
            if p < lim.min_running_pressure_pa:
                raise LimitTrip(
                    f"inlet pressure lost: p_in = {p / 1e3:.2f} kPa, below "
                    f"{lim.min_running_pressure_pa / 1e3:.2f} kPa while running lubricated",
                    first_sample, "pressure",
                )
        touched = self.contact(eng, first_sample)
        if touched is not None:
            raise LimitTrip(touched[1], touched[0], "contact")
        disp = sig.displacement(eng)
        radius = np.hypot(disp[0], disp[1])
        loads = np.abs(eng[sig.load_rows])
        peak_load, peak_radius = float(loads.max()), float(radius.max())
        if peak_load <= lim.max_load_n and peak_radius <= lim.displacement_limit_m:
            self.headroom = (peak_load < HEADROOM_FRACTION * lim.max_load_n
                             and peak_radius < HEADROOM_FRACTION * lim.displacement_limit_m)
            return
        over = loads > lim.max_load_n
        first = _first_true(over)
        over_d = radius > lim.displacement_limit_m
        first_d = _first_true(over_d[None, :])
        if first is None and first_d is None:
            return
        if first_d is None or (first is not None and first[1] <= first_d[1]):
            assert first is not None
            row, k = first
            name = sig.load_names[row]
            raise LimitTrip(
                f"load {name} = {eng[sig.load_rows[row], k]:.1f} N exceeds the "
                f"{lim.max_load_n:g} N limit", first_sample + k, "load_n",
            )
        k = first_d[1]
        raise LimitTrip(
            f"displacement {radius[k] * 1e6:.1f} um (orbit radius) exceeds the "
            f"{lim.displacement_limit_m * 1e6:.4g} um limit", first_sample + k, "displacement_m",
        )


def _first_true(mask: np.ndarray) -> tuple[int, int] | None:
    """(row, column) of the earliest True (smallest column), or None."""
    if not mask.any():
        return None
    cols = np.where(mask.any(axis=0))[0]
    k = int(cols[0])
    row = int(np.argmax(mask[:, k]))
    return row, k


class AxisSignals:
    """Which AI rows measure the X and Y displacement and load.

    Displacement along an axis is the mean of the eddy-current probes whose names start with that
    axis letter (x1, x2 -> x); load is the load cell named f<axis> (fx, fy).
    """

    def __init__(
        self, names: list[str], probe_rows: tuple[list[int], list[int]],
        load_rows: list[int], load_names: list[str],
    ) -> None:
        self.names = names
        self.probe_rows = probe_rows
        self.load_rows = load_rows
        self.load_names = load_names
        # (2, n_ai) averaging matrix: displacement = W @ eng
        self._w = np.zeros((2, len(names)))
        for axis, rows in enumerate(probe_rows):
            self._w[axis, rows] = 1.0 / len(rows)

    @classmethod
    def from_channel_map(cls, cm: ChannelMap) -> AxisSignals:
        probes: tuple[list[int], list[int]] = ([], [])
        loads: list[int] = []
        load_names: list[str] = []
        for i, ch in enumerate(cm.ai):
            if ch.kind is ChannelKind.EDDY_CURRENT_PROBE and ch.name[0] in "xy":
                probes["xy".index(ch.name[0])].append(i)
        for axis in "xy":
            name = f"f{axis}"
            try:
                idx = cm.ai_index(name)
            except KeyError:
                raise TargetError(f"channel map has no load cell named {name!r}") from None
            if cm.ai[idx].kind is not ChannelKind.LOAD_CELL:
                raise TargetError(f"channel {name!r} is not a load cell")
            loads.append(idx)
            load_names.append(name)
        for axis, rows in zip("xy", probes, strict=True):
            if not rows:
                raise TargetError(f"channel map has no eddy-current probe for axis {axis}")
        return cls(cm.ai_names, probes, loads, load_names)

    def displacement(self, eng: np.ndarray) -> np.ndarray:
        """(2, n) mean probe displacement X, Y [m] from an engineering block (n_ai, n)."""
        return self._w @ eng

    def load(self, eng: np.ndarray) -> np.ndarray:
        """(2, n) load X, Y [N]."""
        return eng[self.load_rows]

    def controlled(self, eng: np.ndarray, kind: str) -> np.ndarray:
        """(2, n) the controlled quantity ("displacement" or "load")."""
        return self.displacement(eng) if kind == "displacement" else self.load(eng)
