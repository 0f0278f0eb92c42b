"""Parameters of the simulated rig, loadable from TOML. Defaults are the reference report's.

Sources: M, K_sx, K_sy (Tables 1-2, eq. 6 footnote); C_rv and F_mu (Table 4); film geometry,
density and viscosity (section III.2, Table 5); fluid mass M_f (section VI.2); added mass by
eq. 15; film damping by eq. 16; shaker rating 448 N (section III).
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from daq.config_files import read_toml, to_toml, validate

VISCOSITY_SLOPE_PER_C = 0.01665  # eq. 1 exponent [1/degC]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Structure(_Model):
    mass_kg: float = Field(9.7, gt=0, description="housing effective mass M (Table 1; X only "
                           "where mass_y_kg is set) [kg]")
    stiffness_x_n_per_m: float = Field(788e3, gt=0, description="K_sx (static tests) [N/m]")
    stiffness_y_n_per_m: float = Field(823e3, gt=0, description="K_sy (static tests) [N/m]")
    stiffness_xy_n_per_m: float = Field(
        0.0, description="k_xy, the rods' cross stiffness (their principal axes turned away "
        "from the probes' x and y): force -k_xy y on x and -k_xy x on y; a rod set has "
        "|k_xy| < sqrt(K_sx K_sy) (checked where a rig file is read) [N/m]")
    residual_damping_ns_per_m: float = Field(370.0, ge=0, description="C_rv (Table 4) [N.s/m]")
    mass_y_kg: float | None = Field(
        None, gt=0, description="M along Y where it differs (Table 3: 8.8 kg X, 9.7 kg Y); None: "
        "mass_kg for both axes [kg]")
    residual_damping_y_ns_per_m: float | None = Field(
        None, ge=0, description="C_rv along Y where it differs (Table 3: 367 X, 315 Y); None: "
        "residual_damping_ns_per_m for both axes [N.s/m]")

    def mass_y(self) -> float:
        return self.mass_kg if self.mass_y_kg is None else self.mass_y_kg

    def residual_damping_y(self) -> float:
        return (self.residual_damping_ns_per_m if self.residual_damping_y_ns_per_m is None
                else self.residual_damping_y_ns_per_m)


class Seal(_Model):
    enabled: bool = True
    friction_force_n: float = Field(26.0, ge=0, description="F_mu, dry friction (Table 4) [N]")
    contact_stiffness_n_per_m: float | None = Field(
        None, gt=0, le=1e10,
        description="tangential stiffness of the seal contact, in series with the slider (an "
        "Iwan element: below F_mu the housing moves on it); None: rigid sticking [N/m]")
    wet_friction_increase_n: float = Field(
        0.0, ge=-100, le=100,
        description="added to F_mu while the film is full, in proportion to the fill (issue 28: "
        "the oil's pressure in the recirculation annulus loads the ring beside the wave spring, "
        "or the wetted faces rub otherwise); 0: the dry friction throughout [N]")
    contact_stiffness_y_n_per_m: float | None = Field(
        None, gt=0, le=1e10,
        description="the contact's tangential stiffness along Y where it differs (issue 28: the "
        "ring carrier held differently by axis); None: contact_stiffness_n_per_m [N/m]")


class Contact(_Model):
    """The journal as a wall at the radial clearance (steel on steel, oiled).

    The report gives no contact values: restitution 0.3 and mu 0.15 are assumed, typical of
    oiled steel on steel; what matters for the tests is that nothing passes the wall."""

    enabled: bool = True
    restitution: float = Field(0.3, ge=0, le=1, description="coefficient of restitution")
    friction_coefficient: float = Field(0.15, ge=0, le=1, description="mu at the contact")


class Film(_Model):
    diameter_m: float = Field(0.127, gt=0)
    length_m: float = Field(0.0254, gt=0)
    clearance_m: float = Field(127e-6, gt=0)
    density_kg_per_m3: float = Field(736.0, gt=0)
    viscosity_source: Literal["table5", "eq1"] = Field(
        "table5",
        description="table5: 3.17 cP at 24 degC (Table 5); eq1: 2.8 cP at 23.6 degC (eq. 1)",
    )
    fluid_mass_kg: float = Field(0.62, ge=0, description="M_f, oil in plenum and annulus [kg]")
    added_mass_kg: float | None = Field(None, ge=0, description="D; None: eq. 15 [kg]")
    damping_scale: float = Field(1.0, gt=0, description="multiplies eq. 16 (1 = the formula)")
    eccentricity_law: bool = Field(
        True, description="eq. 16's (1+2 eps^2)/(1-eps^2)^2 with the instantaneous eps = |r|/c"
    )

    def reference_viscosity(self) -> tuple[float, float]:
        """(viscosity [Pa.s], at temperature [degC]) that anchors eq. 1's temperature law."""
        return (3.17e-3, 24.0) if self.viscosity_source == "table5" else (2.8e-3, 23.6)

    def viscosity_pa_s(self, temperature_c: float) -> float:
        mu0, t0 = self.reference_viscosity()
        return mu0 * math.exp(-VISCOSITY_SLOPE_PER_C * (temperature_c - t0))

    def eq15_added_mass_kg(self) -> float:
        r = self.diameter_m / 2
        return 0.5 * self.density_kg_per_m3 * math.pi * r * (2 * self.length_m) ** 3 / (
            10 * self.clearance_m
        )

    def added_mass(self) -> float:
        return self.eq15_added_mass_kg() if self.added_mass_kg is None else self.added_mass_kg

    def eq16_damping_centred(self, viscosity_pa_s: float) -> float:
        """C_rr at eps = 0 (eq. 16) [N.s/m], times ``damping_scale``."""
        c = self.clearance_m
        return (
            self.damping_scale * viscosity_pa_s * self.diameter_m
            * (self.length_m / c) ** 3 * math.pi / 2
        )

    def eq5_flow_m3_per_s(self, dp_pa: float, viscosity_pa_s: float) -> float:
        return math.pi * self.diameter_m * self.clearance_m**3 * dp_pa / (
            12 * viscosity_pa_s * self.length_m
        )


