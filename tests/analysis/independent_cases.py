"""Hidden-effect cases on the independent generator (``tests.independent_rig``), for diagnose.

Each case is lubricated X dwells (20-60 Hz x 13/25/38 um, one probe and one accelerometer per
axis, the rig without seal; the cross-coupling case X, Y and circular dwells in turn, since a
film coupling needs motion and force on both axes), made by a generator that shares no code with
``simulated_hw`` or ``analysis``, written as the canonical CSV, imported with ``sfdrig import
--lubricated --rig``
(the rig described correctly: no seal, the film's centred damping without the eccentricity law)
and handed to diagnose as a run file. One hidden effect per case, added through the
generator's extension points (extra forces, time-varying parameters, sensor transforms, the
frame, the film's cross terms, air, a joint); magnitudes drawn from a seeded generator:

======================== ===================================================================
case                     hidden in the generator
======================== ===================================================================
clean                    nothing
coulomb_friction         seal friction 10..15 N
cubic_stiffness          restoring k3 z^3, k3 = r K / (38 um)^2, r in 0.06..0.12, either sign
quadratic_stiffness      k2 z^2, k2 = r K / 38 um, r in 0.06..0.12, either sign
amplitude_dependent_...  film damping x (1 + 2 eps^2) / (1 - eps^2)^2, eps = |z| / c,
                         c = 0.45..0.6 of 127 um
added_mass               1.5..3 kg on the housing
second_mode              the frame: 100 kg on 5..7 MN/m (36..42 Hz)
viscosity_drift          film damping falling 15..25 % over the run (oil temperature recorded)
sensor_gain              the x probe reading 1.06..1.10 or 0.90..0.94 of the truth
channel_delay            the x probe 120..200 us late
cross_coupling           film cross damping C_xy 800..1500 N.s/m, C_yx = C_xy x (0.5..1.0)
air_entrainment          L_eff = L (1 - a), tau a' = k |v| - a, k 6..14 s/m, tau 50 ms (film
                         damping and added mass 10..30 % lower at 60 Hz, 38 um)
joint_microslip          a Dahl joint beside the rods' spring, k_j 0.25..0.4 of K (taken from
                         it: stuck, the rig is as described), slip force k_j x (20..40 um), 4..13 N
stiffness_drift          K_x falling 8..12 % over the run (not in the library)
coupled_axes             the rods' cross stiffness k_xy = r sqrt(K_x K_y), r in 0.12..0.18,
                         either sign (principal axes turned from the probes'; a baseline
                         order, not a library effect: ``coupling_judged_right``)
======================== ===================================================================

Judged right (``judged_right``): the effect named first with high confidence, its main
parameter within the tolerance written here (``TOLERANCE``, sized from the accuracy measured on
these cases, not the library's documented one), no other cause with high confidence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from tests.independent_rig import (
    AirEntrainment,
    DahlJoint,
    FrameMode,
    Generator,
    RigSpec,
    Sensors,
    delay,
    gain,
    grid,
)

FREQS_HZ = (20.0, 30.0, 40.0, 50.0, 60.0)
AMPS_M = (13e-6, 25e-6, 38e-6)
RECORD_S = 0.5
K_X = 788e3
K_Y = 823e3
CASES = ("clean", "coulomb_friction", "cubic_stiffness", "quadratic_stiffness",
         "amplitude_dependent_damping", "added_mass", "second_mode", "viscosity_drift",
         "sensor_gain", "channel_delay", "cross_coupling", "air_entrainment", "joint_microslip",
         "stiffness_drift")
#: cases the fitted baseline's order should take in (not library effects)
BASELINE_CASES = ("coupled_axes",)
#: cases whose dwells move both axes in turn (the motion of each inferred on import)
BOTH_AXES = ("cross_coupling", "coupled_axes")
OUTSIDE_LIBRARY = ("stiffness_drift",)

#: Each library case's main parameter (its name in diagnose's JSON) and the relative tolerance it
#: is judged on, in brackets the largest error measured (2026-11-25; the library documents
#: 10-20 %): cross coupling, air and joint at seeds 1-5 and 945 (CI's seed of the day then),
#: tolerance 3-5x; the others at seeds 1-3 (second mode, viscosity, sensor gain, delay:
#: 1-2), about 5x
TOLERANCE: dict[str, tuple[str, float]] = {
    "coulomb_friction": ("friction_force_N", 0.015),  # [0.34 %]
    "cubic_stiffness": ("k3_N_per_m3", 0.02),  # [0.48 %]
    "quadratic_stiffness": ("k2_N_per_m2", 0.0125),  # [0.25 %]
    "amplitude_dependent_damping": ("clearance_m", 0.002),  # [0.034 %]
    "added_mass": ("added_mass_kg", 0.01),  # [0.23 %]
    "second_mode": ("frequency_hz", 2e-4),  # [0.004 %]
    "viscosity_drift": ("relative_change", 0.12),  # [4.0 %]
    "sensor_gain": ("gain_ratio", 0.0012),  # [0.024 %]
    "channel_delay": ("delay_s", 0.006),  # [0.12 %]
    "cross_coupling": ("c_xy_Ns_per_m", 0.005),  # [0.098 %]
    "air_entrainment": ("coefficient_s_per_m", 0.006),  # [0.17 %]
    "joint_microslip": ("slip_force_N", 0.03),  # [0.84 %]
}

#: the rig as described to diagnose (RigParams TOML): no seal, the film's centred damping
RIG_TOML = """\
[seal]
enabled = false

