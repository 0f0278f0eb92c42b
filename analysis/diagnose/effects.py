"""The effect library: candidate terms of the rig model, each with named, fitted parameters.

Every effect is a term the simulator itself has (``RigParams.effects``, the seal, the film, the
structure) or a measurement-chain term (channel gain, channel delay), so a fitted effect writes
straight into a rig TOML the simulator loads. Effect ids and parameter names are part of the JSON
contract of ``sfdrig diagnose``:

==========================  ==============================================================
id                          parameters (main parameter first)
==========================  ==============================================================
coulomb_friction            friction_force_N (dry friction against the velocity vector)
cubic_stiffness             k3_N_per_m3 (F = k3 z^3 per axis)
quadratic_stiffness         k2_N_per_m2 (F = k2 z^2 per axis)
amplitude_dependent_damping clearance_m: the c in the film's eccentricity law
                            (1 + 2 eps^2) / (1 - eps^2)^2, eps = |r| / c, centred damping held
added_mass                  added_mass_kg (mass added to the configured structure mass)
cross_coupling              c_xy_Ns_per_m, c_yx_Ns_per_m, d_xy_kg, d_yx_kg (film cross terms;
                            fitted: those from a driven axis into the other)
second_mode                 frequency_hz, modal_mass_kg, damping_ratio (the frame as a second
                            mass-spring)
joint_microslip             mode, slip_force_N, stiffness_N_per_m, shape (a smooth hysteretic
                            element, Bouc-Wen of exponent 1: shape 1 Dahl's micro-slip, 0
                            elastic unloading, a seal's pre-sliding; beside the spring of a
                            mode: the housing's, or the frame's once a second mode is in the
                            model; the spring gives up the joint's stiffness up to half of it,
                            so at small motion the model is unchanged, and stays positive
                            however stiff the joint: a seal stiffer than the rods is in the
                            family)
viscosity_drift             relative_change (film damping, end of data / start - 1), following
                            the recorded oil temperature where it changes (eq. 1), else time
sensor_gain                 channel, gain_ratio (recorded / true)
channel_delay               channel, delay_s
air_entrainment             coefficient_s_per_m (L_eff = L (1 - k mean|v|))
==========================  ==============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from analysis.diagnose.data import RunRecord, driven_axes
from analysis.diagnose.hysteresis import joint_describing_function
from analysis.diagnose.model import Model, Param, get_path, set_path
from analysis.diagnose.oil import drift_course
from analysis.diagnose.residual_analysis import harmonics
from analysis.diagnose.residual_structure import Z_STRUCTURE
from analysis.diagnose.start import stands_above_noise
from rig_model.params import VISCOSITY_SLOPE_PER_C, RigParams


@dataclass
class Context:
    """What the effects need to know about the data and the baseline."""

    records: list[RunRecord]
    base: Model  # the baseline model (configured masses etc. are read from it)
    fitted_baseline: bool
    duration_s: float
    x_rms_m: float  # RMS displacement of the response channels
    f_rms_n: float  # RMS force
    f_typ_hz: float  # typical excitation frequency

    @property
    def lubricated(self) -> bool:
        return any(r.lubricated for r in self.records)

    @property
    def two_axes(self) -> bool:
        """Some run measures a response on both axes (a cross term shows in the response of
        the axis it couples into)."""
        return any({ax for ax, _ in r.objective_channels().values()} >= {0, 1}
                   for r in self.records)

    def driven_axes(self) -> set[int]:
        """The axes some run drives (``data.driven_axes``: a load cell's noise on an axis
        nobody drives does not count)."""
        return set().union(*(driven_axes(r) for r in self.records))

    def redundant_channels(self) -> list[str]:
        """Objective channels (probes, accelerometers, velocity sensors) that share their axis
        with another one in the same run, and respond (`responds`): the pairs whose
        disagreement is a sensor fault. A channel at its noise holds nothing of its gain or
        delay (a fit of either only scales or shifts noise)."""
        out: list[str] = []
        for r in self.records:
            chans = {ch: ax for ch, (ax, _) in r.objective_channels().items()
                     if responds(r, ch)}
            axes = list(chans.values())
            for ch, ax in chans.items():
                if axes.count(ax) > 1 and ch not in out:
                    out.append(ch)
        return out


def responds(rec: RunRecord, ch: str) -> bool:
    """Whether channel ``ch`` shows the drive: its 1X stands above its own noise in some dwell
    (`start.stands_above_noise`). A run without dwells is not judged (True)."""
    dwells = [(s, s.freq_hz) for s in rec.segments if s.freq_hz]
    if not dwells:
        return True
    sig = rec.signal(ch)
    for s, f_hz in dwells:
        z, _, rest = harmonics(sig[s.start:s.stop], s.start, rec.sample_rate_hz, f_hz, 1)
        if stands_above_noise(abs(z[0]), rest, s.stop - s.start):
            return True
    return False


@dataclass
class Variant:
    """One way to fit an effect: fixed labels (e.g. the channel), parameters, start models."""

    labels: dict[str, Any]
    params: list[Param]
    starts: list[Model]
    keep: int = 1  # starts refined after screening (more where the error surface is rugged)
    #: a fitted baseline follows the screened parameters to first order (`fitting.Following`);
    #: off where the variant keeps the baseline's linear fit itself (the joint)
    follow: bool = True


@dataclass
class Effect:
    id: str
    description: str
    main: str  # main parameter name (the size of the effect a finding reports)
    tolerance: float  # relative accuracy documented for the main parameter
    kind: str = "structure"  # "structure" | "measurement"
    extra: dict[str, Any] = field(default_factory=dict)

    def applicable(self, ctx: Context) -> str | None:
        """None when the effect can be fitted on this data, else the reason it cannot."""
        return _APPLICABLE[self.id](ctx)

    def variants(self, ctx: Context, model: Model) -> list[Variant]:
        return _VARIANTS[self.id](ctx, model)


# --- helpers -----------------------------------------------------------------------------
def _stiffness(ctx: Context) -> float:
    st = ctx.base.rig.structure
    return 0.5 * (st.stiffness_x_n_per_m + st.stiffness_y_n_per_m)


def _enable(path: str) -> Any:
    def setter(m: Model, v: float, _p: str = path) -> Model:
        m = set_path(m, _p.rsplit(".", 1)[0] + ".enabled", True)
        return set_path(m, _p, float(v))
    return setter


def _effect_param(name: str, path: str, scale: float, lo: float = -math.inf,
                  hi: float = math.inf) -> Param:
    def get(m: Model, _p: str = path) -> float:
        enabled = get_path(m, _p.rsplit(".", 1)[0] + ".enabled")
        return float(get_path(m, _p)) if enabled else 0.0
    return Param(name, get, _enable(path), scale, lo, hi)


def _needs_film(ctx: Context) -> str | None:
    return None if ctx.lubricated else "no lubricated run: the film is off"


def _always(ctx: Context) -> str | None:
    return None


# --- the library -------------------------------------------------------------------------
def _friction(ctx: Context, m: Model) -> list[Variant]:
    seal = m.rig.seal
    f0 = seal.friction_force_n if seal.enabled else 0.0

    def get(mm: Model) -> float:
        return mm.rig.seal.friction_force_n if mm.rig.seal.enabled else 0.0

    def put(mm: Model, v: float) -> Model:
        return set_path(set_path(mm, "seal.enabled", True), "seal.friction_force_n", float(v))

    scale = max(f0, 0.05 * ctx.f_rms_n)
    start = f0 if f0 > 0 else 0.05 * ctx.f_rms_n
    p = Param("friction_force_N", get, put, 0.3 * scale, 0.0)
    return [Variant({}, [p], [put(m, start)])]


def _cubic(ctx: Context, m: Model) -> list[Variant]:
    scale = 0.1 * _stiffness(ctx) / ctx.x_rms_m**2
    p = _effect_param("k3_N_per_m3", "effects.cubic_stiffness.k3_n_per_m3", scale)
    return [Variant({}, [p], [p.set(m, p.get(m))])]


def _quadratic(ctx: Context, m: Model) -> list[Variant]:
    scale = 0.1 * _stiffness(ctx) / ctx.x_rms_m
    p = _effect_param("k2_N_per_m2", "effects.quadratic_stiffness.k2_n_per_m2", scale)
    return [Variant({}, [p], [p.set(m, p.get(m))])]


def _clearance_setter(c0: float, scale0: float, d0: float):
    def put(mm: Model, v: float) -> Model:
        data = mm.rig.model_dump(mode="python")
        film = data["film"]
        film["clearance_m"] = float(v)
        film["damping_scale"] = scale0 * (float(v) / c0) ** 3  # hold the centred damping
        film["added_mass_kg"] = d0  # hold the added mass
        film["eccentricity_law"] = True
        return replace(mm, rig=RigParams.model_validate(data))
    return put


def _amp_damping(ctx: Context, m: Model) -> list[Variant]:
    base_film = ctx.base.rig.film
    put = _clearance_setter(base_film.clearance_m, base_film.damping_scale,
                            base_film.added_mass())
    # eps must stay below 1 over the data: the clearance exceeds the largest orbit radius
    r_max = max(float(np.max(np.hypot(*_xy(r)))) for r in ctx.records)

    def get(mm: Model) -> float:
        return mm.rig.film.clearance_m if mm.rig.film.eccentricity_law else math.inf

    c_now = m.rig.film.clearance_m
    p = Param("clearance_m", get, put, 0.1 * base_film.clearance_m, 1.05 * r_max)
    starts = [put(m, max(c_now, 1.1 * r_max))]
    if not m.rig.film.eccentricity_law:
        starts.append(put(m, max(0.5 * c_now, 1.2 * r_max)))
    return [Variant({}, [p], starts)]


def _xy(r: RunRecord) -> tuple[np.ndarray, np.ndarray]:
    xs = [v for c, v in r.responses.items() if r.response_axis[c] == 0]
    ys = [v for c, v in r.responses.items() if r.response_axis[c] == 1]
    x = np.mean(xs, axis=0) if xs else np.zeros(r.n_samples)
    y = np.mean(ys, axis=0) if ys else np.zeros(r.n_samples)
    return x - np.mean(x), y - np.mean(y)


def _added_mass(ctx: Context, m: Model) -> list[Variant]:
    m0 = ctx.base.rig.structure.mass_kg

    def get(mm: Model) -> float:
        return mm.rig.structure.mass_kg - m0

    def put(mm: Model, v: float) -> Model:
        return set_path(mm, "structure.mass_kg", m0 + float(v))

    p = Param("added_mass_kg", get, put, 0.05 * m0, -0.9 * m0)
    return [Variant({}, [p], [m])]


def _cross(ctx: Context, m: Model) -> list[Variant]:
    """The film's cross terms the data can show: those from a driven axis into the other
    (C_yx, D_yx where x is driven: y's response to x's motion). The terms back from an
    undriven axis act only through its small coupled motion; fitted beside the others they are
    nearly free (a 43 kN.s/m C_xy on x-only dwells), so they stay as they are."""
    c0 = ctx.base.rig.film.eq16_damping_centred(ctx.base.rig.film.reference_viscosity()[0])
    d0 = max(ctx.base.rig.film.added_mass(), 1.0)
    into = {0: ("c_yx_Ns_per_m", "d_yx_kg"), 1: ("c_xy_Ns_per_m", "d_xy_kg")}
    names = [n for ax in sorted(ctx.driven_axes()) for n in into[ax]]
    path = {"c_xy_Ns_per_m": "c_xy_ns_per_m", "c_yx_Ns_per_m": "c_yx_ns_per_m",
            "d_xy_kg": "d_xy_kg", "d_yx_kg": "d_yx_kg"}
    ps = [_effect_param(n, f"effects.cross_coupling.{path[n]}",
                        0.1 * (c0 if n.startswith("c_") else d0))
          for n in sorted(names, key=list(path).index)]
    return [Variant({}, ps, [ps[0].set(m, ps[0].get(m))])]


def _second_mode(ctx: Context, m: Model) -> list[Variant]:
    fs = min(r.sample_rate_hz for r in ctx.records)
    pf = _effect_param("frequency_hz", "effects.second_mode.frequency_hz", 3.0, 2.0, fs / 4)
    pm = _effect_param("modal_mass_kg", "effects.second_mode.modal_mass_kg",
                       0.3 * ctx.base.rig.structure.mass_kg, 0.05 * ctx.base.rig.structure.mass_kg)
    # start from the configured frame; on a fitted (e.g. imported, unknown scale) structure,
    # from the fitted mass
    # the frame's damping is fitted too: a mode in the band is seen through its damping as
    # much as through its frequency, and a fixed ratio leaves its share as structure
    pz = _effect_param("damping_ratio", "effects.second_mode.damping_ratio", 0.01, 1e-4, 0.5)
    mass0 = (ctx.base.rig.structure.mass_kg if ctx.fitted_baseline
             else ctx.base.rig.effects.second_mode.modal_mass_kg)
    zeta0 = ctx.base.rig.effects.second_mode.damping_ratio
    f_lo, f_hi = 0.3 * ctx.f_typ_hz, min(3.0 * ctx.f_typ_hz, fs / 4)
    starts = []
    for f in np.geomspace(f_lo, f_hi, 15):
        for mass in (mass0, 4 * mass0):
            starts.append(pz.set(pm.set(pf.set(m, float(f)), mass), zeta0))
    return [Variant({}, [pf, pm, pz], starts, keep=3)]


def _spring_beside_joint(spring: float, k_old: float, k_new: float) -> float:
    """A mode's spring once the stiffness the joint beside it takes goes from ``k_old`` to
    ``k_new`` (`_joint`: the stuck stiffness, or its equivalent stiffness at the data's
    typical amplitude).

    Of the spring ``R`` the mode has without the joint, the joint takes ``k``, ``R - k``, up to
    half of it; beyond, ``R^2 / (4 k)`` (the same value and slope at ``k = R / 2``), which stays
    positive for any ``k``: a joint or seal stiffer than the spring itself has a stuck
    stiffness above ``R``, and a refit that moves the spring and the joint together keeps the
    model valid.
    """
    r = spring + k_old if spring >= k_old else 2.0 * math.sqrt(k_old * spring)
    return r - k_new if k_new <= 0.5 * r else r * r / (4.0 * k_new)


def _joint(ctx: Context, m: Model) -> list[Variant]:
    """A micro-slipping joint beside the spring of each mode the model has.

    The joint takes from the mode's spring (the structure's stiffness per axis, or the frame's
    through its frequency) what it adds, up to half of it (`_spring_beside_joint`), so only
    its amplitude dependence (softening, dissipation) is new: on a configured baseline its
    stuck stiffness k_j (the model at small motion is as configured); on a fitted one, which
    has absorbed the joint's mean stiffness, its equivalent stiffness at the data's typical
    amplitude (the describing function: the linear fit stays where it was). Its stiffness may
    exceed the spring's (a seal stiffer than the rods)."""
    k_struct = _stiffness(ctx)
    typical_amplitude_m = math.sqrt(2.0) * ctx.x_rms_m

    def taken(j: dict[str, Any]) -> float:
        if not j["enabled"]:
            return 0.0
        if not ctx.fitted_baseline:
            return float(j["stiffness_n_per_m"])
        return joint_describing_function(j["stiffness_n_per_m"], j["slip_force_n"],
                                         typical_amplitude_m, j["shape"])[0]

    def put(mm: Model, mode: str, **change: float) -> Model:
        data = mm.rig.model_dump(mode="python")
        j = data["effects"]["joint_microslip"]
        old = taken(j)
        j.update(enabled=True, mode=mode, **change)
        new = taken(j)
        if mode == "housing":
            st = data["structure"]
            for key in ("stiffness_x_n_per_m", "stiffness_y_n_per_m"):
                st[key] = _spring_beside_joint(st[key], old, new)
        else:
            sm = data["effects"]["second_mode"]
            k_fr = sm["modal_mass_kg"] * (2 * math.pi * sm["frequency_hz"]) ** 2
            k_fr = _spring_beside_joint(k_fr, old, new)
            sm["frequency_hz"] = math.sqrt(k_fr / sm["modal_mass_kg"]) / (2 * math.pi)
        return replace(mm, rig=RigParams.model_validate(data))

    def get_k(mm: Model) -> float:
        j = mm.rig.effects.joint_microslip
        return j.stiffness_n_per_m if j.enabled else 0.0

    def get_f(mm: Model) -> float:
        return mm.rig.effects.joint_microslip.slip_force_n

    def get_shape(mm: Model) -> float:
        return mm.rig.effects.joint_microslip.shape

    out = []
    modes = ["housing"] + (["frame"] if m.rig.effects.second_mode.enabled else [])
    for mode in modes:
        def put_k(mm: Model, v: float, _mode: str = mode) -> Model:
            return put(mm, _mode, stiffness_n_per_m=max(float(v), 0.0))

        def put_f(mm: Model, v: float, _mode: str = mode) -> Model:
            return put(mm, _mode, slip_force_n=float(v))

        def put_shape(mm: Model, v: float, _mode: str = mode) -> Model:
            return put(mm, _mode, shape=min(max(float(v), 0.0), 1.0))

        if mode == "housing":
            k_mode = min(m.rig.structure.stiffness_x_n_per_m, m.rig.structure.stiffness_y_n_per_m)
        else:
            sm = m.rig.effects.second_mode
            k_mode = sm.modal_mass_kg * (2 * math.pi * sm.frequency_hz) ** 2
        f0 = 0.3 * k_mode * ctx.x_rms_m
        # the upper bound only keeps the search finite: a joint 30x stiffer than the mode's
        # spring is stuck rigid over any motion the data show
        pk = Param("stiffness_N_per_m", get_k, put_k, 0.1 * k_struct, 0.0, 30.0 * k_mode)
        pf = Param("slip_force_N", get_f, put_f, 0.3 * f0, 1e-3 * f0)
        # the law's shape: Dahl (1) to elastic unloading (0), the smooth Bouc-Wen seal; both
        # ends are laws, not a fit held on a bound
        ps = Param("shape", get_shape, put_shape, 0.2, 0.0, 1.0, ends_are_models=True)
        # stuck stiffness below and above the spring's (a seal stiffer than the rods), each law
        starts = [put(m, mode, stiffness_n_per_m=k0, slip_force_n=k0 * ctx.x_rms_m * r,
                      shape=shape)
                  for k0 in (0.3 * k_mode, 2.0 * k_mode) for r in (0.5, 1.0, 2.0)
                  for shape in (0.0, 1.0)]
        # the joint keeps the fitted baseline's linear model itself, exactly where following
        # holds to first order only (a stiff joint is far from first order)
        out.append(Variant({"mode": mode}, [pf, pk, ps], starts, keep=2, follow=False))
    return out


