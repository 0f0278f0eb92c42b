"""`analysis.calibration`: the structure fit against Table 3 (closed form checked here), the
comparison rules, and the shipped calibrated rig against the report's tables through the report's
own identification of the simulated test plan (the reduced plan in CI)."""

from __future__ import annotations

import contextlib
import io
import math
import tempfile
from pathlib import Path

import pytest

from analysis.calibration.compare import Comparison, compare, table_errors
from analysis.calibration.fit import fit_residual_damping, fit_structure
from analysis.calibration.plan import ReportPlan
from analysis.identify import identify
from analysis.report_tables import find, load_table
from sfdrig.report_plan import run_report_plan
from simulated_hw.params import RigParams, rig_params_named_or_file


def _table3_rows(params: RigParams, offset_k: float = 0.0) -> list[Comparison]:
    """Table 3 as `compare` makes it, for an identification that returns ``params`` (K shifted
    by ``offset_k``)."""
    t3 = load_table("table3_impact")
    st = params.structure
    sim = {("K_s", "x"): st.stiffness_x_n_per_m + offset_k,
           ("K_s", "y"): st.stiffness_y_n_per_m + offset_k,
           ("M", "x"): st.mass_kg, ("M", "y"): st.mass_kg,
           ("C_s", "x"): st.residual_damping_ns_per_m, ("C_s", "y"): st.residual_damping_ns_per_m}
    rows = []
    for (q, a), v in sim.items():
        unit = {"K_s": "N/m", "M": "kg", "C_s": "N.s/m"}[q]
        r = find(t3, q, a, unit)
        rows.append(Comparison("Table 3", q, a, unit, r.value, v, r.u_abs or 0.1 * r.value, ""))
    for a in ("x", "y"):
        r = find(t3, "f_n", a, "Hz")
        fn = math.sqrt(sim["K_s", a] / sim["M", a]) / (2 * math.pi)
        rows.append(Comparison("Table 3", "f_n", a, "Hz", r.value, fn, 1.0, ""))
    rows.append(Comparison("Table 4", "C_rv", "xy", "N.s/m", 370.0, st.residual_damping_ns_per_m,
                           12.0, ""))
    return rows


def test_structure_fit_reaches_table3_where_one_spring_per_axis_can():
    m, kx, ky = fit_structure(_table3_rows(RigParams()), RigParams())
    fx = math.sqrt(kx / m) / (2 * math.pi)
    fy = math.sqrt(ky / m) / (2 * math.pi)
    # one mass for both axes: between Table 3's 8.8 (X) and 9.7 kg (Y), within 0.55 kg of both
    assert 9.15 < m < 9.35
    assert abs(fx - 47.0) <= 1.0 and abs(fy - 49.0) <= 1.0
    assert abs(kx - 800e3) <= 40e3 and abs(ky - 923e3) <= 46e3
    # ... and so the Y spring leaves Table 2 (786 +/- 31.5 kN/m) and the text's 823 kN/m
    assert ky > 823e3 * 1.04


def test_structure_fit_removes_the_identification_offset():
    # an identification that reads every K 10 kN/m high: the fitted springs are 10 kN/m softer
    p = RigParams()
    _, kx0, ky0 = fit_structure(_table3_rows(p), p)
    _, kx1, ky1 = fit_structure(_table3_rows(p, offset_k=10e3), p)
    assert kx1 == pytest.approx(kx0 - 10e3, abs=300)
    assert ky1 == pytest.approx(ky0 - 10e3, abs=300)


def test_residual_damping_is_the_band_weighted_mean():
    rows = _table3_rows(RigParams())
    c = fit_residual_damping(rows, 370.0)
    w = [1 / 12.0**2, 1 / 36.7**2, 1 / 31.5**2]
    expected = (370 * w[0] + 367 * w[1] + 315 * w[2]) / sum(w)
    assert c == pytest.approx(expected, rel=1e-9)
    assert 360 < c < 370


def test_comparison_band_and_normalised_error():
    r = Comparison("Table 3", "f_n", "x", "Hz", 47.0, 45.4, 1.0, "stated")
    assert not r.within and r.normalised == pytest.approx(1.6)
    assert r.rel_error == pytest.approx(-1.6 / 47)
    assert table_errors([r])["Table 3"] == {"rows": 1, "within": 0,
                                            "rms_normalised_error": pytest.approx(1.6)}