[film]
eccentricity_law = false

[oil]
initially_filled = true
warming_c_per_hour = 0.0
"""


@dataclass
class IndependentCase:
    effect: str
    truth: dict[str, Any]
    run: Path
    rig_toml: Path
    notes: dict[str, Any] = field(default_factory=dict)


def _program(rng: np.random.Generator, both_axes: bool = False) -> list:
    dwells = list(grid(list(FREQS_HZ), list(AMPS_M), "x", record_s=RECORD_S))
    if both_axes:  # x, y, circular in turn over the grid (each motion at every frequency)
        motions = ("x", "y", "circular_forward")
        dwells = [replace(d, motion=motions[i % 3]) for i, d in enumerate(dwells)]
    order = rng.permutation(len(dwells))  # time not confounded with frequency or amplitude
    return [dwells[i] for i in order]


def build(effect: str, seed: int) -> tuple[RigSpec, Sensors, Generator, dict[str, Any]]:
    """The generator of case ``effect`` and the truth diagnose should recover."""
    rng = np.random.default_rng(seed)
    rig = RigSpec()  # lubricated, no seal, the report's structure and film
    sensors = Sensors(seed=seed + 1000)
    duration = len(FREQS_HZ) * len(AMPS_M) * RECORD_S
    gen_kw: dict[str, Any] = {}
    truth: dict[str, Any] = {}
    sign = 1.0 if rng.random() < 0.5 else -1.0
    c_film = float(rig.film_damping_ns_per_m)  # type: ignore[arg-type]
    if effect == "clean":
        pass
    elif effect == "coulomb_friction":
        f = float(rng.uniform(10, 15))
        rig.seal_friction_n = f
        truth["friction_force_N"] = f
    elif effect == "cubic_stiffness":
        k3 = sign * float(rng.uniform(0.06, 0.12)) * K_X / 38e-6**2
        rig.extra_forces.append(lambda t, z, v, _k=k3: -_k * z**3)
        truth["k3_N_per_m3"] = k3
    elif effect == "quadratic_stiffness":
        k2 = sign * float(rng.uniform(0.06, 0.12)) * K_X / 38e-6
        rig.extra_forces.append(lambda t, z, v, _k=k2: -_k * z**2)
        truth["k2_N_per_m2"] = k2
    elif effect == "amplitude_dependent_damping":
        c = float(rng.uniform(0.45, 0.6)) * 127e-6

        def ecc(t: float, z: np.ndarray, v: np.ndarray, _c: float = c) -> np.ndarray:
            e2 = float(z @ z) / _c**2
            return -c_film * ((1 + 2 * e2) / (1 - e2) ** 2 - 1.0) * v
        rig.extra_forces.append(ecc)
        truth["clearance_m"] = c
    elif effect == "added_mass":
        dm = float(rng.uniform(1.5, 3.0))
        rig.housing_mass_kg = 9.7 + dm
        truth["added_mass_kg"] = dm
    elif effect == "second_mode":
        k_fr = float(rng.uniform(5e6, 7e6))
        frame = FrameMode(frequency_hz=math.sqrt(k_fr / 100.0) / (2 * math.pi),
                          modal_mass_kg=100.0, damping_ratio=0.03)
        rig.frame = frame
        truth["frequency_hz"] = frame.frequency_hz
    elif effect == "viscosity_drift":
        drop = float(rng.uniform(0.15, 0.25))
        rig.film_damping_ns_per_m = lambda t, _d=drop: c_film * (1 - _d * t / duration)
        # the oil temperature that eq. 1 ties to that drop (recorded, corroborating evidence)
        gen_kw["oil_temp_c"] = lambda t, _d=drop: 24.0 - math.log(1 - _d * t / duration) / 0.01665
        truth["relative_change"] = -drop
    elif effect == "sensor_gain":
        g = float(rng.uniform(1.06, 1.10)) if sign > 0 else float(rng.uniform(0.90, 0.94))
        sensors.transforms["x_m"] = [gain(g)]
        truth.update(channel="x", gain_ratio=g)
    elif effect == "channel_delay":
        tau = float(rng.uniform(120e-6, 200e-6))
        sensors.transforms["x_m"] = [delay(tau)]
        truth.update(channel="x", delay_s=tau)
    elif effect == "cross_coupling":
        cxy = float(rng.uniform(800, 1500))
        cyx = cxy * float(rng.uniform(0.5, 1.0))
        rig.film_cross_damping_ns_per_m = (cxy, cyx)
        truth.update(c_xy_Ns_per_m=cxy, c_yx_Ns_per_m=cyx)
    elif effect == "air_entrainment":
        k_air = float(rng.uniform(6, 14))
        rig.air = AirEntrainment(coefficient_s_per_m=k_air, time_constant_s=0.05)
        truth["coefficient_s_per_m"] = k_air
    elif effect == "joint_microslip":
        k_j = float(rng.uniform(0.25, 0.4)) * K_X
        f_s = k_j * float(rng.uniform(20e-6, 40e-6))
        rig.stiffness_x_n_per_m, rig.stiffness_y_n_per_m = K_X - k_j, K_Y - k_j
        rig.joint = DahlJoint(stiffness_n_per_m=k_j, slip_force_n=f_s)
        truth.update(slip_force_N=f_s, stiffness_N_per_m=k_j)
    elif effect == "stiffness_drift":
        drop = float(rng.uniform(0.08, 0.12))
        rig.stiffness_x_n_per_m = lambda t, _d=drop: K_X * (1 - _d * t / duration)
        truth["stiffness_drop"] = drop
    elif effect == "coupled_axes":
        k_xy = sign * float(rng.uniform(0.12, 0.18)) * math.sqrt(K_X * K_Y)
        rig.stiffness_xy_n_per_m = k_xy
        truth["stiffness_xy_N_per_m"] = k_xy
    else:
        raise ValueError(f"unknown case {effect!r} (one of {CASES + BASELINE_CASES})")
    return rig, sensors, Generator(rig, sensors, **gen_kw), truth


def make_independent_case(tmp: Path, effect: str, seed: int, rig_described: bool = True,
                          both_axes: bool | None = None) -> IndependentCase:
    """Generate, write the CSV and import it as a run file (through ``sfdrig import``).

    ``rig_described=False`` imports it without the rig description (diagnose then fits its
    baseline from the data); ``both_axes`` moves both axes in turn (default: the cases of
    ``BOTH_AXES``)."""
    from sfdrig.cli import main

    _, _, gen, truth = build(effect, seed)
    both = effect in BOTH_AXES if both_axes is None else both_axes
    rec = gen.run(_program(np.random.default_rng(seed + 7), both_axes=both))
    csv = rec.to_csv(tmp / f"{effect}-{seed}.csv")
    rig_toml = tmp / "rig.toml"
    rig_toml.write_text(RIG_TOML)
    run = tmp / f"{effect}-{seed}.h5"
    motion = [] if both else ["--motion", "x"]  # both axes: each dwell's motion inferred
    rig = ["--rig", str(rig_toml)] if rig_described else []
    rc = main(["import", str(csv), "--out", str(run), "--lubricated", *motion,
               "--seal", "none", *rig, "--overwrite"])
    if rc != 0:
        raise RuntimeError(f"sfdrig import failed on {csv} (exit {rc})")
    return IndependentCase(effect, truth, run, rig_toml)


def judged_right(effect: str, doc: dict[str, Any],
                 truth: dict[str, Any] | None = None) -> tuple[bool, str]:
    """Whether a diagnose JSON document judges case ``effect`` right, and why not.

    Clean: no finding and nothing unexplained. Outside the library: unexplained or baseline
    inadequate, no high-confidence finding. Library effect: named first with high confidence
    (a sensor effect: the sensor named; a pair it cannot tell apart: said so), no other cause
    with high confidence, and (given ``truth``) its main parameter within ``TOLERANCE``.
    """
    found = [(f["effect"], f["evidence"].get("confidence")) for f in doc["findings"]]
    confident = [e for e, c in found if c == "high"]
    verdict = doc.get("verdict", {}).get("verdict", "")
    if effect == "clean":
        ok = not found and not doc["unexplained"]
        return ok, f"found {found}, verdict {verdict}"
    if effect in OUTSIDE_LIBRARY:
        ok = not confident and verdict in ("unexplained discrepancy", "baseline inadequate")
        return ok, f"found {found}, verdict {verdict}"
    ok = bool(found) and found[0] == (effect, "high") and confident == [effect]
    first = doc["findings"][0] if doc["findings"] else {}
    main, tolerance = TOLERANCE[effect]
    if ok and truth is not None and main in truth:
        got, want = float(first["parameters"][main]), float(truth[main])
        if abs(got - want) > tolerance * abs(want):
            return False, (f"found {found}, {main} = {got:.4g} (truth {want:.4g}, off "
                           f"{got / want - 1:+.3%}, tolerance {tolerance:.2%}), verdict {verdict}")
    if ok and "channel" in truth_channel_of(effect):
        # the faulty sensor named, and nothing it cannot be told from: the probes' x and the
        # accelerometer's ax measure one motion independently, so a fault on x alone is told
        # apart (a list that merely holds x would pass any answer)
        named = first["parameters"].get("channel")
        alike = first["evidence"].get("cannot_tell_from", [])
        ok = named == truth_channel_of(effect)["channel"] and not alike
        return ok, f"found {found} on channel {named} (cannot tell from {alike}), verdict {verdict}"
    return ok, f"found {found}, verdict {verdict}"


def truth_channel_of(effect: str) -> dict[str, str]:
    """The channel a sensor case makes faulty (``build`` puts every sensor fault on x)."""
    return {"channel": "x"} if effect in ("sensor_gain", "channel_delay") else {}


def coupling_chosen(doc: dict[str, Any]) -> float | None:
    """The cross stiffness of the fitted baseline's order chosen [N/m] (None: uncoupled)."""
    for row in doc["baseline"]["order_selection"]:
        if row["chosen"] and row["coupled_axes"]:
            return float(row["parameters"]["stiffness_xy_N_per_m"])
    return None


