"""Generator of measured runs with a hidden effect (tests and benchmarks of diagnose).

`make_case(tmp, effects, seed)` draws (seeded) a magnitude for each named effect, switches it on
in the *true* rig (the configured rig stays as it is and is what the run file records as its
``rig_config``), drives the simulated rig open-loop with sine dwells at several frequencies,
amplitudes and motions (the rig's test programme, in a seeded random order so that time is not
confounded with frequency or amplitude), with the simulator's sensor noise and ADC quantisation,
and writes the run file with `storage.RunWriter`. Diagnose is handed only the file.

Magnitudes drawn (`tests/analysis/test_diagnose_hidden.py` writes the tolerances for these):

=========================== ================================================================
coulomb_friction            seal friction 40..60 N (configured 26 N)
cubic_stiffness             k3 = r K / (50 um)^2, r in 0.05..0.15 (either sign)
quadratic_stiffness         k2 = r K / 50 um, r in 0.05..0.15 (either sign)
amplitude_dependent_damping clearance of the eccentricity law 0.70..0.85 of 127 um
added_mass                  1.0..2.5 kg
cross_coupling              c_xy 800..1500 N.s/m, c_yx = c_xy x (0.5..1)
second_mode                 frame mode 30..55 Hz (modal mass 150 kg)
joint_microslip             on the rods' spring: k_j 0.25..0.4 of K (taken from it), slip
                            force k_j x (20..40 um)
viscosity_drift             film damping -12..-25 % from start to end (oil warming)
sensor_gain                 one probe, recorded/true 1.03..1.08 or 0.92..0.97
channel_delay               one probe, 0.1..0.5 ms
air_entrainment             coefficient 6..14 s/m (film damping 15..40 % lower at speed)
=========================== ================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from daq.channels import default_channel_map
from rig_model import RigParams
from rig_model.params import VISCOSITY_SLOPE_PER_C
from simulated_hw import SimulatedBackend
from storage.records import StepRecord
from storage.runfile import RunWriter

PROBES = ("x1", "x2", "y1", "y2")
LEAD_IN_S = 5.0  # pump running, no drive: the film fills and pressurises before the dwells
STEP_HARMONICS = 5  # 1X..5X per channel, as a run file's /step_harmonics holds (run-files.md)


def step_harmonics(record: np.ndarray, first: int, fs: float, freq_hz: float) -> np.ndarray:
    """A dwell record's complex peak amplitudes 1X..5X (channels, 5) of each row of ``record``
    (channels, samples) as docs/run-files.md defines them: ``z = z0 + sum_h Re(Z_h exp(i h w
    t))`` by least squares with ``t`` counted from the run's sample 0, so ``Z = c - i s`` for
    ``c cos + s sin``. Written here, not taken from the code under test, so the file diagnose
    reads is not made by diagnose."""
    t = (first + np.arange(record.shape[-1])) / fs
    w = 2 * math.pi * freq_hz
    basis = [np.ones_like(t)]
    for h in range(1, STEP_HARMONICS + 1):
        basis += [np.cos(h * w * t), np.sin(h * w * t)]
    coef = np.linalg.lstsq(np.column_stack(basis), np.atleast_2d(record).T, rcond=None)[0]
    return (coef[1::2] - 1j * coef[2::2]).T


@dataclass
class Case:
    """A generated case: what was hidden (effect -> its true parameters) and the run files."""

    effects: dict[str, dict[str, Any]]
    config: RigParams
    truth: RigParams
    paths: list[Path] = field(default_factory=list)
    duration_s: float = 0.0


def config_rig() -> RigParams:
    """The rig as configured (what the run file records): the report's rig, film full."""
    p = RigParams()
    return p.model_copy(update={"oil": p.oil.model_copy(update={"initially_filled": True})})


def _set(data: dict[str, Any], path: str, value: Any) -> None:
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = value


