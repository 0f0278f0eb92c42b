"""The rig in software: shakers, structure, seal, film, oil system and sensors, block by block.

`RigModel.process` takes the AO block (volts, as written to the board) and returns the AI block
(volts, as the board would read it). Everything is deterministic for a given seed.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from daq.channels import ChannelKind, ChannelMap
from rig_model import physics
from rig_model.params import VISCOSITY_SLOPE_PER_C, RigParams


def kernel_params(params: RigParams, sample_rate_hz: float) -> np.ndarray:
    """The flat parameter vector of `physics.integrate` for ``params``."""
    st, film, eff = params.structure, params.film, params.effects
    p = np.zeros(physics.N_PARAMS)
    p[physics.P_M] = st.mass_kg
    p[physics.P_MF] = film.fluid_mass_kg
    p[physics.P_D] = film.added_mass()
    p[physics.P_KX] = st.stiffness_x_n_per_m
    p[physics.P_KY] = st.stiffness_y_n_per_m
    p[physics.P_KXY] = st.stiffness_xy_n_per_m
    p[physics.P_CRV] = st.residual_damping_ns_per_m
    p[physics.P_DM_Y] = st.mass_y() - st.mass_kg
    p[physics.P_DC_Y] = st.residual_damping_y() - st.residual_damping_ns_per_m
    mu0, _ = film.reference_viscosity()
    p[physics.P_C0] = film.eq16_damping_centred(mu0)
    seal = params.seal.enabled and params.journal_in
    p[physics.P_FMU] = params.seal.friction_force_n if seal else 0.0
    p[physics.P_SEAL_KT] = params.seal.contact_stiffness_n_per_m or 0.0
    p[physics.P_SEAL_KTY] = params.seal.contact_stiffness_y_n_per_m or 0.0
    p[physics.P_FMU_WET] = params.seal.wet_friction_increase_n if seal else 0.0
    p[physics.P_CLEAR] = film.clearance_m
    p[physics.P_ECC] = 1.0 if film.eccentricity_law else 0.0
    if eff.cross_coupling.enabled:
        cc = eff.cross_coupling
        p[physics.P_CXY], p[physics.P_CYX] = cc.c_xy_ns_per_m, cc.c_yx_ns_per_m
        p[physics.P_DXY], p[physics.P_DYX] = cc.d_xy_kg, cc.d_yx_kg
    if eff.cubic_stiffness.enabled:
        p[physics.P_K3] = eff.cubic_stiffness.k3_n_per_m3
    if eff.quadratic_stiffness.enabled:
        p[physics.P_K2] = eff.quadratic_stiffness.k2_n_per_m2
    if eff.air_entrainment.enabled:
        ae = eff.air_entrainment
        p[physics.P_AIR_K] = ae.coefficient_s_per_m
        p[physics.P_AIR_MAX] = ae.max_fraction
    p[physics.P_AIR_TAU] = eff.air_entrainment.time_constant_s
    sm = eff.second_mode
    p[physics.P_FRAME_M] = sm.modal_mass_kg
    if sm.enabled:
        wn = 2 * math.pi * sm.frequency_hz
        p[physics.P_FRAME_ON] = 1.0
        p[physics.P_FRAME_K] = sm.modal_mass_kg * wn**2
        p[physics.P_FRAME_C] = 2 * sm.damping_ratio * sm.modal_mass_kg * wn
    p[physics.P_CONTACT_ON] = 1.0 if params.contact.enabled and params.journal_in else 0.0
    p[physics.P_RESTITUTION] = params.contact.restitution
    p[physics.P_CONTACT_MU] = params.contact.friction_coefficient
    jm = eff.joint_microslip
    if jm.enabled and max(jm.stiffness_n_per_m, jm.stiffness_y()) > 0:
        p[physics.P_JOINT_ON] = 1.0 if jm.mode == "housing" else 2.0
        p[physics.P_JOINT_K] = jm.stiffness_n_per_m
        p[physics.P_JOINT_KY] = jm.stiffness_y()
    p[physics.P_JOINT_FS] = jm.slip_force_n
    p[physics.P_JOINT_FSY] = jm.slip_force_y()
    p[physics.P_JOINT_SHAPE] = jm.shape
    rs = eff.relaxing_stiffness
    p[physics.P_RELAX_TAU] = rs.relaxation_time_s
    if rs.enabled:
        p[physics.P_RELAX_KX] = rs.stiffness_x_n_per_m
        p[physics.P_RELAX_KY] = rs.stiffness_y_n_per_m
    p[physics.P_DT] = 1.0 / sample_rate_hz
    p[physics.P_NSUB] = params.steps_per_sample(sample_rate_hz)
    return p


def simulate_response(
    force_n: np.ndarray,
    params: RigParams,
    sample_rate_hz: float,
    fill: float | np.ndarray = 1.0,
    viscosity_scale: float | np.ndarray = 1.0,
    state: np.ndarray | None = None,
    kernel: np.ndarray | None = None,
) -> tuple[physics.Truth, np.ndarray]:
    """Replay a measured force (N, shape (2, n)) through the structure, seal and film.

    Returns the true response and the final state vector (pass it back to continue). This is
    the path the diagnosis uses: the same equations as the live simulation, without shakers,
    sensors or the oil system. ``kernel``: ``kernel_params(params, sample_rate_hz)`` when the
    caller already has it (a diagnosis replays many windows under one rig).
    """
    force = np.ascontiguousarray(force_n, dtype=np.float64)
    if force.ndim != 2 or force.shape[0] != 2:
        raise ValueError(f"force_n must have shape (2, n), got {force.shape}")
    n = force.shape[1]
    fill_arr = np.broadcast_to(np.asarray(fill, dtype=np.float64), (n,)).copy()
    visc_arr = np.broadcast_to(np.asarray(viscosity_scale, dtype=np.float64), (n,)).copy()
    s = np.zeros(physics.N_STATE) if state is None else state.copy()
    out = np.empty((physics.N_OUT, n))
    kp = kernel_params(params, sample_rate_hz) if kernel is None else kernel
    physics.integrate(force, fill_arr, visc_arr, kp, s, out)
    return physics.Truth.from_kernel(out, force, np.zeros(n)), s


def warm_up(params: RigParams, sample_rate_hz: float) -> None:
    """Compile (or load) the physics the rig ``params`` runs, with the journal in and out (a
    commissioning step takes it out), so that no paced block waits for the JIT."""
    physics.warm_up(*(kernel_params(params.model_copy(update={"journal_in": j}), sample_rate_hz)
                      for j in (True, False)))


NOISE_TABLE_SIZE = 1 << 20  # standard normal draws reused with random offsets (4 MiB)
_STARTS_AHEAD = 64  # blocks of noise-table starts drawn at once (`RigModel._noise_starts`)
REST_HORIZON_S = 120.0  # `RigModel.rest` follows the oil this long (24 drain time constants)


@functools.lru_cache(maxsize=4)
def _noise_table(seed: int) -> tuple[np.ndarray, Mapping[str, Any]]:
    """The seed's table of standard normal draws (read-only, shared by the rigs of that seed:
    drawing it takes ~50 ms, and a test or a diagnosis builds many rigs) and the generator's
    state after drawing it."""
    rng = np.random.default_rng(seed)
    table = rng.standard_normal(NOISE_TABLE_SIZE, dtype=np.float32)
    table.flags.writeable = False
    return table, rng.bit_generator.state


class RigModel:
    """The whole simulated rig behind a channel map: AO volts in, AI volts out."""

    def __init__(self, params: RigParams, channel_map: ChannelMap, seed: int = 0) -> None:
        self.params = params
        self.channel_map = channel_map
        self.fs = channel_map.sample_rate_hz
        self.dt = 1.0 / self.fs
        self._noise, after = _noise_table(seed)
        self._rng = np.random.default_rng(seed)
        self._rng.bit_generator.state = after  # as if it had drawn the table itself
        self._starts = np.empty((0, 0), dtype=np.int64)  # `_noise_starts`' draws to come
        self._next_start = 0
        self._kp = kernel_params(params, self.fs)
        self._integrate = physics.kernel_for(self._kp)
        self._state = np.zeros(physics.N_STATE)
        self.sample_index = 0
        # shakers: first-order drive dynamics, one filter state per axis
        a = math.exp(-2 * math.pi * params.shaker.bandwidth_hz * self.dt)
        self._shaker_pole = a
        self._shaker_state = np.zeros(2)
        # the AO row that drives each axis's shaker (-1: none; the last of two on one axis)
        self._drive_row = np.full(2, -1, dtype=np.int64)
        for row, ao in enumerate(channel_map.ao):
            self._drive_row[0 if ao.axis == "x" else 1] = row
        # oil system
        self.pump_on = False
        self._relay_names = {d.name for d in channel_map.do}
        oil = params.oil
        self._p_in = 0.0
        self._p_rec = 0.0
        self._fill = 1.0 if oil.initially_filled else 0.0
        self._temp_c = oil.initial_temperature_c
        self._mu_ref, self._t_ref = params.film.reference_viscosity()
        # impact hammer: pending half-sine pulses (start sample, axis, peak N, duration samples)
        self._impacts: list[tuple[int, int, float, int]] = []
        # a hand pushing with a force gauge: held force per axis, ramped: rows of (from [N],
        # to [N], start sample, width in samples)
        self._push = np.array([(0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0)])
        self._t: np.ndarray = np.empty(0)  # `_times`
        self._decay: np.ndarray = np.empty(0)
        self._decay_tau = 0.0
        film = params.film
        self._flow_numerator = math.pi * film.diameter_m * film.clearance_m**3  # eq. 5
        self._build_sensor_tables()
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # `last_truth`'s

    # --- operator-side actions ------------------------------------------------------------
    def set_relay(self, name: str, value: bool) -> None:
        if name not in self._relay_names:
            raise KeyError(f"no relay named {name!r}")
        self.pump_on = bool(value)

    def set_journal(self, installed: bool) -> None:
        """Journal in (the seal rubs and the housing meets the journal at the clearance, as
        configured) or out (the report's structure tests: no seal, no wall, and no film: the
        oil that was in the damper leaves with the journal), from the next block on."""
        self.params.journal_in = bool(installed)
        if not installed:
            self._fill = 0.0
        self._kp = kernel_params(self.params, self.fs)
        self._integrate = physics.kernel_for(self._kp)

    def schedule_impact(self, axis: str, peak_force_n: float, duration_s: float = 0.002,
                        delay_s: float = 0.0) -> None:
        """Strike the housing with the hammer: a half-sine pulse, read on the hammer channel."""
        if axis not in ("x", "y"):
            raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")
        start = self.sample_index + int(round(delay_s * self.fs))
        width = max(2, int(round(duration_s * self.fs)))
        self._impacts.append((start, 0 if axis == "x" else 1, float(peak_force_n), width))

    def push(self, axis: str, force_n: float, ramp_s: float = 0.5) -> None:
        """A hand pushes the housing along ``axis`` with ``force_n`` (0: lets go), reached over
        ``ramp_s`` and held: an external force that no channel reads (the person reads the
        force gauge)."""
        if axis not in ("x", "y"):
            raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")
        a = 0 if axis == "x" else 1
        now = self._push_at(a, np.array([self.sample_index]))[0]
        self._push[a] = (float(now), float(force_n), self.sample_index,
                         max(1, int(round(ramp_s * self.fs))))

    def rest(self, seconds: float) -> None:
        """The rig left at rest for ``seconds`` while no task runs (drives at 0 V): the oil
        keeps pressurising or venting, and the film filling or draining, as the pump relay says.
        Only these slow states advance, and only over the first `REST_HORIZON_S` (by then the
        film and the pressures have settled; the oil's warming beyond it is not followed). The
        housing is not integrated: with no drive it settles within a fraction of a second."""
        left = int(round(min(max(seconds, 0.0), REST_HORIZON_S) * self.fs))
        while left > 0:  # one second at a time: bounded memory
            n = min(left, int(self.fs))
            self._oil_block(n)
            left -= n

    def continue_from(self, other: RigModel) -> None:
        """Take over ``other``'s physical state (the housing's motion, the shakers' forces, the
        oil and the film, the pump relay): the same rig, observed from now on through this
        model's channels and sample rate."""
        self._state = other._state.copy()
        self._shaker_state = other._shaker_state.copy()
        self._p_in, self._p_rec, self._fill = other._p_in, other._p_rec, other._fill
        self._temp_c = other._temp_c
        self.pump_on = other.pump_on

    @property
    def temperature_c(self) -> float:
        return self._temp_c

    @property
    def film_fill(self) -> float:
        return self._fill

    @property
    def inlet_pressure_pa(self) -> float:
        return self._p_in

    def film_viscosity_pa_s(self) -> float:
        return self._mu_ref * math.exp(-VISCOSITY_SLOPE_PER_C * (self._temp_c - self._t_ref))

    # --- one block ------------------------------------------------------------------------
    def process(self, ao_volts: np.ndarray) -> np.ndarray:
        """Advance the rig by one block. ``ao_volts`` (n_ao, n) -> AI volts (n_ai, n).

        Every true signal of the block is a row of one array (`_SIGNAL_ROWS`): the kernel's
        outputs, the shakers' force, the oil's and the hammer's; each sensor reads its row
        (`physics.sensor_volts`), so a block costs a few calls whatever the channel count."""
        ao = np.asarray(ao_volts, dtype=np.float64)
        n = ao.shape[1]
        sig = np.empty((self._n_signals, n))
        force = sig[_FX:_FY + 1]
        external = np.empty((2, n))
        sh = self.params.shaker
        physics.block_forces(ao, self._drive_row, sh.force_per_volt_n, self._shaker_pole,
                             sh.max_force_n, self._shaker_state, self._hammer_block(n),
                             self._push, self.sample_index, force, external, sig[_HAMMER])
        fill, visc, *_ = self._oil_block(n, sig)
        self._integrate(external, fill, visc, self._kp, self._state, sig[:physics.N_OUT])
        self._last = (sig[:physics.N_OUT], force, sig[_HAMMER])
        film = self.params.film
        physics.eq5_flow(sig[_P_IN], sig[_P_REC], visc, self._flow_numerator, self._mu_ref,
                         film.length_m, sig[_FLOW])
        for j, (i, d) in enumerate(self._delays.items()):
            sig[_N_BASE + j] = self._delay(i, sig[self._source_rows[i]], d)
        self.sample_index += n
        starts = self._noise_starts()
        volts = np.empty((len(self._source), n))
        physics.sensor_volts(sig, self._source, self._gain, self._offset, self._noise, starts,
                             self._sigma, self._lsb, self._lo, self._hi, volts)
        return volts

    @property
    def last_truth(self) -> physics.Truth | None:
        """The true signals of the last block `process` ran (None before the first)."""
        return None if self._last is None else physics.Truth.from_kernel(*self._last)

    # --- internals ------------------------------------------------------------------------
    def _noise_starts(self) -> np.ndarray:
        """Each channel's start in the noise table for the next block: the generator's next
        draws, taken `_STARTS_AHEAD` blocks at a time (the same numbers as one draw a block,
        at a fraction of the calls)."""
        if self._next_start >= self._starts.shape[0]:
            k = len(self._source)
            self._starts = self._rng.integers(0, self._noise.size,
                                              size=_STARTS_AHEAD * k).reshape(_STARTS_AHEAD, k)
            self._next_start = 0
        starts = self._starts[self._next_start]
        self._next_start += 1
        return starts

    def _hammer_block(self, n: int) -> np.ndarray:
        hammer = np.zeros((2, n))
        keep = []
        k0 = self.sample_index
        for start, axis, peak, width in self._impacts:
            idx = np.arange(max(start, k0), min(start + width, k0 + n))
            if idx.size:
                hammer[axis, idx - k0] = peak * np.sin(np.pi * (idx - start + 0.5) / width)
            if start + width > k0 + n:
                keep.append((start, axis, peak, width))
        self._impacts = keep
        return hammer

    def _push_at(self, axis: int, idx: np.ndarray) -> np.ndarray:
        """The hand's force along ``axis`` at samples ``idx`` (as `physics.block_forces`)."""
        start_n, end_n, start, width = self._push[axis]
        return start_n + (end_n - start_n) * np.clip((idx - start) / width, 0.0, 1.0)

    def _times(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(1..n) dt, the block's sample instants after its start [s], and the pressures'
        decay over them (kept for the last n)."""
        tau = self.params.oil.pressure_time_constant_s
        if self._t.size != n or self._decay_tau != tau:
            self._t = (np.arange(n) + 1) * self.dt
            self._decay, self._decay_tau = np.exp(-self._t / tau), tau
        return self._t, self._decay

    def _oil_block(self, n: int, rows: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """The oil system over ``n`` samples (`physics.oil_block`): the pressures, the film's
        fill, the temperature and the viscosity scale. The pressures and the temperature go to
        rows `_P_IN`, `_P_REC` and `_T_OIL` of ``rows`` (`process`'s signals; None: arrays of
        their own); returns (fill, visc, p_in, p_rec, temp)."""
        oil = self.params.oil
        if rows is None:
            p_in, p_rec, temp = np.empty((3, n))
        else:
            p_in, p_rec, temp = rows[_P_IN], rows[_P_REC], rows[_T_OIL]
        t, decay = self._times(n)
        on = self.pump_on
        targets = np.array([oil.supply_pressure_pa if on else 0.0,
                            oil.recirculation_pressure_pa if on else 0.0])
        rate = (oil.warming_c_per_hour / 3600.0) if on else 0.0
        drift = self.params.effects.viscosity_drift
        if drift.enabled:
            rate += drift.warming_c_per_s
        fill, visc = np.empty(n), np.empty(n)
        physics.oil_block(decay, t, np.array([self._p_in, self._p_rec]), targets,
                          0.5 * oil.supply_pressure_pa, self.dt / oil.fill_time_constant_s,
                          self.dt / oil.drain_time_constant_s, self._fill,
                          self.params.journal_in, self._temp_c, rate, self._t_ref,
                          -VISCOSITY_SLOPE_PER_C, p_in, p_rec, fill, temp, visc)
        np.exp(visc, out=visc)
        self._p_in, self._p_rec = float(p_in[-1]), float(p_rec[-1])
        self._fill, self._temp_c = float(fill[-1]), float(temp[-1])
        return fill, visc, p_in, p_rec, temp

    def _build_sensor_tables(self) -> None:
        """Which true signal (a row of `process`'s signals) each AI channel sees, with which
        gain, noise and delay."""
        cm, eff, noise = self.channel_map, self.params.effects, self.params.noise
        sources: list[int] = []
        gains, offsets, sigmas, lo, hi = [], [], [], [], []
        delays: list[float] = []
        for ch in cm.ai:
            sources.append(_SIGNAL_ROWS[_source_for(ch.name, ch.kind)])
            g = ch.gain_v_per_unit
            if eff.probe_gain_error.enabled and eff.probe_gain_error.channel == ch.name:
                g *= eff.probe_gain_error.gain_ratio
            sign = -1.0 if eff.reversed_polarity.enabled and \
                ch.name in eff.reversed_polarity.channels else 1.0
            gains.append(sign * g)
            offsets.append(sign * ch.offset_v)
            sigmas.append(getattr(noise, ch.kind.value) * ch.gain_v_per_unit)
            lo.append(ch.range_v[0])
            hi.append(ch.range_v[1])
            d = 0.0
            if eff.channel_delay.enabled and eff.channel_delay.channel == ch.name:
                d = eff.channel_delay.delay_s
            delays.append(d)
        self._gain = np.array(gains)
        self._offset = np.array(offsets)
        self._sigma = np.array(sigmas)
        self._lo = np.array(lo)
        self._hi = np.array(hi)
        bits = cm.device.ai_bits
        self._lsb = (2 * cm.device.ai_range_v) / 2**bits
        # fractional delays: keep enough history per delayed channel; a delayed channel reads
        # a row of its own after the shared ones
        self._delays = {i: d * self.fs for i, d in enumerate(delays) if d > 0}
        self._history = {i: np.zeros(int(math.ceil(d)) + 2) for i, d in self._delays.items()}
        self._source_rows = list(sources)  # the undelayed rows
        for j, i in enumerate(self._delays):
            sources[i] = _N_BASE + j
        self._source = np.array(sources, dtype=np.int64)
        self._n_signals = _N_BASE + len(self._delays)

    def _delay(self, i: int, sig: np.ndarray, d: float) -> np.ndarray:
        hist = self._history[i]
        ext = np.concatenate([hist, sig])
        idx = np.arange(sig.size) + hist.size - d
        out = np.interp(idx, np.arange(ext.size), ext)
        self._history[i] = ext[-hist.size:]
        return out


# The rows of `RigModel.process`'s true signals: the kernel's outputs (physics.O_*), then these.
_FX, _FY, _P_IN, _P_REC, _FLOW, _T_OIL, _HAMMER = range(physics.N_OUT, physics.N_OUT + 7)
_N_BASE = physics.N_OUT + 7
_SIGNAL_ROWS = {
    "fx": _FX, "fy": _FY, "x": physics.O_X, "y": physics.O_Y,
    "ax": physics.O_AX, "ay": physics.O_AY, "p_in": _P_IN, "p_rec": _P_REC,
    "q_in": _FLOW, "q_out": _FLOW,  # the sealed damper does not leak (section V)
    "t_oil": _T_OIL, "hammer": _HAMMER,
}


def _source_for(name: str, kind: ChannelKind) -> str:
    """Map an AI channel to the true signal it measures, by kind and axis letter of its name."""
    if kind is ChannelKind.LOAD_CELL:
        if name == "hammer":
            return "hammer"
        return "fy" if "y" in name else "fx"
    if kind is ChannelKind.EDDY_CURRENT_PROBE:
        return "y" if name.startswith("y") else "x"
    if kind is ChannelKind.ACCELEROMETER:
        return "ay" if "y" in name else "ax"
    if kind is ChannelKind.PRESSURE_4_20MA:
        return "p_rec" if "rec" in name else "p_in"
    if kind is ChannelKind.FLOW:
        return "q_out" if "out" in name else "q_in"
    return "t_oil"
