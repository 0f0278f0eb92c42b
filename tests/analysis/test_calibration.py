"""`analysis.calibration`: the structure fit against Table 3 (closed form checked here), the
comparison rules, and the shipped calibrated rig against the report's tables through the report's
own identification of the simulated test plan (the reduced plan in CI)."""

from __future__ import annotations

import contextlib
import io
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from analysis.calibration.compare import Comparison, compare, table_errors
from analysis.calibration.fit import (
    AMPLITUDE_INVARIANCE_60HZ,
    TREND_13UM,
    FittedTerm,
    dynamic_stiffness,
    fit_eccentricity_law,
    fit_residual_damping,
    fit_static_dynamic_split,
    fit_structure,
    fit_wet_friction,
    relaxed_share,
)
from analysis.calibration.plan import ReportPlan
from analysis.identify import identify
from analysis.report_tables import find, load_table
from rig_model.params import RigParams, rig_params_named_or_file
from sfdrig.commands.calibrate import simulator
from sfdrig.report_plan import run_report_plan

#: The fixed bands the simulated identification is judged on, written here (issue 27; the same
#: bands as issue 28): the report's stated bands for Tables 2 and 3 (C_s: the report's own
#: "within ~10 %" of the impact C_s, section IV.4); elsewhere friction F_mu 10 %, residual damping
#: C_rv 20 %, total masses M_t 10 %, added mass D 15 % or 1 kg (the larger; 2 kg at 13 um), the
#: film's average damping 10 %, its trends 0.10 of the mean. Not `Comparison.band`, which falls
#: back on the identification's own 95 % uncertainty (a noisier fit would pass more easily).
STATED_BANDS: dict[tuple[str, str, str], float] = {
    ("Table 2", "K_s", "x"): 30.6e3, ("Table 2", "K_s", "y"): 31.5e3,
    ("Table 3", "K_s", "x"): 40e3, ("Table 3", "K_s", "y"): 46e3,
    ("Table 3", "M", "x"): 0.5, ("Table 3", "M", "y"): 0.5,
    ("Table 3", "f_n", "x"): 1.0, ("Table 3", "f_n", "y"): 1.0,
    ("Table 3", "C_s", "x"): 0.10 * 367, ("Table 3", "C_s", "y"): 0.10 * 315,
}


def fixed_band(row: Comparison) -> float:
    """The half-width row ``row`` is judged on (its unit); a row without one here is an error."""
    q = row.quantity
    if (row.table, q, row.axis) in STATED_BANDS:
        return STATED_BANDS[row.table, q, row.axis]
    rel = {"F_mu": 0.10, "C_rv": 0.20, "M_t": 0.10, "C_sfd average": 0.10}
    if row.table in ("Table 4", "Table 6", "Film (section VI.3)") and q in rel:
        return rel[q] * abs(row.report)
    if q == "D at 13 um":
        return 2.0
    if q == "D" or q.startswith("D at "):
        return max(0.15 * abs(row.report), 1.0)
    if row.table.startswith("Film") and row.unit == "1":  # trends, relative to the mean
        return 0.10
    raise AssertionError(f"no fixed band written for {row.key}")


def holds(row: Comparison) -> bool:
    return bool(np.isfinite(row.simulated)) and abs(row.error) <= fixed_band(row)