def _visc_drift(ctx: Context, m: Model) -> list[Variant]:
    p = Param("relative_change", lambda mm: mm.visc_relative_change,
              lambda mm, v: replace(mm, visc_relative_change=float(v)), 0.05, -0.9, 10.0)
    # the course it follows: the recorded oil temperature where it changes, else time
    follows = drift_course(ctx.records, Z_STRUCTURE).describe()
    return [Variant({"follows": follows}, [p], [m])]


def _channel_param(name: str, attr: str, ch: str, default: float, scale: float, lo: float,
                   hi: float) -> Param:
    """A per-channel measurement term (``Model.gain`` or ``Model.delay_s``) of channel ``ch``."""
    def get(mm: Model) -> float:
        return getattr(mm, attr).get(ch, default)

    def put(mm: Model, v: float) -> Model:
        terms: dict[str, Any] = {attr: {**getattr(mm, attr), ch: float(v)}}
        return replace(mm, **terms)

    return Param(name, get, put, scale, lo, hi)


def _sensor_gain(ctx: Context, m: Model) -> list[Variant]:
    out = []
    for ch in ctx.redundant_channels():
        p = _channel_param("gain_ratio", "gain", ch, 1.0, 0.02, 0.2, 5.0)
        out.append(Variant({"channel": ch}, [p], [m]))
    return out