class Oil(_Model):
    supply_pressure_pa: float = Field(15.5e3, ge=0, description="inlet P_s, pump on (Table 5)")
    recirculation_pressure_pa: float = Field(5.7e3, ge=0, description="P_r, pump on (Table 5)")
    pressure_time_constant_s: float = Field(0.5, gt=0)
    fill_time_constant_s: float = Field(1.0, gt=0, description="film filling once pressurised")
    drain_time_constant_s: float = Field(5.0, gt=0, description="film draining, pump off")
    initially_filled: bool = False
    initial_temperature_c: float = Field(24.0, ge=-20, le=120)
    warming_c_per_hour: float = Field(1.0, description="slow warming while the pump runs")


class Shaker(_Model):
    force_per_volt_n: float = Field(50.0, gt=0, description="amplifier + shaker gain [N/V]")
    max_force_n: float = Field(448.0, gt=0, description="rating, 100 lbf (section III) [N]")
    bandwidth_hz: float = Field(1000.0, gt=0, description="first-order corner of the drive")


class SensorNoise(_Model):
    """RMS noise per kind, in the channel's engineering units."""

    load_cell: float = Field(0.05, ge=0)
    eddy_current_probe: float = Field(0.05e-6, ge=0)
    accelerometer: float = Field(0.02, ge=0)
    pressure_4_20mA: float = Field(30.0, ge=0)
    flow: float = Field(0.002, ge=0)
    thermocouple: float = Field(0.02, ge=0)


# --- switchable effects (all off by default) ------------------------------------------------
class CubicStiffness(_Model):
    enabled: bool = False
    k3_n_per_m3: float = Field(0.0, description="F = k3 z^3 per axis [N/m^3]")


class QuadraticStiffness(_Model):
    enabled: bool = False
    k2_n_per_m2: float = Field(0.0, description="F = k2 z^2 per axis [N/m^2]")


class CrossCoupling(_Model):
    enabled: bool = False
    c_xy_ns_per_m: float = 0.0
    c_yx_ns_per_m: float = 0.0
    d_xy_kg: float = 0.0
    d_yx_kg: float = 0.0


class SecondMode(_Model):
    """The frame under the rods as a second mass on its own spring (section IV.3: ~39 Hz)."""

    enabled: bool = False
    frequency_hz: float = Field(39.0, gt=0)
    modal_mass_kg: float = Field(40.0, gt=0)
    damping_ratio: float = Field(0.03, ge=0, lt=1)