def _table3_rows(params: RigParams, offset_k: float = 0.0) -> list[Comparison]:
    """Table 3 and Table 4's C_rv as `compare` makes them, for an identification that returns
    ``params`` (K shifted by ``offset_k``)."""
    t3 = load_table("table3_impact")
    st = params.structure
    sim = {("K_s", "x"): st.stiffness_x_n_per_m + offset_k,
           ("K_s", "y"): st.stiffness_y_n_per_m + offset_k,
           ("M", "x"): st.mass_kg, ("M", "y"): st.mass_y(),
           ("C_s", "x"): st.residual_damping_ns_per_m, ("C_s", "y"): st.residual_damping_y()}
    rows = []
    for (q, a), v in sim.items():
        unit = {"K_s": "N/m", "M": "kg", "C_s": "N.s/m"}[q]
        r = find(t3, q, a, unit)
        rows.append(Comparison("Table 3", q, a, unit, r.value, v, r.u_abs or 0.1 * r.value, ""))
    for a in ("x", "y"):
        r = find(t3, "f_n", a, "Hz")
        fn = math.sqrt(sim["K_s", a] / sim["M", a]) / (2 * math.pi)
        rows.append(Comparison("Table 3", "f_n", a, "Hz", r.value, fn, 1.0, ""))
    c_mean = 0.5 * (st.residual_damping_ns_per_m + st.residual_damping_y())
    rows.append(Comparison("Table 4", "C_rv", "xy", "N.s/m", 370.0, c_mean, 12.0, ""))
    return rows


def test_structure_fit_reaches_table3_per_axis():
    p = RigParams()
    for axis, k_rep, u_k, m_rep, fn_rep in (("x", 800e3, 40e3, 8.8, 47.0),
                                            ("y", 923e3, 46e3, 9.7, 49.0)):
        m, k = fit_structure(_table3_rows(p), p, axis)
        assert abs(k - k_rep) <= u_k and abs(m - m_rep) <= 0.5
        assert abs(math.sqrt(k / m) / (2 * math.pi) - fn_rep) <= 1.0
        if axis == "x":  # X also agrees with Table 2 (765 +/- 31 kN/m) ...
            assert abs(k - 765e3) <= 31e3
        else:  # ... Y cannot: the impact needs a spring far above Table 2 and the text
            assert k > 823e3 + 33e3


def test_structure_fit_removes_the_identification_offset():
    # an identification that reads every K 10 kN/m high: the fitted springs are 10 kN/m softer
    p = RigParams()
    for axis in ("x", "y"):
        _, k0 = fit_structure(_table3_rows(p), p, axis)
        _, k1 = fit_structure(_table3_rows(p, offset_k=10e3), p, axis)
        assert k1 == pytest.approx(k0 - 10e3, abs=300)


def _table2_rows(k_x: float, k_y: float) -> list[Comparison]:
    """Table 2 as `compare` makes it, for a static test that reads ``k_x``, ``k_y``."""
    t2 = load_table("table2_static_stiffness")
    return [Comparison("Table 2", "K_s", a, "N/m", find(t2, "K_s", a, "N/m").value, k,
                       find(t2, "K_s", a, "N/m").u_abs or 0.04 * k, "")
            for a, k in (("x", k_x), ("y", k_y))]


def test_static_and_dynamic_stiffness_split_into_rods_and_relaxing_stiffness():
    # the nominal rig (one spring, 823 kN/m, no relaxing term): its static test reads the
    # springs; Table 2 says 765 / 786 kN/m, the impacts' fit 800 / 923 kN/m (known: Table 3).
    # The rods go to Table 2; the rest, over the share of k_r acting at f_n, is k_r:
    # (w tau)^2 / (1 + (w tau)^2) at 47 / 49 Hz, tau 0.1 s: 0.99885 / 0.99895
    p = RigParams()
    rows = _table2_rows(p.structure.stiffness_x_n_per_m, p.structure.stiffness_y_n_per_m)
    for axis, k_dyn, m, k2 in (("x", 800e3, 8.8, 765e3), ("y", 923e3, 9.7, 786e3)):
        k_rods, k_r = fit_static_dynamic_split(rows, p, axis, m, k_dyn)
        share = relaxed_share(p, math.sqrt(k_dyn / m) / (2 * math.pi))
        assert 0.9988 < share < 0.9990
        assert k_rods == pytest.approx(k2, rel=1e-12)
        assert k_r == pytest.approx((k_dyn - k2) / share, rel=1e-12)
    # an identification that reads the static K 5 kN/m high: the rods 5 kN/m softer
    high = _table2_rows(p.structure.stiffness_x_n_per_m + 5e3, p.structure.stiffness_y_n_per_m)
    assert fit_static_dynamic_split(high, p, "x", 8.8, 800e3)[0] == pytest.approx(760e3)
    # where the dynamic K is within Table 2's band (30.6 kN/m in X) one spring does
    assert fit_static_dynamic_split(rows, p, "x", 8.8, 790e3) == (790e3, 0.0)


