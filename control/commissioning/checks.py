"""What `control.commissioning.procedure` concludes from what it measured: each input at rest
against its
sensor's expectations, and each sensor's response to a small drive against physics, as one-line
findings and proposed corrections to the channel map.

At rest, per kind (the map's ``kind``): load cells and accelerometers near 0 (AC-coupled), a
probe's gap voltage negative, near the map's ``offset_v`` and far enough inside the range for the
clearance's motion, a 4-20 mA loop's 4 mA, flow 0 with the pump off, the oil at room temperature,
the noise of each under a bound; nothing at a range limit.

Under a drive of amplitude F on one axis at w (below the ~45 Hz resonance), with the nominal rig
(K along the axis, M, C), the expected 1X, referred to the drive written: the load cell on that
axis F = g_amp V (the map's ``nominal_force_n_per_v``), the probes x = F / (K - w^2 M + i w C)
and the accelerometer a = -w^2 x; the other axis's sensors little. A sensor that does not respond
while its opposite number responds to the other shaker is swapped with it; one that responds to
neither is dead; its sign is voted on by the drive and the axis's other sensors (a minority of
one is inverted; all sensors against the drive: the amplifier or shaker is); its size against the
median of the same (a load cell, probe or accelerometer outside 0.4-2.5 of it has a wrong gain,
the amplifier outside 1/3-3 a wrong ``nominal_force_n_per_v``). The model's K and M are good to
tens of percent, so the bands are wide: they catch a gain off by 10x, not by 10 %.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from daq.channels import AnalogInput, ChannelKind, ChannelMap
from daq.device_check import LiveValues
from daq.map_edits import Correction

K = ChannelKind
#: the sensors a drive must move, by kind
RESPONDING = (K.LOAD_CELL, K.EDDY_CURRENT_PROBE, K.ACCELEROMETER)
GAIN_BAND = (0.4, 2.5)  # a sensor's size against the axis's median
DRIVE_BAND = (1 / 3, 3.0)  # the amplifier's gain against the map's nominal_force_n_per_v
PROBE_PAIR_BAND = (0.8, 1.25)  # two probes on one axis
RESPONSE_FRACTION = 0.02  # a response under this fraction of the expected is none (a 10x
#: or 30x wrong gain still responds)
RESPONSE_SIGMAS = 6.0  # ... or under this many standard errors of the lock-in


@dataclass(frozen=True)
class Finding:
    """One line of the verdict: ``level`` "fail", "warn" or "ok"; ``where`` names the channel
    (and its terminal) or the part tested."""

    level: str
    where: str
    text: str

    def line(self) -> str:
        return f"{self.level.upper():4} {self.where}: {self.text}"


@dataclass
class Response:
    """One input's 1X under one drive, in its engineering units, against what it should read
    were it on the driven axis (``expected``, referred to the drive's phase)."""

    z: complex
    sigma: float
    expected: complex

    @property
    def responds(self) -> bool:
        return abs(self.z) > max(RESPONSE_SIGMAS * self.sigma,
                                 RESPONSE_FRACTION * abs(self.expected))

    @property
    def ratio(self) -> complex:
        return self.z / self.expected


@dataclass
class Verdict:
    findings: list[Finding] = field(default_factory=list)
    corrections: list[Correction] = field(default_factory=list)

    @property
    def failed(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "fail"]


def where(ch: Any) -> str:
    return f"{ch.name} ({ch.physical_channel})"


def axis_of(ch: AnalogInput) -> str | None:
    """The axis a sensor measures, by the software's names (fx, x1, x2, ax; fy, y1, ...)."""
    if ch.kind not in RESPONDING or ch.name == "hammer":
        return None
    if ch.kind is K.EDDY_CURRENT_PROBE:
        return "y" if ch.name.startswith("y") else "x"
    return "y" if "y" in ch.name else "x"


def _show(ch: AnalogInput, value: float) -> str:
    unit, factor = {"m": ("um", 1e6), "Pa": ("kPa", 1e-3)}.get(ch.units, (ch.units, 1.0))
    return f"{value * factor:.3g} {unit}"


# --- at rest --------------------------------------------------------------------------------
#: kind -> (largest |mean| at rest, largest standard deviation), engineering units
REST_LIMITS: dict[ChannelKind, tuple[float, float]] = {
    K.LOAD_CELL: (5.0, 1.0),
    K.ACCELEROMETER: (1.0, 0.5),
    K.EDDY_CURRENT_PROBE: (float("inf"), 1e-6),
    K.PRESSURE_4_20MA: (20e3, 5e3),
    K.FLOW: (0.2, 0.1),
    K.THERMOCOUPLE: (float("inf"), 1.0),
}
ROOM_C = (5.0, 50.0)
GAP_MATCH_V = 0.1  # a probe's gap voltage this far from offset_v (~12 um): correct offset_v
DEAD_V = 0.3  # an input this close to 0 V where its sensor's output cannot be


def judge_rest(cm: ChannelMap, rest: LiveValues, clearance_m: float) -> Verdict:
    """Each input at rest against its sensor's expectations: at most one finding per input
    (the worst), and the ``offset_v`` corrections of probes whose gap voltage moved."""
    v = Verdict()
    for i, ch in enumerate(cm.ai):
        lo, hi = ch.range_v
        edge = 0.001 * (hi - lo)
        mean, std, mv = float(rest.mean[i]), float(rest.std[i]), float(rest.mean_v[i])
        at_limit = rest.min_v[i] <= lo + edge or rest.max_v[i] >= hi - edge
        max_mean, max_std = REST_LIMITS[ch.kind]
        text, level = "", "fail"
        if ch.kind is K.EDDY_CURRENT_PROBE:
            text, level = _probe_at_rest(ch, mv, at_limit, clearance_m, v)
        elif at_limit:
            text = (f"reads {mv:+.3f} V, at the limit of its range {lo:g} to {hi:g} V: "
                    "clipped (the wrong range, or the sensor out of its own)")
        elif ch.kind is K.PRESSURE_4_20MA and abs(mv) < DEAD_V and ch.offset_v > 2 * DEAD_V:
            text = (f"reads {mv:+.3f} V where the 4 mA of an unpressurised loop is "
                    f"{ch.offset_v:g} V: the loop is open (a cut wire, no loop supply)")
        elif ch.kind is K.THERMOCOUPLE and not ROOM_C[0] <= mean <= ROOM_C[1]:
            text = (f"reads {mean:.1f} degC ({mv:+.3f} V) at rest, not a room temperature: "
                    "check the transmitter and its gain")
        elif abs(mean) > max_mean:
            text = (f"reads {_show(ch, mean)} ({mv:+.3f} V) at rest with nothing driven, over "
                    f"the {_show(ch, max_mean)} its sensor allows: an offset in its "
                    "conditioner, or another signal on this terminal")
        if not text and std > max_std:
            text = (f"noise {_show(ch, std)} rms at rest, over the {_show(ch, max_std)} its "
                    "sensor allows: a ground loop, a floating input or a loose connector")
        if text:
            v.findings.append(Finding(level, where(ch), text))
        else:
            v.findings.append(Finding("ok", where(ch), f"at rest {_show(ch, mean)} "
                                      f"({mv:+.3f} V), noise {_show(ch, std)} rms"))
    return v


def _probe_at_rest(ch: AnalogInput, mv: float, at_limit: bool, clearance_m: float,
                   v: Verdict) -> tuple[str, str]:
    lo, hi = ch.range_v
    swing = ch.gain_v_per_unit * clearance_m
    if abs(mv) < DEAD_V:
        return (f"reads {mv:+.3f} V where its gap voltage should be about {ch.offset_v:+.2f} V: "
                "a dead probe (proximitor unpowered, cable open) or nothing on this terminal",
                "fail")
    if mv > 0 > ch.offset_v:
        return (f"reads {mv:+.2f} V, a proximitor's output is negative (the map: "
                f"{ch.offset_v:+.2f} V): inverted, AI+ and AI- swapped", "fail")
    if at_limit or mv - swing < lo or mv + swing > hi:
        return (f"gap voltage {mv:+.2f} V is out of range: the clearance's motion needs "
                f"+/-{swing:.2f} V ({clearance_m * 1e6:.0f} um at "
                f"{ch.gain_v_per_unit * 1e-3:.2f} V/mm) inside {lo:g} to {hi:g} V: set the "
                f"probe's gap so it reads about {0.85 * lo:+.1f} V", "fail")
    if abs(mv - ch.offset_v) > GAP_MATCH_V:
        v.corrections.append(Correction("ai", ch.name, "offset_v", round(mv, 3),
                                        f"its gap voltage at rest is {mv:+.3f} V"))
        return (f"gap voltage {mv:+.3f} V, the map's offset_v {ch.offset_v:+.3f} V: it would "
                f"read {(mv - ch.offset_v) / ch.gain_v_per_unit * 1e6:+.0f} um at rest; offset_v "
                "corrected in the proposed map", "warn")
    return "", "ok"


# --- under a drive ---------------------------------------------------------------------------
@dataclass
class Plant:
    """The nominal rig the expectations come from (journal out: the rods alone)."""

    mass_kg: float = 9.7
    stiffness_n_per_m: tuple[float, float] = (788e3, 823e3)  # x, y
    damping_ns_per_m: float = 370.0

    def receptance(self, axis: str, freq_hz: float) -> complex:
        w = 2 * math.pi * freq_hz
        k = self.stiffness_n_per_m[0 if axis == "x" else 1]
        return 1.0 / complex(k - w * w * self.mass_kg, w * self.damping_ns_per_m)

    def natural_hz(self) -> float:
        return math.sqrt(min(self.stiffness_n_per_m) / self.mass_kg) / (2 * math.pi)


def expected_response(ch: AnalogInput, axis: str, force: complex, freq_hz: float,
                      plant: Plant) -> complex:
    """What ``ch`` reads on ``axis`` driven by ``force`` (its kind's quantity there)."""
    if ch.kind is K.LOAD_CELL:
        return force
    x = force * plant.receptance(axis, freq_hz)
    if ch.kind is K.EDDY_CURRENT_PROBE:
        return x
    w = 2 * math.pi * freq_hz
    return -w * w * x


def _deg(z: complex) -> float:
    return math.degrees(cmath.phase(z))


def judge_drives(cm: ChannelMap, responses: dict[str, dict[str, Response]],
                 forces: dict[str, complex], freq_hz: float) -> Verdict:
    """Swapped, dead, inverted and wrongly scaled sensors from the responses to each axis's
    drive (``responses[axis][channel]``; ``forces[axis]`` the force the drive should give)."""
    v = Verdict()
    sensors = [ch for ch in cm.ai if axis_of(ch) is not None]
    driven = set(responses)
    done: set[str] = set()
    for ch in sensors:
        a = axis_of(ch)
        assert a is not None
        if a not in driven or ch.name in done:
            continue
        own = responses[a][ch.name]
        if own.responds:
            continue
        b = "y" if a == "x" else "x"
        cross = responses[b][ch.name] if b in driven else None
        done.add(ch.name)
        if cross is not None and cross.responds:
            partner = next((p for p in sensors if p.kind is ch.kind and axis_of(p) == b
                            and p.name not in done and not responses[b][p.name].responds
                            and responses[a][p.name].responds), None)
            if partner is not None:
                done.add(partner.name)
                v.findings.append(Finding("fail", f"{where(ch)} and {where(partner)}", (
                    f"swapped: driving {a}, {partner.name} moved "
                    f"{_show(ch, abs(responses[a][partner.name].z))} and {ch.name} "
                    f"{_show(ch, abs(own.z))}; driving {b}, {ch.name} moved "
                    f"{_show(ch, abs(cross.z))} and {partner.name} "
                    f"{_show(ch, abs(responses[b][partner.name].z))}: physical_channel "
                    "exchanged in the proposed map (or swap the cables)")))
                v.corrections += [
                    Correction("ai", ch.name, "physical_channel", partner.physical_channel,
                               f"{ch.name}'s sensor answers on {partner.physical_channel}"),
                    Correction("ai", partner.name, "physical_channel", ch.physical_channel,
                               f"{partner.name}'s sensor answers on {ch.physical_channel}")]
            else:
                v.findings.append(Finding("fail", where(ch), (
                    f"reads the {b} drive ({_show(ch, abs(cross.z))}) and not the {a} one "
                    f"({_show(ch, abs(own.z))}, about {_show(ch, abs(own.expected))} "
                    f"expected): a {b} sensor is on this terminal")))
        else:
            v.findings.append(Finding("fail", where(ch), (
                f"does not respond to the {a} drive: {_show(ch, abs(own.z))} at {freq_hz:g} Hz "
                f"where about {_show(ch, abs(own.expected))} is expected: a dead sensor, an "
                "open cable or nothing on this terminal")))
    for a in sorted(driven):
        _sign_and_size(cm, a, [ch for ch in sensors if axis_of(ch) == a and ch.name not in done],
                       responses[a], forces[a], freq_hz, v)
    return v


def _sign_and_size(cm: ChannelMap, axis: str, group: list[AnalogInput],
                   resp: dict[str, Response], force: complex, freq_hz: float,
                   v: Verdict) -> None:
    ao = cm.ao[cm.ao_for_axis(axis)]
    drive_where = f"{ao.name} ({ao.physical_channel})"
    cosines = {ch.name: math.cos(cmath.phase(resp[ch.name].ratio)) for ch in group}
    votes = 1 + sum(1 if c > 0 else -1 for c in cosines.values() if abs(c) >= 0.5)
    flip = votes < 0  # every sensor against the drive: the drive is inverted
    if flip:
        v.findings.append(Finding("fail", drive_where, (
            f"the axis's sensors agree with each other and are 180 deg from the drive: the "
            f"amplifier or the shaker of {axis} is wired inverted (swap the shaker's leads)")))
    sized: list[AnalogInput] = []
    for ch in group:
        c = cosines[ch.name] * (-1 if flip else 1)
        rr = resp[ch.name].ratio * (-1 if flip else 1)
        if abs(c) < 0.5:
            v.findings.append(Finding("fail", where(ch), (
                f"responds at {_deg(rr):+.0f} deg from what the {axis} drive should give (0 or "
                "180): another signal, a delay, or the rig is not what the checks assume "
                "(journal in, a resonance near the test frequency)")))
        elif c < 0:
            v.findings.append(Finding("fail", where(ch), (
                f"inverted: {_deg(rr):+.0f} deg from the {axis} drive and the axis's other "
                "sensors: swap AI+ and AI- at the terminal (or the conditioner's output); the "
                "map cannot invert a sensor")))
        else:
            sized.append(ch)
    mags = [1.0] + [abs(resp[ch.name].ratio) for ch in sized]
    ref = float(np.median(mags))
    for ch in sized:
        r = resp[ch.name]
        q = abs(r.ratio) / ref
        if GAIN_BAND[0] <= q <= GAIN_BAND[1]:
            v.findings.append(Finding("ok", where(ch), (
                f"{_show(ch, abs(r.z))} at {_deg(r.ratio):+.0f} deg for the {axis} drive "
                f"(expected about {_show(ch, abs(r.expected) * ref)}, x{q:.2f})")))
            continue
        new = _corrected_gain(ch.gain_v_per_unit, q)
        v.findings.append(Finding("fail", where(ch), (
            f"reads {_show(ch, abs(r.z))} for the {axis} drive where the drive and the axis's "
            f"other sensors say {_show(ch, abs(r.expected) * ref)}: its gain_v_per_unit "
            f"{ch.gain_v_per_unit:.4g} is {_times(1 / q)} (proposed {new:.4g}; check the "
            "sensor's certificate)")))
        v.corrections.append(Correction("ai", ch.name, "gain_v_per_unit", new,
                                        f"reads {q:.2g}x what the {axis} drive gives"))
    if not DRIVE_BAND[0] <= ref <= DRIVE_BAND[1]:
        lcs = [abs(resp[ch.name].ratio) for ch in sized if ch.kind is K.LOAD_CELL
               and GAIN_BAND[0] <= abs(resp[ch.name].ratio) / ref <= GAIN_BAND[1]]
        gain = ao.nominal_force_n_per_v * (lcs[0] if lcs else ref)
        v.findings.append(Finding("fail", drive_where, (
            f"the rig answers {ref:.2g}x what {abs(force):.3g} N from "
            f"nominal_force_n_per_v {ao.nominal_force_n_per_v:g} N/V should give: the "
            f"amplifier's gain is {gain:.3g} N/V (its knob?); corrected in the proposed map")))
        v.corrections.append(Correction("ao", ao.name, "nominal_force_n_per_v",
                                        float(f"{gain:.3g}"), "measured under the drive"))
    else:
        v.findings.append(Finding("ok", drive_where, (
            f"{abs(force):.3g} N asked at {freq_hz:g} Hz: the sensors say {ref:.2f}x that")))
    probes = [ch for ch in sized if ch.kind is K.EDDY_CURRENT_PROBE
              and GAIN_BAND[0] <= abs(resp[ch.name].ratio) / ref <= GAIN_BAND[1]]
    for i, p in enumerate(probes):
        for q_ in probes[i + 1:]:
            ratio = abs(resp[p.name].z) / abs(resp[q_.name].z)
            if not PROBE_PAIR_BAND[0] <= ratio <= PROBE_PAIR_BAND[1]:
                v.findings.append(Finding("warn", f"{where(p)} and {where(q_)}", (
                    f"read the same motion {ratio:.2f}:1: one gain is off by "
                    f"{abs(ratio - 1) * 100:.0f} %: calibrate the probes (sfdrig structure "
                    "--only probe_calibration, then sfdrig channels calibrate)")))


def _times(q: float) -> str:
    return f"{q:.2g}x too large" if q > 1 else f"{1 / q:.2g}x too small"


def _corrected_gain(gain: float, q: float) -> float:
    """``gain * q``: a sensor reading q times what it should has a true gain q times the map's
    (volts = gain x value). Near a power of ten (a decimal slip: within 20 %) that power
    exactly."""
    decade = 10.0 ** round(math.log10(q))
    if decade != 1 and 0.8 <= q / decade <= 1.25:
        return float(f"{gain * decade:.12g}")
    return float(f"{gain * q:.3g}")
