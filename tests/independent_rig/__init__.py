"""An independent data generator for tests: the rig written a second time, sharing no code with
``simulated_hw`` (different integration: closed-form steady state or scipy's ``solve_ivp``).

Produces the canonical CSV ``time_s, freq_hz, fx_N, fy_N, x_m, y_m, ax_mps2, ay_mps2,
oil_temp_C``. Quick start::

    from tests.independent_rig import Generator, RigSpec, Sensors, grid
    rec = Generator(RigSpec()).run(grid([20, 30, 40, 50, 60], [13e-6, 25e-6, 38e-6], "x"))
    rec.to_csv(tmp_path / "lub.csv")          # rec.segments[k] holds each dwell's truth

Extension points (add hidden effects without editing this package):

- ``RigSpec.extra_forces``: callables ``f(t, z, v) -> (Fx, Fy)``, the force on the housing [N]
  for relative displacement ``z`` and velocity ``v`` (2-vectors) at time ``t``;
- any scalar ``RigSpec`` parameter as a function of time (``film_damping_ns_per_m=lambda t: ...``);
- ``RigSpec.frame = FrameMode(frequency_hz=39.0)``: the frame as a second mode;
- ``RigSpec.stiffness_xy_n_per_m``: the rods' cross stiffness (principal axes turned from x, y);
- ``RigSpec.film_cross_damping_ns_per_m`` / ``film_cross_mass_kg``: the film's cross-coupled
  damping and added mass (C_xy, C_yx; D_xy, D_yx);
- ``RigSpec.air = AirEntrainment(coefficient_s_per_m=10.0)``: air in the film at speed;
- ``RigSpec.joint = DahlJoint(stiffness_n_per_m=..., slip_force_n=...)``: a micro-slipping
  joint beside the rods' spring;
- ``Sensors.transforms[column]``: chains of ``transform(t, clean) -> samples`` (``gain``,
  ``delay``, ``offset`` or your own), noise per column in ``Sensors.noise``;
- ``Generator.oil_temp_c``: the recorded oil temperature, constant or a function of time.

Anything nonlinear, stateful (air, joint) or time-varying takes the ``solve_ivp`` path
(0.5-15 s per dwell; a seal at small amplitude needs several force corrections).
``Generator.run(program, continuous=True)`` integrates the whole programme in one go, so the
transients after each change of dwell stay in the record (the default puts separate
steady-state dwells end to end).

``tests.independent_rig.structure`` is a second structure, not the rig: a multi-mode chain
driven at one point with a softening (Iwan) joint, for runs at several force levels.
"""

from tests.independent_rig.generate import (
    MOTIONS,
    Dwell,
    Generator,
    Record,
    Segment,
    Sweep,
    grid,
    motion_shape,
)
from tests.independent_rig.rig import (
    AirEntrainment,
    DahlJoint,
    FilmGeometry,
    FrameMode,
    RigSpec,
    eq1_viscosity_pa_s,
    value_at,
)
from tests.independent_rig.sensors import COLUMNS, Sensors, delay, gain, offset

__all__ = [
    "COLUMNS", "MOTIONS", "AirEntrainment", "DahlJoint", "Dwell", "FilmGeometry", "FrameMode",
    "Generator", "Record", "RigSpec", "Segment", "Sensors", "Sweep", "delay", "eq1_viscosity_pa_s",
    "gain", "grid", "motion_shape", "offset", "value_at",
]
