"""Units of the identification: synchronous components, energy terms, seal force, fits, film."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.dry import dry_point, fit_energy
from analysis.dwells import Dwell
from analysis.lubricated import seal_force_1x
from analysis.sync import harmonics, synthesize, whole_cycle_span
from analysis.uncertainty import line_fit, probe_gain_u, scatter_u95, t95
from rig_model.film import eccentricity_factor, energy_equivalent_damping
from rig_model.params import RigParams

FS = 10_000.0


def test_harmonics_exact_with_run_time_reference() -> None:
    f = 30.0  # 333.33 samples per cycle: not an integer
    first = 12_345
    n = int(10 * FS / f)
    t = (first + np.arange(n)) / FS
    z1, z3 = 3e-5 * np.exp(0.7j), 2e-6 * np.exp(-1.1j)
    sig = 0.4 + np.real(z1 * np.exp(2j * np.pi * f * t) + z3 * np.exp(6j * np.pi * f * t))
    amps, mean = harmonics(sig, first, f, FS)
    assert amps[0] == pytest.approx(z1, abs=1e-15)
    assert amps[2] == pytest.approx(z3, abs=1e-15)
    assert abs(amps[1]) < 1e-15 and mean == pytest.approx(0.4)
    # convention of eq. 12: z = z_c cos + z_s sin  ->  Z = z_c - i z_s
    zc, zs = 2.0, -5.0
    s = zc * np.cos(2 * np.pi * f * t) + zs * np.sin(2 * np.pi * f * t)
    a, _ = harmonics(s, first, f, FS)
    assert a[0] == pytest.approx(complex(zc, -zs))
    np.testing.assert_allclose(synthesize(a, f, t), s, atol=1e-12)


def test_whole_cycle_span() -> None:
    first, last, cycles = whole_cycle_span(100, 100 + 900, 30.0, FS)
    assert cycles == 2.0 and last - first == round(2 * FS / 30.0)
    assert whole_cycle_span(0, 200, 30.0, FS)[2] == 0.0


def _dwell(f: float, **harm: np.ndarray) -> Dwell:
    d = Dwell("r", 0, f, "circular_forward", "load", 40.0, 0, 1000, 10, True)
    d.harmonics.update(harm)
    return d


def test_dry_energy_terms_closed_form() -> None:
    f, r = 50.0, 40e-6
    w = 2 * np.pi * f
    fx = 30.0 * np.exp(1j * 0.9)
    x = r
    # forward circular orbit: Y lags X by 90 deg
    d = _dwell(f, fx=np.array([fx, 0, 0, 0, 0]), fy=np.array([fx * -1j, 0, 0, 0, 0]),
               x=np.array([x, 0, 0, 0, 0], complex), y=np.array([-1j * x, 0, 0, 0, 0]))
    p = dry_point(d)
    assert p.work_j == pytest.approx(2 * np.pi * 30.0 * r * math.sin(0.9))  # eq. 2
    assert p.abs_v_integral_m == pytest.approx(r * w / f, rel=1e-9)  # |V| = r w, one period
    assert p.v2_integral_m2_per_s == pytest.approx((r * w) ** 2 / f, rel=1e-9)


def test_energy_fit_recovers_coefficients() -> None:
    pts = []
    for f in (20.0, 40.0, 80.0, 160.0):
        r = 30e-6
        w = 2 * np.pi * f
        work = 26.0 * r * w / f + 370.0 * (r * w) ** 2 / f
        x = np.array([r, 0, 0, 0, 0], complex)
        d = _dwell(f, fx=np.zeros(5, complex), fy=np.zeros(5, complex), x=x, y=-1j * x)
        p = dry_point(d)
        p.work_j = work
        pts.append(p)
    fit = fit_energy(pts, "t")
    assert fit.f_mu_n == pytest.approx(26.0) and fit.c_rv_ns_per_m == pytest.approx(370.0)
    assert fit.r2 == pytest.approx(1.0)
    with pytest.raises(ValueError, match="at least 3 dwells"):
        fit_energy(pts[:2], "t")


def test_seal_force_of_a_sliding_sinusoid_is_eq9() -> None:
    f, a = 40.0, 30e-6
    w = 2 * np.pi * f
    z = np.zeros(25, complex)
    z[0] = a
    force = np.zeros(25, complex)
    # a sliding housing: K - w^2 M_T + i w C, plus the seal's 4 F_mu / pi along the velocity;
    # at each reversal F - K z = -w^2 M_T a (34 N) exceeds F_mu, so it never sticks
    force[0] = a * (788e3 - w**2 * 17.9 + 1j * w * 5500.0) + 1j * 4 * 26.0 / np.pi
    s1, stick = seal_force_1x(force, z, f, 26.0, 788e3)
    c_equiv = (s1 / (1j * w * a)).real
    assert c_equiv == pytest.approx(4 * 26.0 / (np.pi * w * a), rel=2e-3)  # eq. 9
    assert abs((s1 / a).real) < 1e-3 * abs(s1 / a)  # no in-phase part
    assert stick == 0.0


def test_line_fit_and_appendix_b() -> None:
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    y = 2.0 * x + 1.0 + np.array([0.01, -0.02, 0.0, 0.02, -0.01])
    fit = line_fit(x, y)
    res = y - (fit.slope * x + fit.intercept)
    assert fit.see == pytest.approx(math.sqrt((res**2).sum() / 3))  # eq. B.1
    assert t95(2) == pytest.approx(4.303, abs=1e-3)  # Appendix B
    assert scatter_u95([1.0, 2.0, 3.0]) == pytest.approx(4.303 * 1.0 / math.sqrt(3), rel=1e-3)
    assert scatter_u95([5.0]) == 0.0
    u = probe_gain_u(fit, u_voltmeter_v=0.001, u_gauge_m=0.01)
    expect = math.hypot(0.01 / 4.0, math.hypot(fit.see, 0.001) / np.ptp(y))  # eq. B.4-B.5
    assert u == pytest.approx(expect)
    with pytest.raises(ValueError, match="at least 3 points"):
        line_fit([1, 2], [1, 2])


def test_film_energy_equivalent_damping() -> None:
    p = RigParams()
    c0 = p.film.eq16_damping_centred(3.17e-3)
    assert c0 == pytest.approx(5060, rel=0.01)  # rig-numbers.md
    assert energy_equivalent_damping(p, 1e-9) == pytest.approx(c0, rel=1e-6)
    a = 38e-6
    eps = a / p.film.clearance_m
    uni = energy_equivalent_damping(p, a, "x")
    assert c0 < uni < c0 * eccentricity_factor(eps)  # between centred and the peak eps
    assert energy_equivalent_damping(p, a, "circular_forward") == pytest.approx(
        c0 * (1 + 2 * eps**2) / (1 - eps**2) ** 2)
    p.film.eccentricity_law = False
    assert energy_equivalent_damping(p, a, "x") == pytest.approx(c0)
    with pytest.raises(ValueError, match="motion"):
        energy_equivalent_damping(p, a, "elliptical")