def _delay(ctx: Context, m: Model) -> list[Variant]:
    out = []
    fs = min(r.sample_rate_hz for r in ctx.records)
    for ch in ctx.redundant_channels():
        p = _channel_param("delay_s", "delay_s", ch, 0.0, 0.5 / fs, 0.0, 0.01)
        out.append(Variant({"channel": ch}, [p], [p.set(m, 0.5 / fs)]))
    return out


def _air(ctx: Context, m: Model) -> list[Variant]:
    v_mean = 2 * math.pi * ctx.f_typ_hz * ctx.x_rms_m * math.sqrt(2) * 2 / math.pi
    scale = 0.05 / max(v_mean, 1e-9)
    p = _effect_param("coefficient_s_per_m", "effects.air_entrainment.coefficient_s_per_m",
                      scale, 0.0)
    return [Variant({}, [p], [p.set(m, 0.5 * scale)])]


def _needs_config_mass(ctx: Context) -> str | None:
    if ctx.fitted_baseline:
        return "the fitted baseline fits the mass already"
    return None


def _needs_two_axes_film(ctx: Context) -> str | None:
    if not ctx.two_axes:
        return "needs a response measured on both axes (a sensor on x and one on y)"
    if not ctx.driven_axes():
        return "no axis is driven"
    return _needs_film(ctx)