class JointMicroslip(_Model):
    """A joint that micro-slips (friction at a bolted or clamped interface, a seal's
    pre-sliding): a smooth hysteretic element per axis beside the spring of ``mode``
    ("housing": the rods, between housing and frame; "frame": the frame's own spring, needs
    ``second_mode``). Its law is Bouc-Wen's of exponent 1 with beta + gamma = 1, F = F_s w,
    dw/dz = (k_j / F_s) (1 - (beta sgn(w z') + gamma) |w|), and ``shape`` = beta - gamma:
    shape 1 is Dahl's law dF/dz = k_j (1 - sgn(z') F / F_s); shape 0 unloads elastically at k_j.

    Stuck (small motion) it adds its stiffness k_j; as the motion grows it slips more and
    more (stiffness falls towards 0, dissipation rises), its force never above F_s: the mode
    softens and damps more with the level."""

    enabled: bool = False
    mode: Literal["housing", "frame"] = "housing"
    stiffness_n_per_m: float = Field(0.0, ge=0, description="k_j, the joint stuck (X; Y too "
                                     "where stiffness_y_n_per_m is None) [N/m]")
    slip_force_n: float = Field(1.0, gt=0, description="F_s, the force of full slip (X; Y too "
                                "where slip_force_y_n is None) [N]")
    stiffness_y_n_per_m: float | None = Field(
        None, ge=0, description="k_j along Y where it differs (issue 28: the rods' clamps "
        "need not hold alike in X and Y); None: stiffness_n_per_m [N/m]")
    slip_force_y_n: float | None = Field(
        None, gt=0, description="F_s along Y where it differs; None: slip_force_n [N]")
    shape: float = Field(
        1.0, ge=0, le=1, description="beta - gamma of the Bouc-Wen law (beta + gamma = 1): "
        "1 Dahl (unloading stiffness k_j (1 + |F| / F_s)), 0 elastic unloading at k_j [-]")

    def stiffness_y(self) -> float:
        return self.stiffness_n_per_m if self.stiffness_y_n_per_m is None \
            else self.stiffness_y_n_per_m

    def slip_force_y(self) -> float:
        return self.slip_force_n if self.slip_force_y_n is None else self.slip_force_y_n


class RelaxingStiffness(_Model):
    """A stiffness the structure has in motion but not under a held load (issue 28): a Maxwell
    element beside the rods, spring k_r in series with a dashpot k_r tau, per axis. Its dynamic
    stiffness is k_r (w tau)^2 / (1 + (w tau)^2) and its damping k_r tau / (1 + (w tau)^2): at
    0 Hz nothing (a static test held for several tau reads the rods alone), above 1/(2 pi tau)
    nearly k_r (an impact or a dwell reads K + k_r). A one-time-constant stand-in for whatever
    relaxes (the acrylic bearing's bolted stack, the O-rings, the feed hose): an approximation,
    the report has no data between 0 Hz and its 20 Hz."""

    enabled: bool = False
    stiffness_x_n_per_m: float = Field(0.0, ge=0, description="k_r along X [N/m]")
    stiffness_y_n_per_m: float = Field(0.0, ge=0, description="k_r along Y [N/m]")
    relaxation_time_s: float = Field(0.1, gt=0, le=100, description="tau [s]")


class AirEntrainment(_Model):
    """Effective film length L_eff = L (1 - alpha), alpha = min(max, k * mean |v|)."""

    enabled: bool = False
    coefficient_s_per_m: float = Field(0.0, ge=0, description="alpha per m/s of mean speed")
    max_fraction: float = Field(0.9, ge=0, lt=1)
    time_constant_s: float = Field(0.05, gt=0, description="averaging of |v|")


class ViscosityDrift(_Model):
    """Oil warming faster than the default, viscosity following eq. 1."""

    enabled: bool = False
    warming_c_per_s: float = Field(0.0, description="oil temperature rate [degC/s]")


class ProbeGainError(_Model):
    enabled: bool = False
    channel: str = "x1"
    gain_ratio: float = Field(1.0, gt=0, description="recorded / true")


class ChannelDelay(_Model):
    enabled: bool = False
    channel: str = "x1"
    delay_s: float = Field(0.0, ge=0, le=0.01)


class ReversedPolarity(_Model):
    """Sensors wired with AI+ and AI- swapped (or an inverting conditioner): the board reads
    minus their output, the gap voltage too. A wiring mistake to rehearse `sfdrig commission`
    on; the map cannot say it (its gains are positive)."""

    enabled: bool = False
    channels: list[str] = Field(default_factory=list, description="AI channel names")


