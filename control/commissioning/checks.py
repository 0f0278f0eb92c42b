"""What `control.commissioning.procedure` concludes from what it measured: each input at rest
against its sensor's expectations, and each sensor's response to a small drive against physics,
as one-line findings and proposed corrections to the channel map.

At rest, per kind (the map's ``kind``): load cells and accelerometers near 0 (AC-coupled), a
probe's gap voltage negative, near the map's ``offset_v`` and far enough inside the range for the
clearance's motion, a 4-20 mA loop's 4 mA, flow 0 with the pump off, the oil at room temperature,
the noise of each under a bound; nothing at a range limit. Two probes whose gap voltages each sit
at the other's ``offset_v`` (and not at their own) are swapped, probes and cables: their
``physical_channel`` is exchanged, never their offsets.

Under a drive of amplitude F on one axis at w (below the ~45 Hz resonance), with the nominal rig
(K along the axis, M, C), the expected 1X, referred to the drive written: the load cell on that
axis F = g_amp V (the map's ``nominal_force_n_per_v``), the probes x = F / (K - w^2 M + i w C)
and the accelerometer a = -w^2 x; the other axis's sensors little. The pattern first: every
sensor of each axis answering the other axis's drive is the two drives swapped (two wires, not
eight); no sensor answering one drive while the other drive works is that drive dead; the load
cells reading their drives while no motion sensor moves is a held housing (the probes' gap
voltages were right at rest, so they are alive). Then each sensor: one that does not respond
while its opposite number responds to the other shaker is swapped with it; one that responds to
neither is dead; its sign is voted on by the drive and the axis's other sensors (a minority of
one is inverted; all sensors against the drive: the amplifier or shaker is).

Sizes, each against the physics to the accuracy that physics has:

- The probes and the accelerometer of one axis see one motion of a rigid housing, and a = -w^2 x
  is exact: each must read within `MOTION_TOL` (10 %) of their median (probes calibrated to a
  few % (Table A1's fits), an accelerometer's certificate to about 5 %; the lock-in's error at
  2 N is about 0.1 %). One outside is named with its measured sensitivity (a probe's gain off 2x,
  an accelerometer 10x): of two probes that disagree, the one the accelerometer's -a/w^2 (and
  the model) does not side with.
- The load cell against that motion through the model, F = (K - w^2 M + i w C) x: K and M are
  good to tens of percent (K from the static tests, M from the impact tests; K - w^2 M at 20 Hz
  amplifies their errors by 1.24), so `MODEL_TOL` is 30 %: it finds a load cell's gain off 2x or
  a decimal slip, not 10 %.
- The drive against the load cell: the amplifier's gain is the map's first guess
  (``nominal_force_n_per_v``); off by more than `DRIVE_TOL` (20 %) it is corrected in the
  proposed map (a WARN; a FAIL outside `DRIVE_BAND`, 1/3-3x: a knob far off).
- The load cell agreeing with the drive while the motion agrees with neither: the rig is not the
  model (journal in, a rubbing seal, a lock): named as such, not as a sensor's gain.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass, field

import numpy as np

from daq.channels import (
    AnalogInput,
    AnalogOutput,
    ChannelKind,
    ChannelMap,
    EmergencyStopInput,
)
from daq.device_check import LiveValues
from daq.map_edits import Correction

K = ChannelKind
#: the sensors a drive must move, by kind
RESPONDING = (K.LOAD_CELL, K.EDDY_CURRENT_PROBE, K.ACCELEROMETER)
MOTION_TOL = 0.10  # probes and accelerometer of one axis against their median (a = -w^2 x)
MODEL_TOL = 0.30  # the load cell against the motion through K - w^2 M + iwC (K, M to ~10 %)
DRIVE_TOL = 0.20  # the amplifier against nominal_force_n_per_v: beyond, corrected (a WARN)
DRIVE_BAND = (1 / 3, 3.0)  # ... beyond this a FAIL (a knob far off)
SWAP_GAIN_DIFF = 0.02  # two probes' gains this far apart can tell a swap by their readings
SWAP_RATIO_MATCH = 0.01  # ... when their ratio is the gains' ratio squared to this
G = 9.80665  # standard gravity [m/s^2]: accelerometer sensitivities in mV/g
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


def where(ch: AnalogInput | AnalogOutput | EmergencyStopInput) -> str:
    return f"{ch.name} ({ch.physical_channel})"


def exchanged(group: str, a: AnalogInput | AnalogOutput, b: AnalogInput | AnalogOutput,
              why: str) -> list[Correction]:
    """The corrections that exchange the ``physical_channel`` of ``a`` and ``b`` (of ``group``,
    "ai" or "ao"); ``why`` formats each one's name and the terminal it is found on."""
    return [Correction(group, p.name, "physical_channel", q.physical_channel,
                       why.format(p.name, q.physical_channel)) for p, q in ((a, b), (b, a))]