def _needs_redundant(ctx: Context) -> str | None:
    if not ctx.redundant_channels():
        return ("no redundant sensor (a second probe or an accelerometer on the axis) to tell a "
                "sensor fault from the rig")
    return None


_APPLICABLE = {
    "coulomb_friction": _always,
    "cubic_stiffness": _always,
    "quadratic_stiffness": _always,
    "amplitude_dependent_damping": _needs_film,
    "added_mass": _needs_config_mass,
    "cross_coupling": _needs_two_axes_film,
    "second_mode": _always,
    "joint_microslip": _always,
    "viscosity_drift": _needs_film,
    "sensor_gain": _needs_redundant,
    "channel_delay": _needs_redundant,
    "air_entrainment": _needs_film,
}
_VARIANTS = {
    "coulomb_friction": _friction,
    "cubic_stiffness": _cubic,
    "quadratic_stiffness": _quadratic,
    "amplitude_dependent_damping": _amp_damping,
    "added_mass": _added_mass,
    "cross_coupling": _cross,
    "second_mode": _second_mode,
    "joint_microslip": _joint,
    "viscosity_drift": _visc_drift,
    "sensor_gain": _sensor_gain,
    "channel_delay": _delay,
    "air_entrainment": _air,
}

#: The library, in a fixed order. Tolerances: the relative accuracy documented for each main
#: parameter (10 %; 15 % for the terms that trade off against the film's damping or mass, 20 %
#: for the hysteretic joint). Tests write their own criteria from the accuracy they measure.
LIBRARY: dict[str, Effect] = {e.id: e for e in [
    Effect("coulomb_friction", "dry friction (seal) against the velocity vector",
           "friction_force_N", 0.10),
    Effect("cubic_stiffness", "hardening or softening spring, F = k3 z^3", "k3_N_per_m3", 0.10),
    Effect("quadratic_stiffness", "asymmetric spring, F = k2 z^2", "k2_N_per_m2", 0.10),
    Effect("amplitude_dependent_damping",
           "film damping rising with amplitude (eccentricity law, eq. 16)", "clearance_m", 0.10),
    Effect("added_mass", "mass beyond the configured structure and film", "added_mass_kg", 0.10),
    Effect("cross_coupling", "cross-coupled film damping and mass between x and y",
           "c_xy_Ns_per_m", 0.15),
    Effect("second_mode", "a second structural mode (the frame)", "frequency_hz", 0.10),
    Effect("joint_microslip",
           "a joint micro-slipping beside a mode's spring (Bouc-Wen, Dahl to elastic "
           "unloading): the mode softens and damps more with the level", "slip_force_N", 0.20),
    Effect("viscosity_drift", "film damping drifting over the data (oil warming)",
           "relative_change", 0.15),
    Effect("sensor_gain", "a response sensor whose gain is off (recorded / true)", "gain_ratio",
           0.10, kind="measurement"),
    Effect("channel_delay", "a response channel delayed in time", "delay_s", 0.10,
           kind="measurement"),
    Effect("air_entrainment", "film damping and added mass lost to air at speed",
           "coefficient_s_per_m", 0.15),
]}