class Effects(_Model):
    cubic_stiffness: CubicStiffness = CubicStiffness()
    quadratic_stiffness: QuadraticStiffness = QuadraticStiffness()
    cross_coupling: CrossCoupling = CrossCoupling()
    second_mode: SecondMode = SecondMode()
    joint_microslip: JointMicroslip = JointMicroslip()
    relaxing_stiffness: RelaxingStiffness = RelaxingStiffness()
    air_entrainment: AirEntrainment = AirEntrainment()
    viscosity_drift: ViscosityDrift = ViscosityDrift()
    probe_gain_error: ProbeGainError = ProbeGainError()
    channel_delay: ChannelDelay = ChannelDelay()
    reversed_polarity: ReversedPolarity = ReversedPolarity()


class RigParams(_Model):
    """Everything the simulated rig needs. ``RigParams()`` is the report's rig."""

    structure: Structure = Structure()
    seal: Seal = Seal()
    contact: Contact = Contact()
    film: Film = Film()
    oil: Oil = Oil()
    shaker: Shaker = Shaker()
    noise: SensorNoise = SensorNoise()
    effects: Effects = Effects()
    journal_in: bool = Field(
        True, description="the journal installed; false: the structure alone (the report's "
        "static and impact tests, `sfdrig commission`'s drives): no seal, no wall at the "
        "clearance, no film (the oil loop's gauges still see the pump)")
    max_step_s: float = Field(
        50e-6, gt=0, le=1e-3,
        description="largest integration step (leapfrog); at 50 us the dynamic stiffness is "
        "within 0.25 % at 60 Hz and the damping within 0.1 N.s/m",
    )
    substeps: int | None = Field(
        None, ge=1, le=4096, description="integration steps per sample; None: from max_step_s"
    )

    @model_validator(mode="after")
    def _joint_on_a_mode(self) -> RigParams:
        j = self.effects.joint_microslip
        if j.enabled and j.mode == "frame" and not self.effects.second_mode.enabled:
            raise ValueError("effects.joint_microslip.mode = 'frame' needs "
                             "effects.second_mode.enabled (the frame mode it sits on)")
        return self

    def steps_per_sample(self, sample_rate_hz: float) -> int:
        if self.substeps is not None:
            return self.substeps
        return max(1, math.ceil(1.0 / (sample_rate_hz * self.max_step_s) - 1e-9))

    def to_toml(self) -> str:
        return to_toml(self.model_dump(mode="json", exclude_none=True))


class RigParamsError(ValueError):
    """An invalid rig file; the message names the field and value."""


def rig_params_from_dict(data: dict[str, Any], source: str = "<dict>") -> RigParams:
    """Rig parameters from a TOML document or dict, every problem named with its field.

    The cross stiffness is checked here, at the boundary, rather than on every `RigParams`:
    a fit moves K_sx, K_sy and k_xy one at a time and may pass through a trial that is no
    rod set (the replay then diverges and scores badly; a refusal would end the fit)."""
    params = validate(RigParams, data, "rig parameters", source, RigParamsError)
    st = params.structure
    if st.stiffness_xy_n_per_m**2 >= st.stiffness_x_n_per_m * st.stiffness_y_n_per_m:
        raise RigParamsError(
            f"invalid rig parameters in {source}:\n  structure.stiffness_xy_n_per_m = "
            f"{st.stiffness_xy_n_per_m!r}: a rod set has |k_xy| < sqrt(K_sx K_sy) = "
            f"{math.sqrt(st.stiffness_x_n_per_m * st.stiffness_y_n_per_m):.6g} N/m")
    return params


def load_rig_params(path: str | Path) -> RigParams:
    return rig_params_from_dict(read_toml(path, RigParamsError), str(path))


# Rigs shipped with the package: "nominal" is RigParams() (the report's stated values); "report"
# is calibrated against the report's measured tables (`sfdrig calibrate`, rig_model/rigs/).
NAMED_RIGS = ("nominal", "report")


def rig_params_named_or_file(name_or_path: str | Path) -> RigParams:
    """A named rig (`NAMED_RIGS`) or a rig TOML file."""
    if str(name_or_path) == "nominal":
        return RigParams()
    if str(name_or_path) in NAMED_RIGS:
        with resources.as_file(resources.files("rig_model") / "rigs" / f"{name_or_path}.toml"
                               ) as path:
            return load_rig_params(path)
    return load_rig_params(name_or_path)