def draw_effect(effect: str, rng: np.random.Generator, data: dict[str, Any],
                duration_s: float) -> dict[str, Any]:
    """Switch ``effect`` on in the rig dict ``data`` with a drawn magnitude; return its truth."""
    k = data["structure"]["stiffness_x_n_per_m"]
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if effect == "coulomb_friction":
        f = float(rng.uniform(40, 60))
        _set(data, "seal.friction_force_n", f)
        return {"friction_force_N": f}
    if effect == "cubic_stiffness":
        k3 = sign * float(rng.uniform(0.05, 0.15)) * k / 50e-6**2
        data["effects"]["cubic_stiffness"] = {"enabled": True, "k3_n_per_m3": k3}
        return {"k3_N_per_m3": k3}
    if effect == "quadratic_stiffness":
        k2 = sign * float(rng.uniform(0.05, 0.15)) * k / 50e-6
        data["effects"]["quadratic_stiffness"] = {"enabled": True, "k2_n_per_m2": k2}
        return {"k2_N_per_m2": k2}
    if effect == "amplitude_dependent_damping":
        film = data["film"]
        c0 = film["clearance_m"]
        c = float(rng.uniform(0.70, 0.85)) * c0
        d0 = RigParams.model_validate(data).film.added_mass()
        film.update(clearance_m=c, damping_scale=film["damping_scale"] * (c / c0) ** 3,
                    added_mass_kg=d0, eccentricity_law=True)
        return {"clearance_m": c}
    if effect == "added_mass":
        dm = float(rng.uniform(1.0, 2.5))
        data["structure"]["mass_kg"] += dm
        return {"added_mass_kg": dm}
    if effect == "cross_coupling":
        cxy = float(rng.uniform(800, 1500))
        cyx = cxy * float(rng.uniform(0.5, 1.0))
        data["effects"]["cross_coupling"] = {"enabled": True, "c_xy_ns_per_m": cxy,
                                             "c_yx_ns_per_m": cyx, "d_xy_kg": 0.0,
                                             "d_yx_kg": 0.0}
        return {"c_xy_Ns_per_m": cxy, "c_yx_Ns_per_m": cyx}
    if effect == "second_mode":
        f = float(rng.uniform(30, 55))
        # 150 kg: with the default 40 kg frame and the film full, the simulator's explicit step
        # diverges on some dwells (reported to the simulator's owner)
        data["effects"]["second_mode"].update(enabled=True, frequency_hz=f, modal_mass_kg=150.0)
        return {"frequency_hz": f}
    if effect == "joint_microslip":
        # a joint that was part of the rods' stiffness: stuck, the rig is as configured
        kj = float(rng.uniform(0.25, 0.4)) * k
        fs = kj * float(rng.uniform(20e-6, 40e-6))
        data["structure"]["stiffness_x_n_per_m"] -= kj
        data["structure"]["stiffness_y_n_per_m"] -= kj
        data["effects"]["joint_microslip"] = {"enabled": True, "mode": "housing",
                                              "stiffness_n_per_m": kj, "slip_force_n": fs}
        return {"slip_force_N": fs, "stiffness_N_per_m": kj}
    if effect == "viscosity_drift":
        rel = -float(rng.uniform(0.12, 0.25))
        rate = -math.log1p(rel) / (VISCOSITY_SLOPE_PER_C * duration_s)
        data["effects"]["viscosity_drift"] = {"enabled": True, "warming_c_per_s": rate}
        return {"relative_change": rel}
    if effect == "sensor_gain":
        ch = PROBES[int(rng.integers(0, 4))]
        g = 1.0 + sign * float(rng.uniform(0.03, 0.08))
        data["effects"]["probe_gain_error"] = {"enabled": True, "channel": ch, "gain_ratio": g}
        return {"channel": ch, "gain_ratio": g}
    if effect == "channel_delay":
        ch = PROBES[int(rng.integers(0, 4))]
        d = float(rng.uniform(1e-4, 5e-4))
        data["effects"]["channel_delay"] = {"enabled": True, "channel": ch, "delay_s": d}
        return {"channel": ch, "delay_s": d}
    if effect == "air_entrainment":
        c = float(rng.uniform(6, 14))
        data["effects"]["air_entrainment"].update(enabled=True, coefficient_s_per_m=c)
        return {"coefficient_s_per_m": c}
    raise ValueError(f"no generator for effect {effect!r}")


def dwell_plan(rng: np.random.Generator, n_dwells: int, config: RigParams
               ) -> list[tuple[float, float, str]]:
    """(frequency [Hz], force amplitude [N], motion) per dwell, in a seeded random order."""
    freqs = [20.0, 30.0, 40.0, 50.0, 60.0]
    levels_m = list(np.linspace(15e-6, 45e-6, max(1, math.ceil(n_dwells / len(freqs)))))
    motions = ("x", "y", "circular_forward")
    st, film = config.structure, config.film
    m_t = st.mass_kg + film.fluid_mass_kg + film.added_mass()
    c_t = st.residual_damping_ns_per_m + film.eq16_damping_centred(film.reference_viscosity()[0])
    plan = []
    i = 0
    for lv in levels_m:
        for f in freqs:
            w = 2 * math.pi * f
            z = abs(complex(st.stiffness_x_n_per_m - w * w * m_t, w * c_t))
            force = z * lv + 1.1 * config.seal.friction_force_n
            plan.append((f, force, motions[i % 3]))
            i += 1
    plan = plan[:n_dwells]
    order = rng.permutation(len(plan))
    return [plan[j] for j in order]