def axis_of(ch: AnalogInput) -> str | None:
    """The axis a sensor measures, by the software's names (fx, x1, x2, ax; fy, y1, ...)."""
    if ch.kind not in RESPONDING or ch.name == "hammer":
        return None
    if ch.kind is K.EDDY_CURRENT_PROBE:
        return "y" if ch.name.startswith("y") else "x"
    return "y" if "y" in ch.name else "x"


def show(ch: AnalogInput, value: float) -> str:
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
    swapped = _probes_swapped_at_rest(cm, rest, v)
    for i, ch in enumerate(cm.ai):
        if ch.name in swapped:
            continue
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
            text = (f"reads {show(ch, mean)} ({mv:+.3f} V) at rest with nothing driven, over "
                    f"the {show(ch, max_mean)} its sensor allows: an offset in its "
                    "conditioner, or another signal on this terminal")
        if not text and std > max_std:
            text = (f"noise {show(ch, std)} rms at rest, over the {show(ch, max_std)} its "
                    "sensor allows: a ground loop, a floating input or a loose connector")
        if text:
            v.findings.append(Finding(level, where(ch), text))
        else:
            v.findings.append(Finding("ok", where(ch), f"at rest {show(ch, mean)} "
                                      f"({mv:+.3f} V), noise {show(ch, std)} rms"))
    return v


def _probes_swapped_at_rest(cm: ChannelMap, rest: LiveValues, v: Verdict) -> set[str]:
    """Pairs of probes whose gap voltages each sit at the other's ``offset_v`` and not at their
    own: the probes (with their cables) are on each other's terminals. One finding per pair
    and their ``physical_channel`` exchanged (an ``offset_v`` "corrected" instead would hide
    the swap for good). The names of the probes so judged."""
    probes = [(i, ch) for i, ch in enumerate(cm.ai) if ch.kind is K.EDDY_CURRENT_PROBE]
    gap = {ch.name: float(rest.mean_v[i]) for i, ch in probes}

    def at(name: str, offset: float) -> bool:
        return abs(gap[name] - offset) <= GAP_MATCH_V

    found: set[str] = set()
    for n, (_, p) in enumerate(probes):
        for _, q in probes[n + 1:]:
            if {p.name, q.name} & found or at(p.name, p.offset_v) or at(q.name, q.offset_v):
                continue
            if not (at(p.name, q.offset_v) and at(q.name, p.offset_v)):
                continue
            found |= {p.name, q.name}
            v.findings.append(Finding("fail", f"{where(p)} and {where(q)}", (
                f"swapped: {p.name}'s terminal reads {gap[p.name]:+.3f} V, {q.name}'s gap "
                f"voltage (offset_v {q.offset_v:+.3f} V), and {q.name}'s reads "
                f"{gap[q.name]:+.3f} V, {p.name}'s ({p.offset_v:+.3f} V): the two probes (with "
                "their cables) are on each other's terminals: physical_channel exchanged in "
                "the proposed map (or swap the cables back); their offsets are right")))
            v.corrections += exchanged("ai", p, q, "{}'s gap voltage is on {}")
    return found


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