def _identify_plan(params: RigParams) -> list[Comparison]:
    with tempfile.TemporaryDirectory() as tmp:
        paths = run_report_plan(Path(tmp), params, ReportPlan.reduced(), seed=3)
        with contextlib.redirect_stdout(io.StringIO()):
            return compare(identify(paths))


@pytest.fixture(scope="module")
def side_by_side() -> dict[str, dict[str, Comparison]]:
    return {name: {r.key: r for r in _identify_plan(rig_params_named_or_file(name))}
            for name in ("nominal", "report")}


def _get(rows: dict[str, Comparison], table: str, quantity: str, axis: str) -> Comparison:
    return rows[f"{table}|{quantity}|{axis}"]


def test_calibrated_rig_reproduces_table3_natural_frequencies_and_y_stiffness(side_by_side):
    nominal, report = side_by_side["nominal"], side_by_side["report"]
    for axis, reported in (("x", 47.0), ("y", 49.0)):
        assert not _get(nominal, "Table 3", "f_n", axis).within  # 45.4 / 46.4 Hz
        fn = _get(report, "Table 3", "f_n", axis)
        assert fn.within and abs(fn.simulated - reported) <= 1.0
    assert not _get(nominal, "Table 3", "K_s", "y").within  # 823 against 923 +/- 46 kN/m
    assert _get(report, "Table 3", "K_s", "y").within
    assert _get(report, "Table 3", "K_s", "x").within
    assert _get(report, "Table 3", "M", "y").within


def test_what_one_mass_and_one_damping_per_rig_cannot_reach(side_by_side):
    # measured, not hidden: one housing mass for both axes sits between Table 3's 8.8 kg (X) and
    # 9.7 kg (Y); one C_rv cannot give Table 3's 315 N.s/m in Y beside Table 4's 370 N.s/m;
    # the Y spring the impact test needs is above the static Table 2 value
    report = side_by_side["report"]
    m_x = _get(report, "Table 3", "M", "x")
    assert 0.4 < m_x.error < 0.7
    assert not _get(report, "Table 3", "C_s", "y").within
    assert _get(report, "Table 4", "C_rv", "xy").within
    assert not _get(report, "Table 2", "K_s", "y").within


def test_both_rigs_identify_table4_friction_and_residual_damping(side_by_side):
    for rows in side_by_side.values():
        assert _get(rows, "Table 4", "F_mu", "xy").within
        assert _get(rows, "Table 4", "C_rv", "xy").within


def test_calibrated_film_damping_average_and_trends(side_by_side):
    nominal, report = side_by_side["nominal"], side_by_side["report"]
    avg_n = _get(nominal, "Film (section VI.3)", "C_sfd average", "xy")
    avg_r = _get(report, "Film (section VI.3)", "C_sfd average", "xy")
    assert avg_n.error < -800  # eq. 16 with 3.17 cP, identified with eq. 9: ~4,900 N.s/m
    assert abs(avg_r.error) < 400 and avg_r.within
    for axis in ("x", "y"):
        f_n = _get(nominal, "Film (Fig. 33)", "C_sfd change 20-60 Hz / mean, 13 um", axis)
        f_r = _get(report, "Film (Fig. 33)", "C_sfd change 20-60 Hz / mean, 13 um", axis)
        assert f_n.simulated > 0.25  # rigid sticking: C_sfd rises with frequency at 13 um
        assert f_r.within and abs(f_r.simulated) < 0.6 * f_n.simulated
        a_r = _get(report, "Film (Figs. 33-34)", "C_sfd (38 um - 13 um) / mean", axis)
        assert a_r.within


def test_calibrated_added_mass_rises_with_amplitude_as_table_f1(side_by_side):
    nominal, report = side_by_side["nominal"], side_by_side["report"]
    d13_n = _get(nominal, "Table F1", "D at 13 um", "x").simulated
    d38_n = _get(nominal, "Table F1", "D at 38 um", "x").simulated
    d13_r = _get(report, "Table F1", "D at 13 um", "x").simulated
    d38_r = _get(report, "Table F1", "D at 38 um", "x").simulated
    assert d13_n > d38_n + 2.0  # rigid sticking: the opposite of the report's trend
    assert d13_r < d38_r  # the report: 6.8 kg at 13 um rising to 9.4 kg at 38 um
    assert abs(d13_r - 6.8) < 1.5
    for axis in ("x", "y"):
        assert _get(report, "Table 6", "D", axis).within
        assert _get(report, "Table 6", "M_t", axis).within
