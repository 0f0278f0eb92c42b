"""Dwells and sweeps on the independent rig, recorded as the canonical CSV.

Two integrations, chosen per dwell:

- linear and time-invariant rig (no seal, air, joint, extra force or time-varying parameter):
  the exact steady state in closed form (2x2 receptance, the film's cross terms included), the
  force solved from the target displacement on the axes where it is not zero, the other axis
  unforced (a unidirectional load: a coupled film moves that axis too);
- otherwise scipy's ``solve_ivp`` (DOP853, tight tolerances) from the linear steady state (with
  eq. 9's equivalent seal damping, the air fraction at its steady mean, the joint on its
  closed-form loop), settled for ``settle_cycles``, the force corrected by the linear receptance
  until the fundamental of the displacement is on target (within ``amplitude_tolerance``), then
  recorded from the dense output.

Phase convention: ``z(t) = Re(Z e^{i w (t - t0)})`` with t0 the start of the dwell's record.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from tests.independent_rig.rig import N_STATE, Param, RigSpec, value_at
from tests.independent_rig.sensors import COLUMNS, SIGNALS, CleanSignal, Sensors

MOTIONS = ("x", "y", "circular_forward", "circular_backward", "elliptical")
#: absolute tolerances of the ODE state: z, v, frame f, vf, air fraction, joint force
_ATOL = np.array([1e-13, 1e-13, 1e-10, 1e-10, 1e-13, 1e-13, 1e-10, 1e-10, 1e-9, 1e-8, 1e-8])


def motion_shape(motion: str, amplitude: float, ellipse_ratio: float = 0.5) -> np.ndarray:
    """Complex (X, Y) of a motion: forward circular is x = A cos wt, y = A sin wt (Y = -i X)."""
    a = float(amplitude)
    shapes = {"x": (a, 0.0), "y": (0.0, a), "circular_forward": (a, -1j * a),
              "circular_backward": (a, 1j * a), "elliptical": (a, -1j * ellipse_ratio * a)}
    if motion not in shapes:
        raise ValueError(f"unknown motion {motion!r} (one of {MOTIONS})")
    return np.array(shapes[motion], dtype=np.complex128)


@dataclass(frozen=True)
class Dwell:
    """One dwell: hold the displacement amplitude ``amplitude_m`` at ``freq_hz`` in ``motion``
    (or, with ``force_n`` set, apply that force amplitude open loop instead)."""

    freq_hz: float
    amplitude_m: float = 0.0
    motion: str = "x"
    record_s: float = 0.5
    ellipse_ratio: float = 0.5
    force_n: float | None = None


@dataclass(frozen=True)
class Sweep:
    """A continuous linear sine sweep of constant force amplitude (open loop, ODE path)."""

    f_start_hz: float
    f_stop_hz: float
    duration_s: float
    force_n: float
    motion: str = "x"


@dataclass
class Segment:
    """What one dwell or sweep was made with, and the truth behind its samples."""

    kind: str  # "dwell" or "sweep"
    freq_hz: float
    motion: str
    target_m: np.ndarray  # complex (2,) displacement target (zeros for a sweep)
    force_n: np.ndarray  # complex (2,) force amplitude (sweep: real (2,) amplitudes)
    first_sample: int
    last_sample: int  # exclusive
    t0_s: float
    z: CleanSignal  # t -> (2, n) relative displacement [m]
    v: CleanSignal  # t -> (2, n) relative velocity [m/s]
    accel: CleanSignal  # t -> (2, n) absolute housing acceleration [m/s^2]
    force: CleanSignal  # t -> (2, n) shaker force [N]
    iterations: int = 0
    state: CleanSignal | None = None  # t -> (N_STATE, n) the ODE state (ODE path only)


@dataclass
class Record:
    """A generated measurement: the canonical columns and the truth of every segment."""

    columns: dict[str, np.ndarray]
    segments: list[Segment]
    fs_hz: float
    rig: RigSpec

    def to_csv(self, path: str | Path, columns: Sequence[str] = COLUMNS,
               extra: dict[str, np.ndarray] | None = None, fmt: str = "%.9g") -> Path:
        """Write ``columns`` (canonical names) and ``extra`` columns as a CSV with a header."""
        path = Path(path)
        names = list(columns) + list(extra or {})
        data = [self.columns[c] for c in columns] + list((extra or {}).values())
        table = np.column_stack(data)
        with open(path, "w", newline="") as fh:
            fh.write(",".join(names) + "\n")
            np.savetxt(fh, table, delimiter=",", fmt=fmt)
        return path

    def step_column(self) -> np.ndarray:
        """Segment index per sample (for files that carry a step column)."""
        out = np.zeros(len(self.columns["time_s"]))
        for k, seg in enumerate(self.segments):
            out[seg.first_sample:seg.last_sample] = k
        return out


@dataclass
class Generator:
    """Records dwells and sweeps on ``rig`` through ``sensors``.

    Usage::

        rig = RigSpec(seal_friction_n=0.0)                       # lubricated, no seal
        rig.extra_forces.append(lambda t, z, v: -3e12 * z**3)    # a hidden cubic spring
        sensors = Sensors(seed=3)
        sensors.transforms["x_m"] = [gain(1.05)]                 # a probe reading 5 % high
        rec = Generator(rig, sensors).run(grid([20, 40, 60], [13e-6, 38e-6], "x"))
        rec.to_csv(tmp_path / "lub.csv")

    ``oil_temp_c`` may vary with time (``lambda t: 24 + 0.1 * t``); it is only recorded: make
    a parameter follow it (``film_damping_ns_per_m=lambda t: ...``) for a viscosity drift.
    """

    rig: RigSpec = field(default_factory=RigSpec)
    sensors: Sensors = field(default_factory=Sensors)
    fs_hz: float = 5000.0
    oil_temp_c: Param = 24.0
    settle_cycles: int = 20
    amplitude_tolerance: float = 1e-3
    max_iterations: int = 12

    def run(self, program: Sequence[Dwell | Sweep], continuous: bool = False) -> Record:
        """Record every dwell and sweep of ``program`` back to back (one time base).

        ``continuous=False``: each dwell is its own steady state (records of separate dwells
        put end to end, as the old VI stored them). ``continuous=True``: the forces found for
        the dwells drive one ``solve_ivp`` integration of the whole programme, so every change
        of dwell leaves its transient in the record (as on the rig; the dry rig without the
        seal rings for about 0.5 s). ``Record.segments`` then describe that integration.
        """
        rng = np.random.default_rng(self.sensors.seed)
        segments: list[Segment] = []
        n0 = 0
        for item in program:
            t0 = n0 / self.fs_hz
            if isinstance(item, Sweep):
                n = int(round(item.duration_s * self.fs_hz))
                seg = self._sweep(item, t0, n0, n)
            else:
                n = int(round(item.record_s * self.fs_hz))
                seg = self._dwell(item, t0, n0, n)
            segments.append(seg)
            n0 += n
        if continuous and segments:
            self._integrate_through(segments, n0)
        t = np.arange(n0) / self.fs_hz
        columns: dict[str, np.ndarray] = {"time_s": t, "freq_hz": np.empty(n0)}
        for name in SIGNALS:
            columns[name] = np.empty(n0)
        for seg in segments:
            sl = slice(seg.first_sample, seg.last_sample)
            ts = t[sl]
            if seg.kind == "sweep":
                columns["freq_hz"][sl] = _sweep_freq(seg, ts)
            else:
                columns["freq_hz"][sl] = seg.freq_hz
            clean = _channels(seg, self.oil_temp_c)
            for name in SIGNALS:
                columns[name][sl] = self.sensors.record(name, ts, clean[name], rng)
        return Record(columns=columns, segments=segments, fs_hz=self.fs_hz, rig=self.rig)

    def _integrate_through(self, segments: list[Segment], n_total: int) -> None:
        """Replace the segments' motion by one integration driven by their forces in turn."""
        starts = np.array([seg.t0_s for seg in segments])
        forces = [seg.force for seg in segments]

        def shaker(t: float) -> np.ndarray:
            k = max(int(np.searchsorted(starts, t, side="right")) - 1, 0)
            return np.asarray(forces[k](np.array([t])))[:, 0]

        first = segments[0]
        # start on the first dwell's steady state (its own record, sampled just before t0)
        t0 = first.t0_s
        if first.state is not None:
            y0 = np.asarray(first.state(np.array([t0])))[:, 0]
        else:
            y0 = np.zeros(N_STATE)
            y0[0:2] = np.asarray(first.z(np.array([t0])))[:, 0]
            y0[2:4] = np.asarray(first.v(np.array([t0])))[:, 0]
        t_end = n_total / self.fs_hz + 2.0 / max(seg.freq_hz for seg in segments)
        f_min = min(seg.freq_hz for seg in segments)
        sol = solve_ivp(lambda t, y: self.rig.derivative(t, y, shaker(t)), (t0, t_end), y0,
                        method="DOP853", rtol=1e-8, atol=_ATOL, dense_output=True,
                        max_step=0.05 / max(f_min, 1.0))
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed: {sol.message}")
        for k, seg in enumerate(segments):
            n = seg.last_sample - seg.first_sample
            new = self._segment_from(sol, seg.freq_hz, seg.motion, seg.target_m, seg.force_n,
                                     seg.first_sample, n, seg.t0_s, shaker, seg.iterations,
                                     seg.kind)
            if seg.kind == "sweep":
                new.sweep_rate_hz_per_s = seg.sweep_rate_hz_per_s  # type: ignore[attr-defined]
            segments[k] = new

    # --- dwells -------------------------------------------------------------------------------
    def _dwell(self, dwell: Dwell, t0: float, first: int, n: int) -> Segment:
        omega = 2 * math.pi * dwell.freq_hz
        target = motion_shape(dwell.motion, dwell.amplitude_m, dwell.ellipse_ratio)
        if dwell.force_n is not None:
            force = motion_shape(dwell.motion, dwell.force_n, dwell.ellipse_ratio)
            target = np.zeros(2, dtype=complex)
        else:
            force = self.rig.force_for(target, omega, t0,
                                       self.rig.steady_air_fraction(target, omega))
        if self.rig.is_linear_time_invariant:
            return self._closed_form(dwell, omega, force, target, t0, first, n)
        return self._integrated(dwell, omega, force, target, t0, first, n)

    def _closed_form(self, dwell: Dwell, omega: float, force: np.ndarray, target: np.ndarray,
                     t0: float, first: int, n: int) -> Segment:
        z_amp = self.rig.receptance_matrix(omega, t0) @ force
        h_abs = z_amp + self.rig.frame_per_relative(omega, t0) @ z_amp

        def harmonic(amp: np.ndarray, factor: complex) -> CleanSignal:
            return lambda t: np.real(np.outer(amp * factor, np.exp(1j * omega * (
                np.asarray(t) - t0))))

        return Segment("dwell", dwell.freq_hz, dwell.motion, target, force, first, first + n, t0,
                       z=harmonic(z_amp, 1.0), v=harmonic(z_amp, 1j * omega),
                       accel=harmonic(h_abs, -(omega**2)), force=harmonic(force, 1.0))

    def _integrated(self, dwell: Dwell, omega: float, force: np.ndarray, target: np.ndarray,
                    t0: float, first: int, n: int) -> Segment:
        rig = self.rig
        period = 2 * math.pi / omega
        t_start = t0 - self.settle_cycles * period
        t_end = t0 + n / self.fs_hz + 2 * period  # margin for sensor delays
        # Linearised receptance with the seal's equivalent damping (eq. 9, per axis)
        f_mu = value_at(rig.seal_friction_n, t0)
        amp = np.maximum(np.abs(target), 1e-9)
        c_seal = 4 * f_mu / (math.pi * omega * amp) if target.any() else np.zeros(2)
        air = rig.steady_air_fraction(target, omega)
        h_lin = np.array([rig.receptance(omega, t0, float(c), air)[k]
                          for k, c in enumerate(c_seal)])
        h_free = rig.receptance(omega, t0, air_fraction=air)
        if target.any():  # harmonic balance: the nonlinear forces' fundamental on the target
            held = np.abs(target) > 0
            force = np.where(held, rig.force_for(target, omega, t0, air)
                             - self._nonlinear_fundamental(target, omega, t0), 0.0)
        # Iterate on a short record (a few cycles after settling), then integrate the whole
        # record once with the converged force.
        n_cyc = max(1, min(4, int((n / self.fs_hz) // period)))
        t_meas = t0 + np.linspace(0.0, n_cyc * period, 64 * n_cyc, endpoint=False)
        gain_est = h_free.copy()  # per axis dZ/dF: the seal's force has a constant magnitude,
        # so the linear part's receptance is the right first guess (eq. 9's C_seal is not)
        iterations = 0
        prev: tuple[np.ndarray, np.ndarray] | None = None
        settled = None
        while target.any():
            iterations += 1
            sol = self._solve(self._harmonic_force(force, omega, t0), omega, h_lin, force, t0,
                              t_start, t0 + (n_cyc + 1) * period)
            settled = sol
            z = sol.sol(t_meas)[0:2]  # type: ignore[attr-defined]
            measured = 2 * np.mean(z * np.exp(-1j * omega * (t_meas - t0)), axis=1)
            err = np.where(np.abs(target) > 0, target - measured, 0.0)  # free axes move freely
            if np.max(np.abs(err)) <= self.amplitude_tolerance * np.max(np.abs(target)):
                break
            if iterations >= self.max_iterations:
                raise RuntimeError(f"dwell {dwell}: amplitude not reached ({measured} vs "
                                   f"{target}) after {iterations} iterations")
            if prev is not None:  # secant update per axis
                d_f, d_z = force - prev[0], measured - prev[1]
                ok = np.abs(d_f) > 0
                gain_est[ok] = d_z[ok] / d_f[ok]
            prev = (force.copy(), measured)
            force = force + np.where(np.abs(target) > 0, err / gain_est, 0.0)
        f_amp = force
        shaker = self._harmonic_force(f_amp, omega, t0)
        # the converged trial is settled under this very force: go on from it a period before
        # the record (margin for sensor delays) instead of settling again
        y_start = None if settled is None else settled.sol(t0 - period)  # type: ignore[attr-defined]
        sol = self._solve(shaker, omega, h_lin, f_amp, t0,
                          t_start if y_start is None else t0 - period, t_end, y_start)
        return self._segment_from(sol, dwell.freq_hz, dwell.motion, target, f_amp, first, n,
                                  t0, shaker, iterations)

    def _nonlinear_fundamental(self, target: np.ndarray, omega: float, t0: float) -> np.ndarray:
        """Fundamental (complex, per axis) of the seal and extra forces on the housing while it
        moves exactly as ``target`` (the describing function of the nonlinear terms)."""
        phases = np.linspace(0.0, 2 * math.pi, 256, endpoint=False)
        acc = np.zeros(2, dtype=complex)
        joint = self.rig.joint
        for ph in phases:
            rot = np.exp(1j * ph)
            z, v = np.real(target * rot), np.real(1j * omega * target * rot)
            f = self.rig.nonlinear_force(t0 + ph / omega, z, v)
            if joint is not None:  # the joint's steady loop, against the motion
                f = f - joint.loop_force(z, v, np.abs(target))
            acc += f * np.conj(rot)
        return 2 * acc / phases.size

    @staticmethod
    def _harmonic_force(f_amp: np.ndarray, omega: float,
                        t0: float) -> Callable[[float], np.ndarray]:
        (ar, ai), (br, bi) = ((float(a.real), float(a.imag)) for a in f_amp)

        def force(t: float) -> np.ndarray:
            c, s = math.cos(omega * (t - t0)), math.sin(omega * (t - t0))
            return np.array([ar * c - ai * s, br * c - bi * s])
        return force

    def _solve(self, shaker: Callable[[float], np.ndarray], omega: float, h_lin: np.ndarray,
               f_amp: np.ndarray, t0: float, t_start: float, t_end: float,
               y0: np.ndarray | None = None) -> object:
        """Integrate from ``y0`` or else the linear steady state of force
        ``Re(f_amp e^{iw(t - t0)})``."""
        rig = self.rig
        if y0 is None:
            z_amp = h_lin * f_amp
            z_c = z_amp * np.exp(1j * omega * (t_start - t0))
            y0 = rig.initial_state(np.real(z_c), np.real(1j * omega * z_c), omega, z_amp)
            f_c = rig.frame_per_relative(omega, t0) @ z_c
            y0[4:6] = np.real(f_c)
            y0[6:8] = np.real(1j * omega * f_c)
        sol = solve_ivp(lambda t, y: rig.derivative(t, y, shaker(t)), (t_start, t_end), y0,
                        method="DOP853", rtol=1e-8, atol=_ATOL, dense_output=True,
                        max_step=0.05 / (omega / (2 * math.pi)))
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed: {sol.message}")
        return sol

    def _segment_from(self, sol: object, freq_hz: float, motion: str, target: np.ndarray,
                      f_amp: np.ndarray, first: int, n: int, t0: float,
                      shaker: Callable[[float], np.ndarray], iterations: int,
                      kind: str = "dwell") -> Segment:
        rig = self.rig
        dense = sol.sol  # type: ignore[attr-defined]

        def z(t: np.ndarray) -> np.ndarray:
            return np.asarray(dense(np.asarray(t, dtype=float))[0:2])

        def v(t: np.ndarray) -> np.ndarray:
            return np.asarray(dense(np.asarray(t, dtype=float))[2:4])

        def accel(t: np.ndarray) -> np.ndarray:
            t = np.atleast_1d(np.asarray(t, dtype=float))
            states = dense(t)
            out = np.empty((2, t.size))
            for k, tk in enumerate(t):
                d = rig.derivative(float(tk), states[:, k], shaker(float(tk)))
                out[:, k] = d[2:4] + d[6:8]  # absolute: relative + frame
            return out

        def force(t: np.ndarray) -> np.ndarray:
            t = np.atleast_1d(np.asarray(t, dtype=float))
            return np.stack([shaker(float(tk)) for tk in t], axis=1)

        def state(t: np.ndarray) -> np.ndarray:
            return np.asarray(dense(np.asarray(t, dtype=float)))

        return Segment(kind, freq_hz, motion, target, f_amp, first, first + n, t0, z=z, v=v,
                       accel=accel, force=force, iterations=iterations, state=state)

    # --- sweeps -------------------------------------------------------------------------------
    def _sweep(self, sweep: Sweep, t0: float, first: int, n: int) -> Segment:
        rate = (sweep.f_stop_hz - sweep.f_start_hz) / sweep.duration_s
        direction = np.abs(motion_shape(sweep.motion, 1.0))
        quarter = np.array([0.0, math.pi / 2 if sweep.motion == "circular_forward" else
                            -math.pi / 2 if sweep.motion == "circular_backward" else 0.0])
        amp = sweep.force_n * direction

        def shaker(t: float) -> np.ndarray:
            tau = max(t - t0, 0.0)
            phase = 2 * math.pi * (sweep.f_start_hz * tau + 0.5 * rate * tau**2)
            return np.asarray(amp * np.cos(phase - quarter))

        omega = 2 * math.pi * sweep.f_start_hz
        h = self.rig.receptance(omega, t0)
        period = 1.0 / sweep.f_start_hz
        t_start = t0 - self.settle_cycles * period
        t_end = t0 + n / self.fs_hz + 2 * period

        def shaker_full(t: float) -> np.ndarray:  # steady at f_start before t0
            if t >= t0:
                return shaker(t)
            return np.asarray(amp * np.cos(omega * (t - t0) - quarter))

        sol = self._solve(shaker_full, omega, h, amp * np.exp(-1j * quarter), t0, t_start,
                          t_end)
        seg = self._segment_from(sol, sweep.f_start_hz, sweep.motion, np.zeros(2, complex),
                                 amp.astype(complex), first, n, t0, shaker_full, 1, "sweep")
        seg.sweep_rate_hz_per_s = rate  # type: ignore[attr-defined]
        return seg


def _sweep_freq(seg: Segment, t: np.ndarray) -> np.ndarray:
    rate = float(getattr(seg, "sweep_rate_hz_per_s", 0.0))
    return seg.freq_hz + rate * (t - seg.t0_s)


def _channels(seg: Segment, oil_temp_c: Param) -> dict[str, CleanSignal]:
    def row(fn: CleanSignal, k: int) -> CleanSignal:
        return lambda t: np.asarray(fn(t))[k]

    def temp(t: np.ndarray) -> np.ndarray:
        return np.array([value_at(oil_temp_c, float(tk)) for tk in np.atleast_1d(t)])

    return {"fx_N": row(seg.force, 0), "fy_N": row(seg.force, 1), "x_m": row(seg.z, 0),
            "y_m": row(seg.z, 1), "ax_mps2": row(seg.accel, 0), "ay_mps2": row(seg.accel, 1),
            "oil_temp_C": temp}


def grid(freqs_hz: Sequence[float], amplitudes_m: Sequence[float], motion: str = "x",
         record_s: float = 0.5, by: str = "amplitude") -> list[Dwell]:
    """The report's test programme: every frequency at every amplitude (``by="amplitude"``:
    amplitude in the outer loop, as the rig's five tests of Table 5)."""
    if by == "amplitude":
        return [Dwell(f, a, motion, record_s) for a in amplitudes_m for f in freqs_hz]
    return [Dwell(f, a, motion, record_s) for f in freqs_hz for a in amplitudes_m]