def _other(axis: str) -> str:
    return "y" if axis == "x" else "x"


def _drive_where(cm: ChannelMap, axis: str) -> str:
    ao = cm.ao[cm.ao_for_axis(axis)]
    return f"{ao.name} ({ao.physical_channel})"


def judge_drives(cm: ChannelMap, responses: dict[str, dict[str, Response]],
                 forces: dict[str, complex], freq_hz: float) -> Verdict:
    """Swapped drives, a held housing, swapped, dead, inverted and wrongly scaled sensors from
    the responses to each axis's drive (``responses[axis][channel]``; ``forces[axis]`` the
    force the drive should give). The whole pattern first (the drives, the housing), then each
    sensor."""
    v = Verdict()
    sensors = [ch for ch in cm.ai if axis_of(ch) is not None]
    responses = dict(responses)
    forces = dict(forces)
    done: set[str] = set()
    if _drives_swapped(cm, sensors, responses, v):
        responses = {_other(a): r for a, r in responses.items()}  # judge each by what moved it
        forces = {_other(a): f for a, f in forces.items()}
    driven = set(responses)
    for dead in sorted(driven):
        if _drive_dead(cm, dead, sensors, responses, freq_hz, v):
            done |= {ch.name for ch in sensors if axis_of(ch) == dead}
    if _housing_held(sensors, responses, done, freq_hz, v):
        done |= {ch.name for ch in sensors if ch.kind is not K.LOAD_CELL}
    for ch in sensors:
        a = axis_of(ch)
        assert a is not None
        if a not in driven or ch.name in done:
            continue
        own = responses[a][ch.name]
        if own.responds:
            continue
        b = _other(a)
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
                    f"{show(ch, abs(responses[a][partner.name].z))} and {ch.name} "
                    f"{show(ch, abs(own.z))}; driving {b}, {ch.name} moved "
                    f"{show(ch, abs(cross.z))} and {partner.name} "
                    f"{show(ch, abs(responses[b][partner.name].z))}: physical_channel "
                    "exchanged in the proposed map (or swap the cables)")))
                v.corrections += exchanged("ai", ch, partner, "{}'s sensor answers on {}")
            else:
                v.findings.append(Finding("fail", where(ch), (
                    f"reads the {b} drive ({show(ch, abs(cross.z))}) and not the {a} one "
                    f"({show(ch, abs(own.z))}, about {show(ch, abs(own.expected))} "
                    f"expected): a {b} sensor is on this terminal")))
        else:
            v.findings.append(Finding("fail", where(ch), (
                f"does not respond to the {a} drive: {show(ch, abs(own.z))} at {freq_hz:g} Hz "
                f"where about {show(ch, abs(own.expected))} is expected: a dead sensor, an "
                "open cable or nothing on this terminal")))
    for a in sorted(driven):
        group = [ch for ch in sensors if axis_of(ch) == a and ch.name not in done]
        if group:
            _sign_and_size(cm, a, group, responses[a], forces[a], freq_hz, v)
    return v