def test_dynamic_stiffness_of_the_shipped_rig_is_what_its_impacts_read():
    # the report rig (`sfdrig calibrate`'s output): one spring of 788.6 kN/m in X; in Y the rods
    # at 786 kN/m and k_r 135.8 kN/m. Its impacts identify 788.7 / 921.2 kN/m (the reduced
    # plan, seed 3, measured): the model of the identification agrees within 0.1 %
    p = rig_params_named_or_file("report")
    assert dynamic_stiffness(p, "x") == pytest.approx(788.7e3, rel=1e-3)
    assert dynamic_stiffness(p, "y") == pytest.approx(921.2e3, rel=1e-3)
    p.effects.relaxing_stiffness.enabled = False
    assert dynamic_stiffness(p, "y") == p.structure.stiffness_y_n_per_m


def test_wet_friction_fit_brings_the_13um_trend_in_x_to_the_reports():
    # the report rig without its wet friction: the film damping at 13 um rises 18 % of the mean
    # from 20 to 60 Hz in X (reduced plan, seed 3; the report: nearly constant). The fit, from
    # two runs, gives the rise that cancels it; run again there the trend is within 0.02 of 0
    # (the band is 0.10). The trend is not exactly linear in dF (slope -0.093 per newton from
    # 0 to 1 N, -0.059 from 3 to 4 N, measured): one secant step from 0 N lands within 0.02.
    p = rig_params_named_or_file("report")
    p.seal.wet_friction_increase_n = 0.0
    logged: list[str] = []
    sim, plan = simulator(3), ReportPlan.reduced()
    fitted = fit_wet_friction(sim, plan, p, logged.append)
    assert fitted is not None
    df, key = fitted
    assert key == f"Film (Fig. 33)|{TREND_13UM}|x"
    assert 1.0 < df < 3.0 and len(logged) == 1
    p.seal.wet_friction_increase_n = df
    (row,) = [r for r in compare(sim(p, plan.only_lubricated((13e-6,), ("x",))))
              if r.key == key]
    assert abs(row.simulated) < 0.02, row.simulated


def test_residual_damping_per_axis_by_weighted_least_squares():
    cx, cy = fit_residual_damping(_table3_rows(RigParams()), RigParams())
    # the normal equations of the three rows (C_x = 367, C_y = 315, (C_x + C_y)/2 = 370),
    # each over its band (36.7, 31.5, 12), solved here by hand
    a = np.array([[1 / 36.7, 0.0], [0.0, 1 / 31.5], [0.5 / 12, 0.5 / 12]])
    b = np.array([367 / 36.7, 315 / 31.5, 370 / 12])
    ata, atb = a.T @ a, a.T @ b
    det = ata[0, 0] * ata[1, 1] - ata[0, 1] * ata[1, 0]
    ex = (atb[0] * ata[1, 1] - ata[0, 1] * atb[1]) / det
    ey = (ata[0, 0] * atb[1] - ata[1, 0] * atb[0]) / det
    assert (cx, cy) == (pytest.approx(ex, rel=1e-9), pytest.approx(ey, rel=1e-9))
    assert cy < cx and 360 < 0.5 * (cx + cy) < 372


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