def make_case(tmp: Path, effects: list[str], seed: int, n_dwells: int = 15,
              record_s: float = 0.25, settle_s: float = 0.2, n_runs: int = 1) -> Case:
    """Generate ``n_runs`` runs with ``effects`` hidden (none: clean data) under ``tmp``.

    The runs share the true rig; each has its own dwell order and noise.
    """
    rng = np.random.default_rng(seed)
    config = config_rig()
    plans = [dwell_plan(rng, n_dwells, config) for _ in range(n_runs)]
    ramp_s = 0.05
    per_dwell = [[2 * ramp_s + settle_s + math.ceil(record_s * f) / f for f, _, _ in plan]
                 for plan in plans]
    duration = LEAD_IN_S + sum(per_dwell[0])
    data = config.model_dump(mode="python")
    truths = {e: draw_effect(e, rng, data, duration) for e in effects}
    truth = RigParams.model_validate(data)
    case = Case(truths, config, truth)
    for k, (plan, spans) in enumerate(zip(plans, per_dwell, strict=True)):
        name = f"hidden-{'-'.join(effects) or 'clean'}-{seed}" + (f"-run{k}" if n_runs > 1 else "")
        path, dur = _record(Path(tmp) / f"{name}.h5", config, truth, plan, spans, seed + 1000 * k,
                            ramp_s, settle_s, record_s)
        case.paths.append(path)
        case.duration_s = max(case.duration_s, dur)
    return case


def _record(path: Path, config: RigParams, truth: RigParams, plan: list, per_dwell: list,
            seed: int, ramp_s: float, settle_s: float, record_s: float) -> tuple[Path, float]:
    """Drive the true rig through ``plan`` and write the run file; return (path, duration)."""
    cm = default_channel_map()
    fs = cm.sample_rate_hz
    backend = SimulatedBackend(truth, seed=seed)
    backend.configure(cm)
    backend.set_do("pump", True)
    backend.start()
    writer = RunWriter.create(
        path, f"hidden-{seed}", "sweep", cm.to_json_dict()["ai"], cm.ao_names, fs,
        channel_map=cm.to_json_dict(), rig_config=config.model_dump(mode="json"),
        test_spec={"generator": "tests/analysis/hidden_effects.py", "seed": seed},
        lubricated=True, flush_interval_s=0, overwrite=True, swmr=False)
    n_ao = len(cm.ao)
    sample = 0

    def push(ao: np.ndarray) -> np.ndarray:
        nonlocal sample
        backend.write_ao(ao)
        ai = cm.to_engineering(backend.read_ai(ao.shape[1]))
        writer.on_block(sample, ai, ao)
        sample += ao.shape[1]
        return ai

    try:
        push(np.zeros((n_ao, int(LEAD_IN_S * fs))))
        for index, ((f, force, motion), span_s) in enumerate(zip(plan, per_dwell,
                                                                 strict=True)):
            n = int(round(span_s * fs))
            t = (sample + np.arange(n)) / fs
            tl = np.arange(n) / fs
            env = np.clip(np.minimum(tl / ramp_s, (span_s - tl) / ramp_s), 0.0, 1.0)
            w = 2 * math.pi * f
            ax_v = force / truth.shaker.force_per_volt_n
            ux = ax_v * np.cos(w * t) if motion in ("x", "circular_forward") else 0.0 * t
            uy = ax_v * np.sin(w * t) if motion in ("y", "circular_forward") else 0.0 * t
            if motion == "y":
                uy = ax_v * np.cos(w * t)
            ao = np.zeros((n_ao, n))
            ao[cm.ao_for_axis("x")] = env * ux
            ao[cm.ao_for_axis("y")] = env * uy
            first = sample
            ai = push(ao)
            a = int(round((ramp_s + settle_s) * fs))
            b = a + int(round(math.ceil(record_s * f) / f * fs))
            z = step_harmonics(ai[:, a:b], first + a, fs, f)
            harm = {name: [[float(v.real), float(v.imag)] for v in z[row]]
                    for row, name in enumerate(cm.ai_names)}
            writer.on_step(StepRecord.from_wire({
                "index": index, "freq_hz": f, "target_kind": "load", "target_value": force,
                "motion": motion, "first_sample": first + a, "last_sample": first + b,
                "updates": 0, "converged": True, "reason": "", "harmonics": harm,
                "drive_v": {nm: [0.0, 0.0] for nm in cm.ao_names},
            }))
    finally:
        writer.close()
    return path, sample / fs