def _drives_swapped(cm: ChannelMap, sensors: list[AnalogInput],
                    responses: dict[str, dict[str, Response]], v: Verdict) -> bool:
    """Every sensor of one axis answers the other axis's drive and not its own, both ways:
    the two drives go to each other's shaker (two wires), not every sensor to the other axis
    (eight). One finding naming the drives, their AO physical_channels exchanged."""
    if set(responses) != {"x", "y"} or len(cm.ao) < 2:
        return False
    for a in ("x", "y"):
        own = [ch for ch in sensors if axis_of(ch) == a]
        if len(own) < 2 or any(responses[a][ch.name].responds or
                               not responses[_other(a)][ch.name].responds for ch in own):
            return False
    ax, ay = cm.ao[cm.ao_for_axis("x")], cm.ao[cm.ao_for_axis("y")]

    def moved(drive: str, axis: str) -> str:
        return ", ".join(f"{ch.name} {show(ch, abs(responses[drive][ch.name].z))}"
                         for ch in sensors if axis_of(ch) == axis)

    v.findings.append(Finding("fail", f"{where(ax)} and {where(ay)}", (
        f"the drives are swapped: {ax.name} moved every y sensor ({moved('x', 'y')}) and no x "
        f"sensor; {ay.name} moved every x sensor ({moved('y', 'x')}): {ax.name}'s output goes "
        f"to the Y shaker's amplifier and {ay.name}'s to the X one: physical_channel exchanged "
        "in the proposed map (or swap the amplifier inputs); the sensors are right")))
    v.corrections += exchanged("ao", ax, ay, "{}'s shaker's amplifier is on {}")
    return True


def _drive_dead(cm: ChannelMap, axis: str, sensors: list[AnalogInput],
                responses: dict[str, dict[str, Response]], freq_hz: float, v: Verdict) -> bool:
    """No sensor of either axis answers ``axis``'s drive while the other drive moves its own
    sensors: no force reaches the rig from that output (amplifier, cable, shaker)."""
    b = _other(axis)
    if b not in responses or any(r.responds for r in responses[axis].values()):
        return False
    if not any(responses[b][ch.name].responds for ch in sensors if axis_of(ch) == b):
        return False
    lc = next((ch for ch in sensors if axis_of(ch) == axis and ch.kind is K.LOAD_CELL), None)
    force = f"; {lc.name} read {show(lc, abs(responses[axis][lc.name].z))}" if lc else ""
    v.findings.append(Finding("fail", _drive_where(cm, axis), (
        f"nothing answers this drive at {freq_hz:g} Hz{force} and no sensor moved, while the "
        f"{b} drive moves its axis: no force reaches the rig from this output (the amplifier "
        "off or its gain at zero, the AO cable, the shaker's leads or its stinger)")))
    return True


def _housing_held(sensors: list[AnalogInput], responses: dict[str, dict[str, Response]],
                  done: set[str], freq_hz: float, v: Verdict) -> bool:
    """The load cells read their drives and no motion sensor (probe, accelerometer) moved on
    either axis: the housing is held (their gap voltages at rest were right, so they are
    alive), not that many dead cables."""
    live = [ch for ch in sensors if ch.name not in done and axis_of(ch) in responses]
    cells = [ch for ch in live if ch.kind is K.LOAD_CELL]
    motion = [ch for ch in live if ch.kind is not K.LOAD_CELL]
    if not cells or len(motion) < 2:
        return False
    if not all(responses[axis_of(ch) or "x"][ch.name].responds for ch in cells):
        return False
    if any(r[ch.name].responds for ch in motion for r in responses.values()):
        return False
    read = ", ".join(f"{ch.name} {show(ch, abs(responses[axis_of(ch) or 'x'][ch.name].z))}"
                     for ch in cells)
    probe = next((ch for ch in motion if ch.kind is K.EDDY_CURRENT_PROBE), motion[0])
    r = responses[axis_of(probe) or "x"][probe.name]
    v.findings.append(Finding("fail", "housing", (
        f"held: the load cells read the drives ({read}) and none of the {len(motion)} motion "
        f"sensors moved ({probe.name} {show(probe, abs(r.z))} where "
        f"{show(probe, abs(r.expected))} is expected at {freq_hz:g} Hz): something holds the "
        "housing against the drive, not that many dead cables: the seal's friction with the "
        "journal in (about 26 N, far over the drive), a transport lock or a clamp: take the "
        "journal out, free the housing and run again")))
    return True