#: The calibrated rig on the reduced plan (CI), seed 3, against the fixed bands: the rows that
#: hold (measured 2026-11-26 on the rig `sfdrig calibrate` now writes, with issue 28's terms:
#: 28 of 29, as with the hand-fitted rig before it; before the terms 24) ...
REDUCED_HOLD = (
    "Table 2|K_s|x", "Table 2|K_s|y",
    "Table 3|K_s|x", "Table 3|M|x", "Table 3|C_s|x", "Table 3|f_n|x",
    "Table 3|K_s|y", "Table 3|M|y", "Table 3|C_s|y", "Table 3|f_n|y",
    "Table 4|F_mu|xy", "Table 4|C_rv|xy",
    "Table 6|M_t|x", "Table 6|D|x", "Table F1|D at 13 um|x", "Table F1|D at 25 um|x",
    "Table F1|D at 38 um|x",
    "Table 6|M_t|y", "Table 6|D|y", "Table F1|D at 13 um|y", "Table F1|D at 38 um|y",
    "Film (section VI.3)|C_sfd average|xy",
    "Film (Fig. 33)|C_sfd change 20-60 Hz / mean, 13 um|x",
    "Film (Fig. 33)|C_sfd change 20-60 Hz / mean, 13 um|y",
    "Film (Figs. 33-34)|C_sfd (38 um - 13 um) / mean|x",
    "Film (Figs. 33-34)|C_sfd (38 um - 13 um) / mean|y",
    "Film (section VI.3)|C_sfd (38 um - 13 um) / mean at 60 Hz|x",
    "Film (section VI.3)|C_sfd (38 um - 13 um) / mean at 60 Hz|y",
)
#: ... and the known misses (issue 28), with what was measured
REDUCED_MISS = {
    "Table F1|D at 25 um|y": "7.31 kg against 6.2 kg (+1.11 kg; band 1 kg; the hand-fitted rig "
                             "7.50 kg, before the issue's terms 8.42 kg): a held-out row; on the "
                             "full plan it holds (7.03 kg), see docs/report-discrepancies.md",
}


def test_the_comparison_has_every_row_judged(side_by_side):
    assert sorted(side_by_side["report"]) == sorted((*REDUCED_HOLD, *REDUCED_MISS))


@pytest.mark.parametrize("key", [
    *REDUCED_HOLD,
    *(pytest.param(k, marks=pytest.mark.xfail(reason=f"issue 28: {why}", strict=True))
      for k, why in REDUCED_MISS.items())])
def test_calibrated_rig_row_on_its_fixed_band(side_by_side, key):
    row = side_by_side["report"][key]
    assert holds(row), (f"{key}: simulated {row.simulated:.4g} against the report's "
                        f"{row.report:.4g}, fixed band +/- {fixed_band(row):.4g}")


def test_nominal_rig_misses_table3_where_calibration_was_needed(side_by_side):
    # the nominal rig misses the natural frequencies (45.4 / 46.4 Hz against 47 / 49), K in Y
    # (823 against 923 +/- 46 kN/m), M in X (9.7 against 8.8 +/- 0.5 kg) and C_s in Y (370
    # against 315 +/- 31.5 N.s/m); the calibrated rig holds all eight rows (above)
    nominal = side_by_side["nominal"]
    missed = {q_axis for q_axis in (("K_s", "x"), ("K_s", "y"), ("M", "x"), ("M", "y"),
                                    ("C_s", "x"), ("C_s", "y"), ("f_n", "x"), ("f_n", "y"))
              if not holds(_get(nominal, "Table 3", *q_axis))}
    assert missed == {("f_n", "x"), ("f_n", "y"), ("K_s", "y"), ("M", "x"), ("C_s", "y")}


