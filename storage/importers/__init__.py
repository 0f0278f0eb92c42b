"""Import measured data from elsewhere (CSV, MATLAB .mat, NI TDMS) into a run file.

Canonical signals (all optional except at least one force and one displacement)::

    time_s      sample times [s] (uniformly sampled), or give fs_hz
    freq_hz     excitation frequency of the dwell each sample belongs to [Hz]
    fx_N fy_N   forces [N]              -> channels fx, fy
    x_m y_m     displacements [m]       -> channels x, y
    ax_mps2 ay_mps2 accelerations [m/s^2] -> channels ax, ay
    oil_temp_C  oil temperature [degC]  -> channel t_oil

Columns (variables, TDMS channels) named like a canonical signal are used as they are; others are
mapped with ``mapping={"fx_N": "V1"}`` (CLI ``--map fx_N=V1``) and scaled with
``scale={"x_m": 1e-3}`` (``--scale x_m=1e-3``). The import is all-or-nothing: everything is read and
checked in memory, written to a temporary file beside the target and renamed into place only when
complete. Every error names the file and the line, column or variable at fault.
"""

from storage.importers.common import (
    CANONICAL,
    DISPLACEMENTS,
    FORCES,
    MeasuredData,
    parse_assignments,
    parse_scale,
)
from storage.importers.csv_format import read_csv
from storage.importers.mat_format import read_mat
from storage.importers.tdms_format import read_tdms
from storage.importers.to_run import (
    READERS,
    dwell_steps,
    import_file,
    read_measured,
    write_imported_run,
)

__all__ = [
    "CANONICAL", "DISPLACEMENTS", "FORCES", "READERS", "MeasuredData", "dwell_steps",
    "import_file", "parse_assignments", "parse_scale", "read_csv", "read_mat", "read_measured",
    "read_tdms", "write_imported_run",
]