#: the rods' cross stiffness taken into the fitted baseline, relative: measured within 0.07 % at
#: seeds 1-5 (docs/benchmarks.md) and 0.13 % at seed 945; was 10 %
COUPLING_TOLERANCE = 0.005


def coupling_judged_right(doc: dict[str, Any], truth: dict[str, Any],
                          tolerance: float = COUPLING_TOLERANCE) -> tuple[bool, str]:
    """Whether a diagnose JSON document of the ``coupled_axes`` case (imported without a rig
    description) judges it right, and why not: the coupled order chosen, its cross stiffness
    within ``tolerance`` of the truth, and no finding with high confidence (in particular not
    the film's ``cross_coupling``)."""
    found = [(f["effect"], f["evidence"].get("confidence")) for f in doc["findings"]]
    confident = [e for e, c in found if c == "high"]
    k_xy, want = coupling_chosen(doc), float(truth["stiffness_xy_N_per_m"])
    why = (f"order {order_summary(doc)}, k_xy {k_xy} (truth {want:.4g}), found {found}, "
           f"verdict {doc.get('verdict', {}).get('verdict', '')}")
    ok = (k_xy is not None and abs(k_xy - want) <= tolerance * abs(want) and not confident)
    return ok, why


def order_summary(doc: dict[str, Any]) -> list[tuple[Any, ...]]:
    """The fitted baseline's order table in short: (modes per axis, coupled, chosen, cross
    stiffness, held-out gain, why not chosen) per row."""
    return [(r["modes_per_axis"], r["coupled_axes"], r["chosen"],
             r.get("parameters", {}).get("stiffness_xy_N_per_m"), r.get("gain"),
             r.get("not_chosen") or r.get("not_tried"))
            for r in doc["baseline"]["order_selection"]]
