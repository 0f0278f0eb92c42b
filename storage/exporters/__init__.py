"""Export run files to the formats a lab already uses: MATLAB .mat, CSV, NI TDMS.

Each export holds the signals in engineering units with their units and sensors, the drives,
the step table, the per-step harmonics and the run's conditions, with the same names and
conventions in every format (`storage.exporters.common`), and the metadata that lets
`sfdrig import` restore the run (`storage.importers.restore`). Files appear whole or not at all.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from storage.errors import ExportError
from storage.exporters.common import (
    EXPORT_FORMAT,
    EXPORT_VERSION,
    ExportSet,
    Progress,
    check_out_dir,
    column_name,
    select,
)
from storage.exporters.csv_format import write_csv
from storage.exporters.mat_format import write_mat
from storage.exporters.tdms_format import write_tdms
from storage.reader import open_run

WRITERS = {"mat": write_mat, "csv": write_csv, "tdms": write_tdms}


def export_run(path: str | Path, to: str, out_dir: str | Path, *, steps: str | None = None,
               channels: Sequence[str] | None = None, progress: Progress | None = None,
               overwrite: bool = False) -> list[Path]:
    """Export run file ``path`` as ``to`` ("mat", "csv" or "tdms") into folder ``out_dir``.

    Parameters
    ----------
    steps : str, optional
        ``N`` or ``N-M``: only those steps (inclusive) and the samples of their records.
    channels : list of str, optional
        Input channels to export (names or comma-separated lists); the drives always are.
    progress : callable, optional
        Called with (samples written, samples in the export) after every block.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    ExportError, RunFileError
        One line naming the run and the step range, channel or folder at fault.
    """
    if to not in WRITERS:
        raise ExportError(f"--to {to!r}: one of {', '.join(WRITERS)}")
    out = Path(out_dir)
    with open_run(path) as run:
        exp = select(run, steps, channels)  # a refused selection creates no folder
        made = _missing_folders(out)
        try:
            check_out_dir(out)
            return WRITERS[to](exp, out, progress=progress, overwrite=overwrite)
        except BaseException:
            for folder in made:  # nothing written: leave no empty folder behind
                try:
                    folder.rmdir()
                except OSError:
                    break
            raise


def _missing_folders(out: Path) -> list[Path]:
    """The folders ``out`` would create, deepest first."""
    missing = []
    for folder in (out, *out.parents):
        if folder.exists():
            break
        missing.append(folder)
    return missing


__all__ = ["EXPORT_FORMAT", "EXPORT_VERSION", "WRITERS", "ExportError", "ExportSet",
           "column_name", "export_run", "select"]