#: The full plan (`sfdrig calibrate`'s, slow), seed 3: all 33 rows hold on the fixed bands
#: (measured 2026-11-26 on the rig `sfdrig calibrate` writes from the nominal one; the hand-fitted
#: rig before it held 32, without Table F1 D at 25 um in Y, 7.25 kg, now 7.03 against 6.2 +/- 1.0;
#: before issue 28's terms 25: Table 2 K_s y, Table F1 D in Y at 13-32 um and in X at 19 um, the
#: 13 um frequency trend in X and Y were out). Exactly these rows: a regression shows.
FULL_HOLD = (
    "Table 2|K_s|x", "Table 2|K_s|y",
    "Table 3|K_s|x", "Table 3|M|x", "Table 3|C_s|x", "Table 3|f_n|x",
    "Table 3|K_s|y", "Table 3|M|y", "Table 3|C_s|y", "Table 3|f_n|y",
    "Table 4|F_mu|xy", "Table 4|C_rv|xy",
    "Table 6|M_t|x", "Table 6|D|x", "Table F1|D at 13 um|x", "Table F1|D at 19 um|x",
    "Table F1|D at 25 um|x", "Table F1|D at 32 um|x", "Table F1|D at 38 um|x",
    "Table 6|M_t|y", "Table 6|D|y", "Table F1|D at 13 um|y", "Table F1|D at 19 um|y",
    "Table F1|D at 25 um|y", "Table F1|D at 32 um|y", "Table F1|D at 38 um|y",
    "Film (section VI.3)|C_sfd average|xy",
    "Film (Fig. 33)|C_sfd change 20-60 Hz / mean, 13 um|x",
    "Film (Fig. 33)|C_sfd change 20-60 Hz / mean, 13 um|y",
    "Film (Figs. 33-34)|C_sfd (38 um - 13 um) / mean|x",
    "Film (Figs. 33-34)|C_sfd (38 um - 13 um) / mean|y",
    "Film (section VI.3)|C_sfd (38 um - 13 um) / mean at 60 Hz|x",
    "Film (section VI.3)|C_sfd (38 um - 13 um) / mean at 60 Hz|y",
)
FULL_MISS: tuple[str, ...] = ()


@pytest.mark.slow
def test_calibrated_rig_holds_33_of_33_rows_of_the_full_plan():
    with tempfile.TemporaryDirectory() as tmp:
        paths = run_report_plan(Path(tmp), rig_params_named_or_file("report"), ReportPlan(),
                                seed=3)
        with contextlib.redirect_stdout(io.StringIO()):
            rows = {r.key: r for r in compare(identify(paths))}
    assert sorted(rows) == sorted((*FULL_HOLD, *FULL_MISS))
    held = {k for k, r in rows.items() if holds(r)}
    shown = {k: f"{r.simulated:.4g} vs {r.report:.4g} +/- {fixed_band(r):.4g}"
             for k, r in rows.items()}
    assert held == set(FULL_HOLD), (
        f"now holding, not listed: {[(k, shown[k]) for k in sorted(held - set(FULL_HOLD))]}; "
        f"no longer holding: {[(k, shown[k]) for k in sorted(set(FULL_HOLD) - held)]}")


def test_table2_and_table3_in_y_with_the_relaxing_stiffness(side_by_side):
    # one spring per axis could not give both the static 786 kN/m (Table 2) and the impact's
    # 923 kN/m in Y (issue 28); the rods at the static value with a relaxing stiffness beside
    # them (135.8 kN/m, tau 0.1 s: relaxed under the static test's held loads, nearly all there
    # at the impact's 49 Hz) give both: measured 786.4 and 921.2 kN/m (within 0.3 %). In X the
    # report's 765 and 800 kN/m are within Table 2's band of one spring: 788.6 kN/m, both tests
    report = side_by_side["report"]
    static, impact = (_get(report, "Table 2", "K_s", "y"), _get(report, "Table 3", "K_s", "y"))
    assert static.simulated == pytest.approx(786e3, rel=3e-3)
    assert impact.simulated == pytest.approx(923e3, rel=3e-3)
    static, impact = (_get(report, "Table 2", "K_s", "x"), _get(report, "Table 3", "K_s", "x"))
    assert static.simulated == pytest.approx(impact.simulated, rel=1e-3)
    assert holds(static) and holds(impact)
    # the nominal rig, one spring at the text's 823 kN/m, misses Table 3 in Y (above)


