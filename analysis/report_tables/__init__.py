"""The reference report's measured results as data.

One CSV per table (and one for the numbers given only in the text and figures). Every row is one
value with its unit and the report's stated uncertainty, so that a simulated or identified result
can be compared with what the rig really did. Values are transcribed as printed; where the report
contradicts itself (Table 2 against the text, Table 5 against eq. 1) both values are kept and the
row's note says so.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from analysis.errors import AnalysisError

TABLES = (
    "table1_mass",
    "table2_static_stiffness",
    "table3_impact",
    "table4_dry_friction",
    "table5_lubricated_conditions",
    "table6_inertia",
    "tableA1_probe_gain",
    "tableF1_added_mass",
    "text_and_figures",
)
COLUMNS = ("source", "quantity", "axis", "condition", "value", "unit", "uncertainty",
           "uncertainty_basis", "note")
UNITS = frozenset({"kg", "lb", "N", "N/m", "lb/in", "N.s/m", "lb.s/in", "Hz", "1", "Pa", "Pa.s",
                   "m", "degC", "1/degC", "mV/mil"})
UNCERTAINTY_BASES = frozenset({"", "stated", "percent", "scale"})


@dataclass(frozen=True)
class ReportValue:
    source: str
    quantity: str
    axis: str
    condition: str
    value: float
    unit: str
    uncertainty: float | None
    uncertainty_basis: str
    note: str

    @property
    def u_abs(self) -> float | None:
        """The stated uncertainty in the value's unit (None where the report states none)."""
        if self.uncertainty is None:
            return None
        if self.uncertainty_basis == "percent":
            return abs(self.value) * self.uncertainty / 100.0
        return self.uncertainty


def load_csv(path: Path) -> list[ReportValue]:
    """Read one table file; every problem names the file, the line and the column."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise AnalysisError(f"{path}: cannot read ({exc.strerror})") from None
    reader = csv.DictReader(text.splitlines())
    if tuple(reader.fieldnames or ()) != COLUMNS:
        raise AnalysisError(f"{path}:1: header is {reader.fieldnames}, expected {list(COLUMNS)}")
    rows = []
    for row in reader:
        where = f"{path}:{reader.line_num}"
        if None in row or any(v is None for v in row.values()):
            raise AnalysisError(f"{where}: expected {len(COLUMNS)} columns")
        rows.append(_parse_row(row, where))
    if not rows:
        raise AnalysisError(f"{path}: no rows")
    return rows


def load_table(name: str) -> list[ReportValue]:
    """One of TABLES, from the installed package."""
    if name not in TABLES:
        raise AnalysisError(f"unknown report table {name!r}; known: {', '.join(TABLES)}")
    with resources.as_file(resources.files(__package__) / f"{name}.csv") as path:
        return load_csv(path)


def find(rows: list[ReportValue], quantity: str, axis: str | None = None,
         unit: str | None = None) -> ReportValue:
    """The one row of this quantity (and axis, unit); anything else is an error."""
    hits = [r for r in rows if r.quantity == quantity and (axis is None or r.axis == axis)
            and (unit is None or r.unit == unit)]
    if len(hits) != 1:
        raise AnalysisError(f"report table: {len(hits)} rows match quantity={quantity!r} "
                            f"axis={axis!r} unit={unit!r}, expected one")
    return hits[0]


def _parse_row(row: dict[str, str], where: str) -> ReportValue:
    value = _number(row["value"], where, "value")
    if value is None:
        raise AnalysisError(f"{where}: column 'value' is empty")
    unit = row["unit"].strip()
    if unit not in UNITS:
        raise AnalysisError(f"{where}: column 'unit': {unit!r} is not one of {sorted(UNITS)}")
    basis = row["uncertainty_basis"].strip()
    if basis not in UNCERTAINTY_BASES:
        raise AnalysisError(f"{where}: column 'uncertainty_basis': {basis!r} is not one of "
                            f"{sorted(UNCERTAINTY_BASES)}")
    uncertainty = _number(row["uncertainty"], where, "uncertainty")
    if uncertainty is not None and uncertainty < 0:
        raise AnalysisError(f"{where}: column 'uncertainty' is negative ({uncertainty})")
    if (uncertainty is None) != (basis == ""):
        raise AnalysisError(f"{where}: an uncertainty needs its basis and a basis its uncertainty")
    for key in ("source", "quantity"):
        if not row[key].strip():
            raise AnalysisError(f"{where}: column {key!r} is empty")
    return ReportValue(row["source"].strip(), row["quantity"].strip(), row["axis"].strip(),
                       row["condition"].strip(), value, unit, uncertainty, basis,
                       row["note"].strip())


def _number(text: str, where: str, column: str) -> float | None:
    if not text.strip():
        return None
    try:
        value = float(text)
    except ValueError:
        raise AnalysisError(f"{where}: column {column!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise AnalysisError(f"{where}: column {column!r}: {text!r} is not finite")
    return value