def _agree(p: float, q: float, tol: float) -> bool:
    return 1 / (1 + tol) <= p / q <= 1 + tol


def _sensitivity(ch: AnalogInput, gain: float) -> str:
    if ch.kind is K.EDDY_CURRENT_PROBE:
        return f"{gain * 1e-3:.4g} V/mm"
    if ch.kind is K.ACCELEROMETER:
        return f"{gain * G * 1e3:.4g} mV/g"
    return f"{gain * 1e3:.4g} mV/{ch.units}"


def _as_motion(ch: AnalogInput) -> str:
    return f"{ch.name} (-a/w^2)" if ch.kind is K.ACCELEROMETER else ch.name


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
    size = {ch.name: abs(resp[ch.name].ratio) for ch in sized}  # 1: as the model and drive say
    motion = [ch for ch in sized if ch.kind is not K.LOAD_CELL]
    cells = [ch for ch in sized if ch.kind is K.LOAD_CELL]
    forces_ = [size[ch.name] for ch in cells] + [1.0]
    good = _judge_motion(axis, motion, resp, size, float(np.median(forces_)), v)
    _probes_read_as_swapped(good, size, v)
    m = float(np.median([size[ch.name] for ch in good])) if good else None
    measured = 1.0  # the force the rig feels, over the drive's nominal
    for ch in cells:
        r, l_ = resp[ch.name], size[ch.name]
        if m is None or _agree(l_, m, MODEL_TOL):
            measured = l_
            v.findings.append(Finding("ok", where(ch), (
                f"{show(ch, abs(r.z))} at {_deg(r.ratio):+.0f} deg for the {axis} drive "
                f"(the probes' motion x (K - w^2 M) says {show(ch, abs(r.expected) * m)})"
                if m is not None else
                f"{show(ch, abs(r.z))} at {_deg(r.ratio):+.0f} deg for the {axis} drive")))
        elif _agree(m, 1.0, MODEL_TOL):
            q = l_ / m
            new = _corrected_gain(ch.gain_v_per_unit, q)
            v.findings.append(Finding("fail", where(ch), (
                f"reads {show(ch, abs(r.z))} for the {axis} drive where the drive and the "
                f"axis's motion x (K - w^2 M) say {show(ch, abs(r.expected) * m)}: its "
                f"gain_v_per_unit {ch.gain_v_per_unit:.4g} is {_times(1 / q)} (measured "
                f"{_sensitivity(ch, ch.gain_v_per_unit * q)}; proposed {new:.4g}; check the "
                "sensor's certificate)")))
            v.corrections.append(Correction("ai", ch.name, "gain_v_per_unit", new,
                                            f"reads {q:.2g}x what the {axis} drive gives"))
        else:
            v.findings.append(Finding("fail", f"{axis} axis", (
                f"{ch.name} reads {show(ch, abs(r.z))} for the drive's "
                f"{abs(r.expected):.3g} N, the housing moved {m:.2g}x what the model's "
                f"K - w^2 M + iwC gives for that: the rig is not the one the checks assume "
                "(journal in or a seal rubbing, a lock, a resonance near the test "
                "frequency), or this load cell and the amplifier are both off")))
            return
    if not _agree(measured, 1.0, DRIVE_TOL):
        gain = ao.nominal_force_n_per_v * measured
        level = "warn" if DRIVE_BAND[0] <= measured <= DRIVE_BAND[1] else "fail"
        v.findings.append(Finding(level, drive_where, (
            f"the rig answers {measured:.2g}x what {abs(force):.3g} N from "
            f"nominal_force_n_per_v {ao.nominal_force_n_per_v:g} N/V should give: the "
            f"amplifier's gain is {gain:.3g} N/V (its knob?); corrected in the proposed map")))
        v.corrections.append(Correction("ao", ao.name, "nominal_force_n_per_v",
                                        float(f"{gain:.3g}"), "measured under the drive"))
    else:
        v.findings.append(Finding("ok", drive_where, (
            f"{abs(force):.3g} N asked at {freq_hz:g} Hz: the sensors say {measured:.2f}x that")))


