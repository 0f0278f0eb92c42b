"""CSV (and .txt) files with a header row."""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from storage.errors import ImportDataError
from storage.importers.common import (
    MeasuredData,
    ReadColumns,
    _select,
    measured_from,
)


def _decimals_quantum(texts: list[str]) -> float:
    """Half a unit of the last printed digit of a column of numbers [same units]."""
    worst = 0.0
    for s in texts:
        s = s.strip().strip('"').lower()
        mant, _, exp = s.partition("e")
        digits = len(mant.partition(".")[2])
        try:
            q = 0.5 * 10.0 ** (int(exp or 0) - digits)
        except ValueError:
            continue
        worst = max(worst, q)
    return worst


def read_csv(path: str | Path, mapping: Mapping[str, str] | None = None,
             fs_hz: float | None = None, scale: Mapping[str, float] | None = None) -> MeasuredData:
    """Read a CSV file with a header row into canonical signals.

    Copes with a byte-order mark, quoted header names, a trailing delimiter on every line, blank
    trailing lines, and ``,`` / ``;`` / tab delimiters. Only the columns used are parsed.

    Parameters
    ----------
    path : str or Path
    mapping : dict, optional
        Canonical name -> column name.
    fs_hz : float, optional
        Sample rate [Hz]; required without a time_s column, checked against one.
    scale : dict, optional
        Canonical name -> factor applied to the column.

    Raises
    ------
    ImportDataError
        Naming the line and column of a non-numeric cell, a short row, a non-uniform time step.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise ImportDataError(f"{path}: cannot read: {err.strerror}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise ImportDataError(f"{path}, line {line}: not UTF-8 text ({err.reason})") from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    first = 0
    while first < len(lines) and not lines[first].strip():
        first += 1
    if first >= len(lines):
        raise ImportDataError(f"{path}: empty file (no header row)")
    header_line = lines[first]
    delim = ","
    if "," not in header_line:
        delim = ";" if ";" in header_line else ("\t" if "\t" in header_line else ",")
    header = [h.strip() for h in next(csv.reader([header_line], delimiter=delim))]
    while header and header[-1] == "":  # trailing delimiter
        header.pop()
    if not header:
        raise ImportDataError(f"{path}, line {first + 1}: empty header row")
    for j, h in enumerate(header):
        if h == "":
            raise ImportDataError(f"{path}, line {first + 1}: column {j + 1} has no name")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise ImportDataError(f"{path}, line {first + 1}: duplicate column names {dup}")
    if all(_is_number(h) for h in header):
        raise ImportDataError(f"{path}, line {first + 1}: no header row (the first line holds "
                              "numbers); add a header line naming the columns")
    chosen = _select(header, mapping or {}, str(path), "columns")
    for canon, col in chosen.items():
        if col not in header:
            raise ImportDataError(
                f"{path}: --map {canon}={col}: no column {col!r} (columns: {header})"
            )
    body = lines[first + 1:]
    line_no = np.arange(first + 2, first + 2 + len(body))
    if "" in body:  # empty lines inside the data: drop them, keep the numbering
        keep = [i for i, line in enumerate(body) if line]
        body = [body[i] for i in keep]
        line_no = line_no[keep]
    if not body:
        raise ImportDataError(f"{path}: header only, no data rows")
    idx = {canon: header.index(col) for canon, col in chosen.items()}
    cols = sorted(set(idx.values()))
    data = _parse_columns(path, body, line_no, header, delim, cols)
    columns = {canon: data[cols.index(j)] for canon, j in idx.items()}

    quantum = None
    if "time_s" in idx:  # the printed decimals: a time rounded to them is still uniform
        quantum = _decimals_quantum([_cell(s, delim, idx["time_s"])
                                     for s in body[:: max(1, len(body) // 1000)]])
    return measured_from(ReadColumns(
        columns, {c: f"column {col!r}" for c, col in chosen.items()}, "csv",
        line_of=lambda i: f"line {int(line_no[i])}", time_quantum_s=quantum), str(path), fs_hz,
        scale)


def _widths_ok(text: str, delim: str, n_cols: int) -> bool:
    """Every line has ``n_cols`` cells, or one more that is empty (a trailing delimiter).
    Vectorised: counting per line in Python costs seconds on million-line files."""
    buf = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    ends = np.append(np.flatnonzero(buf == ord("\n")), buf.size)
    delims = np.flatnonzero(buf == ord(delim))
    counts = np.diff(np.concatenate(([0], np.searchsorted(delims, ends))))
    trailing = buf[np.maximum(ends - 1, 0)] == ord(delim)
    return bool(np.all((counts == n_cols - 1) | ((counts == n_cols) & trailing)))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _cell(line: str, delim: str, j: int) -> str:
    cells = line.split(delim)
    return cells[j] if j < len(cells) else ""


def _parse_columns(path: Path, body: list[str], line_no: np.ndarray, header: list[str],
                   delim: str, cols: list[int]) -> list[np.ndarray]:
    """Parse columns ``cols`` of the data rows; fast path via numpy, exact errors otherwise."""
    n_cols = len(header)
    text = "\n".join(body)
    if '"' not in text and _widths_ok(text, delim, n_cols):  # quotes would fool the count
        try:
            arr = np.loadtxt(io.StringIO(text), delimiter=delim, usecols=cols, ndmin=2,
                             dtype=np.float64, comments=None)
        except ValueError:
            pass  # the slow path names the line and column
        else:
            if arr.shape == (len(body), len(cols)):
                return [np.ascontiguousarray(arr[:, k]) for k in range(len(cols))]
    # Slow path: locate the first fault exactly.
    out = np.empty((len(cols), len(body)))
    for i, row in enumerate(csv.reader(body, delimiter=delim)):
        where = f"{path}, line {int(line_no[i])}"
        extra = row[n_cols:]
        if len(row) < n_cols:
            raise ImportDataError(f"{where}: {len(row)} cell(s), the header has {n_cols} columns")
        if any(c.strip() for c in extra):
            raise ImportDataError(
                f"{where}: {len(row)} cells, the header has {n_cols} columns"
            )
        for k, j in enumerate(cols):
            cell = row[j].strip()
            try:
                out[k, i] = float(cell)
            except ValueError:
                what = "empty cell" if not cell else f"{cell!r} is not a number"
                raise ImportDataError(f"{where}, column {header[j]!r}: {what}") from None
    return list(out)


