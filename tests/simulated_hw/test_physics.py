"""The simulated rig against the report (Tables 2-4, 6; eq. 9, 15, 16) and energy balance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daq import default_channel_map
from rig_model import RigParams, physics, simulate_response
from rig_model.params import Film, Oil, Seal
from rig_model.rig import kernel_params
from simulated_hw import SimulatedBackend

FS = 10_000.0
CM = default_channel_map()


def lockin(sig: np.ndarray, freq_hz: float, fs: float = FS, harmonic: int = 1,
           window_s: float = 0.4) -> complex:
    """Complex amplitude Z (sig = Re(Z e^{iwt})) over the whole cycles in the last ``window_s``
    of ``sig`` (the start-up transient before it is left out)."""
    per = fs / freq_hz
    n = int(round(np.floor(window_s * fs / per) * per))
    seg = sig[-n:]
    t = (np.arange(sig.size - n, sig.size)) / fs
    return 2.0 * np.mean(seg * np.exp(-1j * 2 * np.pi * harmonic * freq_hz * t))


def run_open_loop(params: RigParams, drive_v: dict[str, tuple[float, float]], freq_hz: float,
                  seconds: float, pump: bool = False, seed: int = 1,
                  ramp_s: float = 0.0) -> np.ndarray:
    """Drive the shakers with fixed sines (amplitude V, phase rad), raised linearly over the first
    ``ramp_s`` (a sine switched on at full force throws the dry housing about twice as far as its
    steady orbit), and return AI in engineering units for the whole run."""
    be = SimulatedBackend(params, seed=seed)
    be.configure(CM)
    if pump:
        be.set_do("pump", True)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    ao = np.zeros((2, n))
    for name, (amp, ph) in drive_v.items():
        ao[CM.ao_names.index(name)] = amp * np.cos(2 * np.pi * freq_hz * t + ph)
    if ramp_s > 0:
        ao *= np.minimum(t / ramp_s, 1.0)
    be.write_ao(ao)
    be.start()
    volts = be.read_ai(n)
    return CM.to_engineering(volts)


def test_dry_impact_natural_frequency_x():
    """Impact on the dry housing without the seal: f_n = 45 +/- 2 Hz (Table 2: 45 +/- 1 Hz)."""
    params = RigParams(seal=Seal(enabled=False))
    be = SimulatedBackend(params, seed=3)
    be.configure(CM)
    n = int(8 * FS)
    be.write_ao(np.zeros((2, n)))
    be.start()
    assert be.rig is not None
    be.rig.schedule_impact("x", peak_force_n=300.0, duration_s=0.002, delay_s=0.1)
    ai = CM.to_engineering(be.read_ai(n))
    x = 0.5 * (ai[CM.ai_index("x1")] + ai[CM.ai_index("x2")])
    f = ai[CM.ai_index("hammer")]
    freqs = np.fft.rfftfreq(n, 1 / FS)
    h = np.abs(np.fft.rfft(x) / np.fft.rfft(f))
    band = (freqs > 10) & (freqs < 150)
    fn = freqs[band][np.argmax(h[band])]
    expected = math.sqrt(788e3 / 9.7) / (2 * math.pi)
    assert abs(fn - 45.0) <= 2.0
    assert fn == pytest.approx(expected, abs=0.3)  # 45.4 Hz, to the FFT resolution (0.125 Hz)
    # the static flexibility 1/K at low frequency (Table 2: K_sx = 788 kN/m)
    low = (freqs > 3) & (freqs < 8)
    assert 1 / np.mean(h[low]) == pytest.approx(788e3, rel=0.05)


def test_lubricated_system_is_overdamped_no_peak_20_60_hz():
    """Section VI.1: with the film, |X/F| shows no resonance peak over 20-60 Hz."""
    params = RigParams(oil=Oil(initially_filled=True))
    mags = []
    freqs = np.arange(20.0, 61.0, 2.5)
    for fq in freqs:
        ai = run_open_loop(params, {"shaker_x": (3.0, 0.0)}, fq, seconds=0.6, pump=True)
        x = 0.5 * (ai[CM.ai_index("x1")] + ai[CM.ai_index("x2")])
        fx = ai[CM.ai_index("fx")]
        mags.append(abs(lockin(x, fq)) / abs(lockin(fx, fq)))
    mags = np.array(mags)
    assert np.all(np.diff(mags) < 0), f"|X/F| not monotone: {mags}"
    # the undamped lubricated natural frequency would be 33.4 Hz (rig-numbers note): a light
    # system would peak there; this one falls by more than 2x from 20 to 60 Hz with no bump.
    assert mags[0] / mags[-1] > 2.0


# drives that keep the orbit inside the 127 um clearance (about 96 and 80 um; the journal stops
# anything further)
@pytest.mark.parametrize("freq_hz,drive_v", [(60.0, 1.5), (100.0, 5.0)])
def test_seal_equivalent_damping_macro_slip_dry(freq_hz: float, drive_v: float):
    """eq. 9: in macro-slip the seal's equivalent damping is 4 F_mu / (pi w |X|), within 5 %,
    identified from the load cell and the probes as the report does (eq. 14, C_t - C_rv).

    Eq. 9 assumes a sinusoidal motion. Dry, below the 45 Hz resonance, the friction's 3X lands
    near the resonance and distorts the motion (at 20 Hz the path per cycle is 8 % shorter than
    4|X|, so eq. 9 overstates the seal damping by ~10 %); above it the motion is sinusoidal."""
    params = RigParams()  # dry, seal on
    ai = run_open_loop(params, {"shaker_x": (drive_v, 0.0)}, freq_hz, seconds=1.0, ramp_s=0.2)
    x = 0.5 * (ai[CM.ai_index("x1")] + ai[CM.ai_index("x2")])
    assert np.max(np.abs(x)) < 0.95 * 127e-6  # never at the journal
    fx = ai[CM.ai_index("fx")]
    w = 2 * np.pi * freq_hz
    X, F = lockin(x, freq_hz), lockin(fx, freq_hz)
    c_total = (F / (1j * w * X)).real  # eq. 14
    c_seal = c_total - params.structure.residual_damping_ns_per_m
    expected = 4 * 26.0 / (np.pi * w * abs(X))
    assert abs(X) > 10e-6  # really slipping, not stuck
    assert c_seal == pytest.approx(expected, rel=0.05)


@pytest.mark.parametrize("freq_hz,drive_v", [(40.0, 1.7), (50.0, 1.8), (60.0, 1.6), (60.0, 2.4)])
def test_seal_equivalent_damping_macro_slip_lubricated(freq_hz: float, drive_v: float):
    """eq. 9 on the lubricated rig (the report's use of it), from the seal's own force.

    Macro-slip means the seal slips through the whole cycle. At 20 Hz and 13-30 um the simulated
    seal sticks for 15-25 % of each cycle (Coulomb friction with rigid sticking), where eq. 9
    overstates the seal's damping by 5-15 %."""
    params = RigParams(oil=Oil(initially_filled=True))
    be = SimulatedBackend(params, seed=5)
    be.configure(CM)
    be.set_do("pump", True)
    n = int(1.0 * FS)
    t = np.arange(n) / FS
    be.write_ao(np.vstack([drive_v * np.cos(2 * np.pi * freq_hz * t), np.zeros(n)]))
    be.start()
    be.read_ai(n)
    assert be.rig is not None and be.rig.last_truth is not None
    tr = be.rig.last_truth
    w = 2 * np.pi * freq_hz
    X = lockin(tr.x_m, freq_hz)
    friction = lockin(tr.friction_x_n, freq_hz)  # force of the seal on the housing
    c_seal = (-friction / (1j * w * X)).real
    expected = 4 * 26.0 / (np.pi * w * abs(X))
    assert 13e-6 < abs(X) < 40e-6  # the report's 13-38 um range
    stuck = np.mean(np.abs(tr.vx_m_per_s[-4000:]) < 1e-6)
    assert stuck < 0.02  # macro-slip
    assert c_seal == pytest.approx(expected, rel=0.05)


def test_seal_makes_odd_third_harmonic_in_acceleration():
    """Section IV.3 and VI.1: dry friction shows as a 3X component in the acceleration."""
    # 40 N: about 63 um, inside the clearance (the journal would clip a larger orbit)
    with_seal = run_open_loop(RigParams(), {"shaker_x": (0.8, 0.0)}, 30.0, seconds=1.0)
    no_seal = run_open_loop(RigParams(seal=Seal(enabled=False)), {"shaker_x": (0.8, 0.0)},
                            30.0, seconds=1.0)
    ax = CM.ai_index("ax")
    a1 = abs(lockin(with_seal[ax], 30.0, harmonic=1))
    a2 = abs(lockin(with_seal[ax], 30.0, harmonic=2))
    a3 = abs(lockin(with_seal[ax], 30.0, harmonic=3))
    a3_free = abs(lockin(no_seal[ax], 30.0, harmonic=3))
    assert a3 / a1 > 0.02  # a clear 3X
    assert a3 > 10 * a2  # odd, not even
    assert a3 > 20 * a3_free  # and it comes from the seal


@pytest.mark.parametrize("lubricated", [False, True])
def test_shaker_work_equals_dissipated_energy_per_cycle(lubricated: bool):
    """Per cycle in steady state, the work of the shaker force equals the energy dissipated by
    the residual damping, the film and the seal (eq. 2-4), within 1 %."""
    params = RigParams(oil=Oil(initially_filled=lubricated))
    fq, fs = 40.0, FS
    n = int(1.5 * fs)
    t = np.arange(n) / fs
    # dry, 35 N near the resonance gives a 73 um orbit (60 N would reach the journal)
    amp = 60.0 if lubricated else 35.0
    force = np.vstack([amp * np.cos(2 * np.pi * fq * t), amp * np.sin(2 * np.pi * fq * t)])
    tr, _ = simulate_response(force, params, fs, fill=1.0 if lubricated else 0.0)
    assert np.hypot(tr.x_m, tr.y_m).max() < 0.9 * 127e-6  # no contact: this balance has no wall
    per = int(round(fs / fq))
    seg = slice(n - 20 * per, n)  # the last 20 whole cycles
    vx, vy = tr.vx_m_per_s[seg], tr.vy_m_per_s[seg]
    work = np.sum(tr.fx_n[seg] * vx + tr.fy_n[seg] * vy) / fs
    c_rv = params.structure.residual_damping_ns_per_m
    dissipated = np.sum(
        c_rv * (vx**2 + vy**2)
        - (tr.film_x_n[seg] * vx + tr.film_y_n[seg] * vy)
        - (tr.friction_x_n[seg] * vx + tr.friction_y_n[seg] * vy)
    ) / fs
    assert work > 0
    assert dissipated == pytest.approx(work, rel=0.01)
    # and the seal's part matches eq. 3 (F_mu times the path length) where it slips
    friction = -np.sum(tr.friction_x_n[seg] * vx + tr.friction_y_n[seg] * vy) / fs
    path = np.sum(np.hypot(vx, vy)) / fs
    assert friction == pytest.approx(26.0 * path, rel=0.01)


def test_film_coefficients_match_eq15_eq16_and_notes():
    film = RigParams().film
    assert film.eq15_added_mass_kg() == pytest.approx(7.58, abs=0.01)
    assert film.eq16_damping_centred(3.17e-3) == pytest.approx(5060, rel=0.001)
    assert film.viscosity_pa_s(24.0) == pytest.approx(3.17e-3)
    eq1 = RigParams(film=film.model_copy(update={"viscosity_source": "eq1"})).film
    assert eq1.viscosity_pa_s(24.0) == pytest.approx(2.78e-3, abs=0.005e-3)
    q = film.eq5_flow_m3_per_s(9.8e3, 3.17e-3)
    assert q == pytest.approx(8.3e-6, rel=0.01)


def test_same_seed_same_data_and_different_seed_different_noise():
    a = run_open_loop(RigParams(), {"shaker_x": (3.0, 0.0)}, 40.0, 0.2, seed=7)
    b = run_open_loop(RigParams(), {"shaker_x": (3.0, 0.0)}, 40.0, 0.2, seed=7)
    c = run_open_loop(RigParams(), {"shaker_x": (3.0, 0.0)}, 40.0, 0.2, seed=8)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_shaker_force_saturates_at_rating():
    ai = run_open_loop(RigParams(seal=Seal(enabled=False)), {"shaker_x": (10.0, 0.0)}, 200.0, 0.2)
    fx = ai[CM.ai_index("fx")]
    assert np.max(np.abs(fx)) == pytest.approx(448.0, abs=1.0)


def test_pump_relay_builds_pressure_and_flow_by_eq5():
    be = SimulatedBackend(RigParams(), seed=2)
    be.configure(CM)
    n = int(6 * FS)
    be.write_ao(np.zeros((2, n)))
    be.start()
    be.set_do("pump", True)
    ai = CM.to_engineering(be.read_ai(n))
    p_in = ai[CM.ai_index("p_in")][-1000:].mean()
    p_rec = ai[CM.ai_index("p_rec")][-1000:].mean()
    q = ai[CM.ai_index("q_in")][-1000:].mean()
    assert p_in == pytest.approx(15.5e3, rel=0.02)
    assert p_rec == pytest.approx(5.7e3, rel=0.03)
    q_eq5 = RigParams().film.eq5_flow_m3_per_s(p_in - p_rec, 3.17e-3) * 60_000
    assert q == pytest.approx(q_eq5, rel=0.03)
    assert be.rig is not None and be.rig.film_fill > 0.98


@pytest.mark.parametrize("freq_hz", [20.0, 120.0])
def test_velocity_and_acceleration_are_at_the_sample_instants(freq_hz: float):
    """Probes, velocity and accelerometer must agree in time: a = -w^2 x and v = i w x, with no
    half-sample skew between them (a skew would look like a channel delay to the diagnosis)."""
    params = RigParams(seal=Seal(enabled=False), oil=Oil(initially_filled=True))
    t = np.arange(int(1.0 * FS)) / FS
    force = np.vstack([80 * np.cos(2 * np.pi * freq_hz * t), np.zeros(t.size)])
    tr, _ = simulate_response(force, params, FS, fill=1.0)
    w = 2 * np.pi * freq_hz
    X = lockin(tr.x_m, freq_hz)
    V = lockin(tr.vx_m_per_s, freq_hz)
    A = lockin(tr.ax_m_per_s2, freq_hz)
    assert np.angle(V / (1j * w * X)) == pytest.approx(0.0, abs=2e-4)
    assert abs(V) == pytest.approx(w * abs(X), rel=1e-3)
    assert np.angle(A / (-(w**2) * X)) == pytest.approx(0.0, abs=2e-4)
    assert abs(A) == pytest.approx(w**2 * abs(X), rel=2e-3)


def test_second_mode_frame_resonances_match_the_two_mass_model():
    """The frame effect (section IV.3: ~39 Hz frame, ~50 Hz rods): an impact shows the two modes
    of the housing-on-frame system at the undamped 2-DOF eigenfrequencies."""
    params = RigParams(seal=Seal(enabled=False))
    sm = params.effects.second_mode
    sm.enabled, sm.frequency_hz, sm.modal_mass_kg, sm.damping_ratio = True, 39.0, 40.0, 0.01
    n = int(8 * FS)
    force = np.zeros((2, n))
    force[0, 100:120] = 300 * np.sin(np.pi * np.arange(20) / 20)
    tr, _ = simulate_response(force, params, FS, fill=0.0)
    freqs = np.fft.rfftfreq(n, 1 / FS)
    h = np.abs(np.fft.rfft(tr.x_m) / np.fft.rfft(force[0]))
    m1, k1 = 9.7, 788e3
    m2 = 40.0
    k2 = m2 * (2 * np.pi * 39.0) ** 2
    # absolute coordinates: housing u1, frame u2; rods k1 between them, frame spring k2 to ground
    kmat = np.array([[k1, -k1], [-k1, k1 + k2]])
    mmat = np.diag([m1, m2])
    expected = np.sort(np.sqrt(np.linalg.eigvals(np.linalg.solve(mmat, kmat)).real)) / (2 * np.pi)
    peaks = [i for i in range(1, h.size - 1)
             if 10 < freqs[i] < 150 and h[i] > h[i - 1] and h[i] > h[i + 1]
             and h[i] > 0.2 * h[(freqs > 10) & (freqs < 150)].max()]
    found = np.sort(freqs[peaks])
    assert len(found) == 2, found
    np.testing.assert_allclose(found, expected, atol=0.5)


def test_frame_coupling_stays_stable_at_high_eccentricity():
    """Regression: with the frame on, a light frame and the film near contact (damping ~300x
    the centred value), the coupled implicit step stays bounded."""
    params = RigParams()
    sm = params.effects.second_mode
    sm.enabled, sm.frequency_hz, sm.modal_mass_kg = True, 39.0, 10.0
    t = np.arange(int(2 * FS)) / FS
    force = np.vstack([200 * np.cos(2 * np.pi * 20 * t), 200 * np.sin(2 * np.pi * 20 * t)])
    tr, _ = simulate_response(force, params, FS, fill=1.0)
    r = np.hypot(tr.x_m, tr.y_m)
    assert np.all(np.isfinite(r))
    assert r.max() < 127e-6  # inside the clearance: the film's eccentricity law holds it off


def _two_mass_receptance(params: RigParams, omega: float, added_mass_relative: bool = True
                         ) -> tuple[complex, complex]:
    """Closed form, lubricated, linear (no seal, centred film): relative displacement z and
    absolute housing acceleration a per newton on the housing, with the frame on its spring
    (or rigid, when the frame mode is off).

    Housing: -w^2 M_a (z + z_f) + R z = F, frame: (k_fr + i w c_fr - w^2 m_fr) z_f = R z, with
    R = K + i w C - w^2 D the film and rods between housing and journal (the film's added mass
    on the relative acceleration) and M_a = M + M_f. ``added_mass_relative=False``: D moved to
    the absolute acceleration (the formulation this model replaced), to show the test can tell."""
    st, film, sm = params.structure, params.film, params.effects.second_mode
    m_a = st.mass_kg + film.fluid_mass_kg
    d = film.added_mass()
    c = st.residual_damping_ns_per_m + film.eq16_damping_centred(film.reference_viscosity()[0])
    wn = 2 * math.pi * sm.frequency_hz
    frame = (sm.modal_mass_kg * wn**2 + 1j * omega * 2 * sm.damping_ratio * sm.modal_mass_kg * wn
             - omega**2 * sm.modal_mass_kg)
    if not added_mass_relative:
        m_a, d = m_a + d, 0.0
    r = st.stiffness_x_n_per_m + 1j * omega * c - omega**2 * d
    frame_per_relative = r / frame if sm.enabled else 0.0
    z = 1.0 / (r - omega**2 * m_a * (1.0 + frame_per_relative))
    return z, -(omega**2) * z * (1.0 + frame_per_relative)


@pytest.mark.parametrize(("freq_hz", "frame"), [(25.0, True), (36.0, True), (39.0, True),
                                                (45.0, True), (60.0, True), (25.0, False),
                                                (45.0, False)])
def test_film_added_mass_acts_on_the_motion_relative_to_the_journal(freq_hz: float,
                                                                     frame: bool):
    """With the frame mode on and the film full, the probe (relative) and accelerometer
    (absolute) responses match the two-mass closed form with the film's damping and added mass
    on the housing-journal relative motion and their reaction on the frame, within 0.1 %
    (measured: 1.5e-4 at most; the former absolute-acceleration formulation is off by 26-60 %).
    With a rigid frame both formulations are the same model."""
    params = RigParams(seal=Seal(enabled=False), film=Film(eccentricity_law=False))
    sm = params.effects.second_mode
    sm.enabled, sm.frequency_hz, sm.modal_mass_kg, sm.damping_ratio = frame, 39.0, 40.0, 0.03
    amp = 30.0
    t = np.arange(int(2.5 * FS)) / FS
    force = np.vstack([amp * np.cos(2 * np.pi * freq_hz * t), np.zeros(t.size)])
    tr, _ = simulate_response(force, params, FS, fill=1.0)
    assert np.abs(tr.x_m).max() < 0.5 * 127e-6  # inside the clearance, no contact
    z_sim = lockin(tr.x_m, freq_hz) / amp
    a_sim = lockin(tr.ax_m_per_s2, freq_hz) / amp
    w = 2 * np.pi * freq_hz
    z_exp, a_exp = _two_mass_receptance(params, w)
    assert abs(z_sim / z_exp - 1) < 1e-3, (z_sim, z_exp)
    assert abs(a_sim / a_exp - 1) < 1e-3, (a_sim, a_exp)
    if frame:  # the test can tell the two formulations apart
        z_abs, a_abs = _two_mass_receptance(params, w, added_mass_relative=False)
        assert max(abs(z_sim / z_abs - 1), abs(a_sim / a_abs - 1)) > 0.1


def test_the_journal_stops_the_housing_at_the_clearance():
    """The issue's case: 100 N at 40 Hz on the dry rig went to 410 um, three times the 127 um
    clearance. With the journal as a wall the orbit ends at c and the contact force shows."""
    from rig_model.rig import simulate_response

    fs = 10_000.0
    t = np.arange(20_000) / fs
    force = np.vstack([100.0 * np.sin(2 * np.pi * 40.0 * t), np.zeros_like(t)])
    free = RigParams.model_validate({"contact": {"enabled": False}})
    truth_free, _ = simulate_response(force, free, fs, fill=0.0)
    assert np.hypot(truth_free.x_m, truth_free.y_m).max() > 3 * 127e-6 * 0.9
    truth, _ = simulate_response(force, RigParams(), fs, fill=0.0)
    radius = np.hypot(truth.x_m, truth.y_m)
    assert radius.max() <= 127e-6 * (1 + 1e-9)
    assert radius.max() >= 127e-6 * (1 - 1e-3)  # it does reach the wall (seen at the samples)
    assert truth.contact_n.max() > 1e3  # a stiff contact: kN for an instant
    # only at the wall: within a sample (0.1 ms) the rebound carries it at most a few um away
    assert np.all(truth.contact_n[radius < 0.95 * 127e-6] == 0)


def test_contact_restitution_reflects_the_approach_speed():
    """A housing thrown at the wall (no spring, no friction, no film) comes back at e times its
    speed: the coefficient of restitution."""
    from rig_model.rig import simulate_response

    fs = 10_000.0
    params = RigParams.model_validate({
        "structure": {"stiffness_x_n_per_m": 1e-6, "stiffness_y_n_per_m": 1e-6,
                      "residual_damping_ns_per_m": 0.0},
        "seal": {"enabled": False}, "contact": {"restitution": 0.5},
    })
    n = 4000
    force = np.zeros((2, n))
    force[0, :10] = 9.7 * 0.01 * fs / 10  # an impulse giving ~0.01 m/s along +x
    truth, _ = simulate_response(force, params, fs, fill=0.0)
    v_in = truth.vx_m_per_s[50]
    hit = int(np.argmax(truth.contact_n > 0))
    v_out = truth.vx_m_per_s[hit + 5]
    assert v_in > 0.008 and hit > 50
    assert v_out == pytest.approx(-0.5 * v_in, rel=0.02)
    assert np.hypot(truth.x_m, truth.y_m).max() <= 127e-6 * (1 + 1e-9)


def _joint_rig(mode: str = "housing", k_j: float = 300e3, f_s: float = 6.0) -> RigParams:
    data = RigParams().model_dump(mode="python")
    data["seal"]["enabled"] = False
    data["effects"]["joint_microslip"] = {"enabled": True, "mode": mode,
                                          "stiffness_n_per_m": k_j, "slip_force_n": f_s}
    if mode == "frame":
        data["effects"]["second_mode"] = {"enabled": True, "frequency_hz": 39.0,
                                          "modal_mass_kg": 40.0, "damping_ratio": 0.03}
    return RigParams.model_validate(data)


@pytest.mark.parametrize("force_n", [2.0, 20.0])
def test_joint_microslip_follows_the_dahl_loop(force_n: float):
    """Quasi-static (1 Hz, dry): the joint's force, from the equation of motion, traces the
    Dahl loop dF/dz = k_j (1 - sgn(z') F / F_s): peak F_s (1 - e) / (1 + e), e = exp(-2 k_j X
    / F_s), and the loop's energy 2 int_{-X}^{X} (F_s - (F_s + F_peak) exp(-k_j (z + X) / F_s))
    dz."""
    rig = _joint_rig()
    fs_hz, f_hz = 2000.0, 1.0
    t = np.arange(int(4 * fs_hz)) / fs_hz
    force = np.vstack([force_n * np.sin(2 * math.pi * f_hz * t), np.zeros_like(t)])
    tr, _ = simulate_response(force, rig, fs_hz, fill=0.0)
    st = rig.structure
    joint = (force[0] - st.stiffness_x_n_per_m * tr.x_m
             - st.residual_damping_ns_per_m * tr.vx_m_per_s - st.mass_kg * tr.ax_m_per_s2)
    last = slice(int(3 * fs_hz), None)  # the last cycle (steady loop)
    z, fj = tr.x_m[last], joint[last]
    amp = 0.5 * (z.max() - z.min())
    e = math.exp(-2 * 300e3 * amp / 6.0)
    peak = 6.0 * (1 - e) / (1 + e)
    assert 0.5 * (fj.max() - fj.min()) == pytest.approx(peak, rel=0.01)
    assert np.all(np.abs(fj) <= 6.0 * 1.001)
    work = float(np.sum(0.5 * (fj[1:] + fj[:-1]) * np.diff(z)))
    ascending = 2 * amp * 6.0 - (6.0 + peak) * (6.0 / 300e3) * (1 - e)
    assert abs(work) == pytest.approx(2 * ascending, rel=0.03)
    # the secant stiffness K + F_peak / X: small motion, the joint stuck adds its stiffness;
    # larger, it slips and the spring softens
    assert force_n / amp == pytest.approx(788e3 + peak / amp, rel=0.01)
    if force_n == 2.0:
        assert peak / amp == pytest.approx(300e3, rel=0.05)
    else:
        assert peak / amp < 0.8 * 300e3


def test_joint_microslip_on_the_frame_mode_softens_it():
    """On the frame's spring: the frame resonance (near 39 Hz) falls with the force level."""
    fs_hz = 5000.0
    t = np.arange(int(2.0 * fs_hz)) / fs_hz
    peaks = []
    for level in (5.0, 200.0):
        freqs = np.linspace(25.0, 60.0, 36)
        amp = []
        for f in freqs:
            force = np.vstack([level * np.sin(2 * math.pi * f * t), np.zeros_like(t)])
            tr, _ = simulate_response(force, _joint_rig("frame", 3e6, 20.0), fs_hz, fill=0.0)
            amp.append(np.ptp(tr.ax_m_per_s2[len(t) // 2:]) / level)
        peaks.append(freqs[int(np.argmax(amp))])
    assert peaks[1] < peaks[0] - 2.0


def test_joint_on_the_frame_needs_the_frame_mode():
    data = RigParams().model_dump(mode="python")
    data["effects"]["joint_microslip"] = {"enabled": True, "mode": "frame",
                                          "stiffness_n_per_m": 1e5}
    with pytest.raises(ValueError, match="needs effects.second_mode.enabled"):
        RigParams.model_validate(data)


def test_cross_stiffness_static_deflection_is_the_2x2_stiffness_solution():
    """A static force on x, the rods' cross stiffness k_xy on: x and y settle where the
    symmetric 2x2 stiffness matrix [[K_x, k_xy], [k_xy, K_y]] puts them, within 1e-6."""
    params = RigParams(seal=Seal(enabled=False))
    params.contact.enabled = False
    st = params.structure
    k_x, k_y = st.stiffness_x_n_per_m, st.stiffness_y_n_per_m
    st.stiffness_xy_n_per_m = k_xy = 0.15 * math.sqrt(k_x * k_y)
    force_n = 40.0
    t = np.arange(int(3.0 * FS)) / FS
    ramp = force_n * np.minimum(t / 0.2, 1.0)  # raised gently: no ringing to wait for
    tr, _ = simulate_response(np.vstack([ramp, np.zeros(t.size)]), params, FS, fill=0.0)
    det = k_x * k_y - k_xy**2
    assert tr.x_m[-1] == pytest.approx(k_y / det * force_n, rel=1e-6)
    assert tr.y_m[-1] == pytest.approx(-k_xy / det * force_n, rel=1e-6)
    # and the force on y alone moves x the same way (the spring is symmetric)
    tr, _ = simulate_response(np.vstack([np.zeros(t.size), ramp]), params, FS, fill=0.0)
    assert tr.x_m[-1] == pytest.approx(-k_xy / det * force_n, rel=1e-6)
    assert tr.y_m[-1] == pytest.approx(k_x / det * force_n, rel=1e-6)


def test_the_diagonal_kernel_is_the_general_one_with_the_cross_terms_at_zero():
    """The kernel compiled for a rig without the frame mode and the film's cross terms (the
    report's rig) inverts diagonal matrices and takes the friction's stopping impulse as the
    kick's momentum; the one compiled for cross terms does the 2x2 algebra. With the cross
    terms zero they are the same equations: the responses agree to round-off through a stuck,
    a slipping seal and bounces on the journal (eccentricity law on)."""
    p = kernel_params(RigParams(), FS)
    switches = physics.kernel_switches(p)
    assert switches == (False, 1, True, False, False)  # no frame, Coulomb, eps law, no air/cross
    n = int(0.3 * FS)
    t = np.arange(n) / FS
    circle = np.vstack([np.cos(2 * np.pi * 40 * t), np.sin(2 * np.pi * 40 * t)])
    push = np.vstack([np.minimum(t / 0.1, 1.0) * 400.0, np.zeros(n)])  # 0.5 mm static: the wall
    force = np.hstack([10.0 * circle, 150.0 * circle, push + 150.0 * circle])
    fill, visc = np.ones(force.shape[1]), np.ones(force.shape[1])
    outs = []
    for kernel in (physics.kernel_for(p), physics._make_kernel(*switches[:4], True)):
        out = np.empty((physics.N_OUT, force.shape[1]))
        kernel(force, fill, visc, p, np.zeros(physics.N_STATE), out)
        outs.append(out)
    diagonal, general = outs
    assert np.all(np.isfinite(diagonal))
    assert diagonal[physics.O_CONTACT].max() > 0  # the wall was met
    stuck = slice(n // 2, n)
    assert np.abs(diagonal[physics.O_VX, stuck]).max() < 1e-9  # held by the seal
    assert np.abs(diagonal[physics.O_VX, n:2 * n]).max() > 1e-3  # then slipping
    scale = np.abs(general).max(axis=1) + 1e-300
    assert np.all(np.abs(diagonal - general).max(axis=1) <= 1e-8 * scale)