def test_both_rigs_identify_table4_friction_and_residual_damping(side_by_side):
    # the nominal rig's friction and residual damping (26 N, 370 N.s/m) come back within 0.1 %
    # and 0.3 % on the reduced plan (25.99 N, 370.98 N.s/m): held here to 1.5 %
    for q in ("F_mu", "C_rv"):
        row = _get(side_by_side["nominal"], "Table 4", q, "xy")
        assert holds(row) and abs(row.rel_error) < 0.015, (q, row.simulated)
    # the report rig's seal contact (35 MN/m in X, 22 in Y, issue 28) stores and returns part of
    # the orbit's energy, which the report's energy balance (eq. 2-4) does not model: its
    # friction comes back (26.23 N against 26.01 N built in) and its C_rv reads low, 312.9
    # N.s/m against the 358 built in (the mean of 391 and 326): within the fixed band, and
    # pinned here to the measured value within 3 %
    f_mu = _get(side_by_side["report"], "Table 4", "F_mu", "xy")
    c_rv = _get(side_by_side["report"], "Table 4", "C_rv", "xy")
    assert holds(f_mu) and abs(f_mu.rel_error) < 0.015, f_mu.simulated
    assert holds(c_rv) and c_rv.simulated == pytest.approx(312.9, rel=0.03)


def test_calibrated_film_damping_average_and_trends(side_by_side):
    nominal, report = side_by_side["nominal"], side_by_side["report"]
    avg_n = _get(nominal, "Film (section VI.3)", "C_sfd average", "xy")
    avg_r = _get(report, "Film (section VI.3)", "C_sfd average", "xy")
    assert avg_n.error < -800  # eq. 16 with 3.17 cP, identified with eq. 9: ~4,900 N.s/m
    # measured: 5,939 N.s/m against 6,000 (-61); fixed band 600
    assert abs(avg_r.error) < 150 and holds(avg_r)
    for axis in ("x", "y"):
        q = "C_sfd change 20-60 Hz / mean, 13 um"
        f_n = _get(nominal, "Film (Fig. 33)", q, axis).simulated
        f_r = _get(report, "Film (Fig. 33)", q, axis).simulated
        assert f_n > 0.25  # rigid sticking: C_sfd rises with frequency at 13 um
        # the seal's friction 1.35 N higher with the film full (issue 28) flattens it: measured
        # +0.080 (X) and +0.032 (Y) on the reduced plan (+0.147 / +0.150 before)
        assert abs(f_r) < 0.09
        q = "C_sfd (38 um - 13 um) / mean"
        a_n = _get(nominal, "Film (Figs. 33-34)", q, axis).simulated
        a_r = _get(report, "Film (Figs. 33-34)", q, axis).simulated
        assert a_n > 0.2 and abs(a_r) < 0.05  # "nearly constant": +0.014 / +0.040 measured
        # section VI.3, "invariant at 60 Hz": eq. 16's eccentricity law alone gives +0.082 (see
        # below); the calibrated rig has it off (measured -0.004 / +0.031)
        r60_n = _get(nominal, "Film (section VI.3)", AMPLITUDE_INVARIANCE_60HZ, axis)
        r60_r = _get(report, "Film (section VI.3)", AMPLITUDE_INVARIANCE_60HZ, axis)
        assert r60_n.simulated > 0.08
        assert holds(r60_r) and abs(r60_r.simulated) < 0.05