def parameters_of(variant: Variant, model: Model) -> dict[str, Any]:
    """The finding's parameters (JSON-safe): labels first, then the fitted values."""
    out: dict[str, Any] = dict(variant.labels)
    for p in variant.params:
        out[p.name] = float(p.get(model))
    return out


def extended_rig(model: Model, duration_s: float, drift_anchor: float = 0.0) -> RigParams:
    """The rig configuration the simulator loads: model terms written into ``RigParams``.

    Measurement terms become ``effects.probe_gain_error`` / ``effects.channel_delay`` (one
    channel each, as the simulator supports); a viscosity drift becomes the warming rate that
    gives the same damping change over ``duration_s`` through eq. 1, from the temperature
    ``drift_anchor`` of the drift before the model's own (``Evaluator.drift_anchor``: a film
    held at the data's mean temperature is half-way through a steady warming).
    """
    data = model.rig.model_dump(mode="python")
    eff = data["effects"]
    for ch, g in model.gain.items():
        if g != 1.0:
            eff["probe_gain_error"] = {"enabled": True, "channel": ch, "gain_ratio": float(g)}
    for ch, d in model.delay_s.items():
        if d != 0.0:
            eff["channel_delay"] = {"enabled": True, "channel": ch, "delay_s": float(d)}
    if model.visc_relative_change != 0.0:
        rate = -math.log1p(model.visc_relative_change) / (VISCOSITY_SLOPE_PER_C * duration_s)
        prev = eff["viscosity_drift"]["warming_c_per_s"] if eff["viscosity_drift"]["enabled"] \
            else 0.0
        eff["viscosity_drift"] = {"enabled": True, "warming_c_per_s": prev + rate}
        data["oil"]["initial_temperature_c"] -= drift_anchor * rate * duration_s
    return RigParams.model_validate(data)