def _probes_read_as_swapped(motion: list[AnalogInput], size: dict[str, float],
                            v: Verdict) -> None:
    """Two probes of one axis with gains g1 != g2 swapped (with their cables) read g2/g1 and
    g1/g2 of the motion: their ratio is (g2/g1)^2, not 1. Where the gains differ by more than
    `SWAP_GAIN_DIFF` and the ratio is that to `SWAP_RATIO_MATCH`, a WARN (within the
    calibrations' few %, so not proof; the gap voltages at rest are, when they differ)."""
    probes = [ch for ch in motion if ch.kind is K.EDDY_CURRENT_PROBE]
    for n, p in enumerate(probes):
        for q in probes[n + 1:]:
            swapped = (q.gain_v_per_unit / p.gain_v_per_unit) ** 2
            ratio = size[p.name] / size[q.name]
            if abs(math.log(swapped)) > 2 * SWAP_GAIN_DIFF and \
                    abs(math.log(ratio / swapped)) < SWAP_RATIO_MATCH:
                v.findings.append(Finding("warn", f"{where(p)} and {where(q)}", (
                    f"read the same motion {ratio:.3f}:1, the square of their gains' ratio "
                    f"({q.gain_v_per_unit:.5g}/{p.gain_v_per_unit:.5g})^2 = {swapped:.3f}: "
                    "what two probes on each other's terminals read (within their "
                    "calibrations' few %, so check their cables: give them different gap "
                    "voltages and commission again, a swap then shows at rest)")))


def _judge_motion(axis: str, motion: list[AnalogInput], resp: dict[str, Response],
                  size: dict[str, float], force: float, v: Verdict) -> list[AnalogInput]:
    """The probes and the accelerometer of one axis see one motion (a = -w^2 x): each within
    `MOTION_TOL` of their median (of two that disagree, the one nearer the force's motion
    through the model); the others named with their measured sensitivity. The ones that
    agree."""
    if not motion:
        return []
    if len(motion) == 2 and not _agree(size[motion[0].name], size[motion[1].name], MOTION_TOL):
        ref = min((size[ch.name] for ch in motion), key=lambda s: abs(math.log(s / force)))
    else:
        ref = float(np.median([size[ch.name] for ch in motion]))
    good = [ch for ch in motion if _agree(size[ch.name], ref, MOTION_TOL)]
    for ch in motion:
        r = resp[ch.name]
        if ch in good:
            v.findings.append(Finding("ok", where(ch), (
                f"{show(ch, abs(r.z))} at {_deg(r.ratio):+.0f} deg for the {axis} drive "
                f"(the model: {show(ch, abs(r.expected))}, x{size[ch.name]:.2f})")))
            continue
        q = size[ch.name] / ref
        new = _corrected_gain(ch.gain_v_per_unit, q)
        others = " and ".join(_as_motion(o) for o in good) or "the drive through the model"
        shown = abs(r.expected) * ref
        v.findings.append(Finding("fail", where(ch), (
            f"reads {show(ch, abs(r.z))} for the {axis} drive where {others} say "
            f"{show(ch, shown)} (x{q:.2f}; one motion, a = -w^2 x, read to the "
            f"{MOTION_TOL:.0%} the sensors' calibrations allow): its sensitivity measures "
            f"{_sensitivity(ch, ch.gain_v_per_unit * q)} where gain_v_per_unit says "
            f"{_sensitivity(ch, ch.gain_v_per_unit)} ({_times(1 / q)}; proposed {new:.4g}; "
            "check the sensor's certificate)")))
        v.corrections.append(Correction("ai", ch.name, "gain_v_per_unit", new,
                                        f"reads {q:.2g}x the {axis} axis's motion"))
    return good


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
