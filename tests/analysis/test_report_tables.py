"""The report's tables as data: every file loads, and the printed numbers agree with each other
(unit conversions, f_n = sqrt(K/M)/2pi, zeta, D = M_t - M - M_f), which a transcription slip
breaks."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from analysis.errors import AnalysisError
from analysis.report_tables import COLUMNS, TABLES, find, load_csv, load_table

LBF_N = 4.4482216152605
IN_M = 0.0254
LB_KG = 0.45359237
LB_PER_IN = LBF_N / IN_M  # N/m per lb/in (and N.s/m per lb.s/in)


def test_every_table_loads_with_units_and_sources() -> None:
    for name in TABLES:
        rows = load_table(name)
        assert rows, name
        assert all(r.source and r.quantity for r in rows)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_table3_is_consistent_with_itself(axis: str) -> None:
    t3 = load_table("table3_impact")
    k = find(t3, "K_s", axis, "N/m")
    m = find(t3, "M", axis, "kg")
    c = find(t3, "C_s", axis, "N.s/m")
    f_n = find(t3, "f_n", axis)
    assert k.u_abs is not None and m.u_abs is not None and f_n.u_abs is not None
    # f_n from K and M, with their stated uncertainties propagated (eq. B.11 read backwards)
    f_calc = math.sqrt(k.value / m.value) / (2 * math.pi)
    u_f = 0.5 * f_calc * math.hypot(k.u_abs / k.value, m.u_abs / m.value)
    assert abs(f_calc - f_n.value) <= f_n.u_abs + u_f
    zeta = c.value / (2 * math.sqrt(k.value * m.value))
    assert zeta == pytest.approx(find(t3, "zeta", axis).value, abs=0.0015)
    assert k.value == pytest.approx(find(t3, "K_s", axis, "lb/in").value * LB_PER_IN, rel=0.01)
    assert m.value == pytest.approx(find(t3, "M", axis, "lb").value * LB_KG, rel=0.02)
    assert c.value == pytest.approx(find(t3, "C_s", axis, "lb.s/in").value * LB_PER_IN, rel=0.03)


def test_table2_si_and_us_agree_and_text_values_differ() -> None:
    t2 = load_table("table2_static_stiffness")
    for axis in ("x", "y"):
        us = find(t2, "K_s", axis, "lb/in")
        si = find(t2, "K_s", axis, "N/m")
        assert si.value == pytest.approx(us.value * LB_PER_IN, rel=0.002)
        assert si.u_abs == pytest.approx(us.u_abs * LB_PER_IN, rel=0.002)
        used = find(t2, "K_s_used", axis)
        # the text's values lie 3-5 % above Table 2's: kept both, flagged in the note
        assert 0.025 < used.value / si.value - 1 < 0.05
        assert "contradicts" in used.note


def test_table6_added_mass_is_total_minus_housing_and_fluid() -> None:
    t6 = load_table("table6_inertia")
    m = find(t6, "M").value
    m_f = find(t6, "M_f").value
    for axis in ("x", "y"):
        assert find(t6, "D", axis).value == pytest.approx(
            find(t6, "M_t", axis).value - m - m_f, abs=0.05)
    f1 = load_table("tableF1_added_mass")
    at38 = [r for r in f1 if r.condition == "amplitude 38 um"]
    assert {r.axis: r.value for r in at38} == {
        "x": find(t6, "D", "x").value, "y": find(t6, "D", "y").value}


def test_table1_total_mass_in_both_units() -> None:
    t1 = load_table("table1_mass")
    lb = find(t1, "effective_mass_total", unit="lb")
    kg = find(t1, "effective_mass_total", unit="kg")
    assert kg.value == pytest.approx(lb.value * LB_KG, rel=0.01)
    assert kg.u_abs == pytest.approx(0.097)


def _write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "bad.csv"
    path.write_text(",".join(COLUMNS) + "\n" + body, encoding="utf-8")
    return path


@pytest.mark.parametrize(("body", "says"), [
    ("Table 9,K,x,,abc,N/m,,,\n", "bad.csv:2: column 'value': 'abc' is not a number"),
    ("Table 9,K,x,,1,furlong,,,\n", "bad.csv:2: column 'unit': 'furlong'"),
    ("Table 9,K,x,,1,N/m,5,,\n", "bad.csv:2: an uncertainty needs its basis"),
    ("Table 9,K,x,,1,N/m,-5,stated,\n", "bad.csv:2: column 'uncertainty' is negative"),
    ("Table 9,K,x,,nan,N/m,,,\n", "bad.csv:2: column 'value': 'nan' is not finite"),
    ("Table 9,K,x\n", "bad.csv:2: expected 9 columns"),
    ("", "bad.csv: no rows"),
])
def test_a_broken_table_names_file_line_and_column(tmp_path: Path, body: str, says: str) -> None:
    with pytest.raises(AnalysisError) as err:
        load_csv(_write(tmp_path, body))
    assert says in str(err.value)


def test_unknown_table_and_ambiguous_lookup_are_errors() -> None:
    with pytest.raises(AnalysisError, match="unknown report table 'table7'"):
        load_table("table7")
    with pytest.raises(AnalysisError, match="2 rows match quantity='K_s' axis='x'"):
        find(load_table("table3_impact"), "K_s", "x")