def test_calibrated_added_mass_rises_with_amplitude_as_table_f1(side_by_side):
    nominal, report = side_by_side["nominal"], side_by_side["report"]
    d13_n = _get(nominal, "Table F1", "D at 13 um", "x").simulated
    d38_n = _get(nominal, "Table F1", "D at 38 um", "x").simulated
    d13_r = _get(report, "Table F1", "D at 13 um", "x")
    d38_r = _get(report, "Table F1", "D at 38 um", "x")
    assert d13_n > d38_n + 2.0  # rigid sticking: the opposite of the report's trend
    assert d13_r.simulated < d38_r.simulated  # the report: 6.8 kg at 13 um rising to 9.4 kg
    # measured: 6.62 kg (band 2 kg) and 9.20 kg (band 1.41 kg)
    assert holds(d13_r) and holds(d38_r)
    # by axis (issue 28): the report's Y values start 3.6 kg below X's at 13 um and meet them
    # at 38 um (3.2 / 6.8 kg rising to 8.1 / 9.4); the softer seal contact in Y and the relaxing
    # stiffness give 3.74 / 6.62 kg at 13 um (before: 6.06 / 5.41, the wrong way round)
    d13_y = _get(report, "Table F1", "D at 13 um", "y")
    d38_y = _get(report, "Table F1", "D at 38 um", "y")
    assert holds(d13_y) and d13_y.simulated < d13_r.simulated - 2.0
    assert d38_y.simulated - d13_y.simulated > 1.5 * (d38_r.simulated - d13_r.simulated)
    for axis in ("x", "y"):  # measured: D 9.20 / 8.59 kg, M_t 19.5 / 18.9 kg
        assert holds(_get(report, "Table 6", "D", axis))
        assert holds(_get(report, "Table 6", "M_t", axis))


def _energy_averaged_eccentricity_factor(eps0: float) -> float:
    """(1 + 2 e^2) / (1 - e^2)^2 with e = eps0 sin(t), weighted by the velocity squared over a
    cycle (written here from eq. 16, independently of the simulator)."""
    t = np.linspace(0.0, 2 * np.pi, 20001)[:-1]
    e2 = (eps0 * np.sin(t)) ** 2
    w = np.cos(t) ** 2
    return float(np.sum((1 + 2 * e2) / (1 - e2) ** 2 * w) / np.sum(w))


def _plan_60hz() -> ReportPlan:
    return ReportPlan(structure=(), dry_loads_n=(), lub_amplitudes_m=(13e-6, 38e-6),
                      lub_freqs_hz=(60.0,))


def test_60hz_amplitude_row_is_the_films_own_law_without_the_seal():
    # known answer: without the seal the 60 Hz row is eq. 16's energy-averaged eccentricity law
    # (13 against 38 um of the 127 um clearance: +0.082); with the law off the film is constant
    lo, hi = (_energy_averaged_eccentricity_factor(a / 127e-6) for a in (13e-6, 38e-6))
    expected = (hi - lo) / (0.5 * (hi + lo))
    assert 0.08 < expected < 0.085
    for law, want in ((True, expected), (False, 0.0)):
        p = rig_params_named_or_file("report")
        p.seal.enabled = False
        p.film.eccentricity_law = law
        with tempfile.TemporaryDirectory() as tmp:
            paths = run_report_plan(Path(tmp), p, _plan_60hz(), seed=3)
            with contextlib.redirect_stdout(io.StringIO()):
                rows = [r for r in compare(identify(paths))
                        if r.quantity == AMPLITUDE_INVARIANCE_60HZ]
        assert {r.axis for r in rows} == {"x", "y"}
        for r in rows:
            assert r.simulated == pytest.approx(want, abs=0.005), (law, r.axis, r.simulated)
            assert 0 < r.band < 0.2


def test_eccentricity_law_is_switched_off_by_the_60hz_invariance():
    # with the seal of the calibrated rig, the law makes the 60 Hz film damping rise with
    # amplitude (the report: invariant); the fit turns it off and names the rows that decided
    p = rig_params_named_or_file("report")
    p.film.eccentricity_law = True
    terms: list[FittedTerm] = []
    rejected: list[str] = []
    logged: list[str] = []
    keys = fit_eccentricity_law(simulator(3), _plan_60hz(), p, terms, rejected, logged.append)
    assert p.film.eccentricity_law is False
    assert [t.name for t in terms] == ["film.eccentricity_law"] and not rejected
    assert keys == {f"Film (section VI.3)|{AMPLITUDE_INVARIANCE_60HZ}|{a}" for a in "xy"}
    assert len(logged) == 2 and "on" in logged[0] and "off" in logged[1]
