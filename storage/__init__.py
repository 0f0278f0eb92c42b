"""HDF5 run files (SWMR writer, reader), the run catalog, importers of measured data and
exporters of runs (MAT, CSV, TDMS).

Imports no sibling package: channel metadata arrives as plain dicts / JSON.
"""

from storage.errors import ImportDataError, MissingSignalError, RunFileError
from storage.layout import EVENT_KINDS, FORMAT, FORMAT_VERSION, KINDS, STATUSES
from storage.reader import CANONICAL_SIGNALS, RunData, open_run
from storage.runfile import RunWriter

__all__ = [
    "CANONICAL_SIGNALS",
    "EVENT_KINDS",
    "FORMAT",
    "FORMAT_VERSION",
    "KINDS",
    "STATUSES",
    "ImportDataError",
    "MissingSignalError",
    "RunData",
    "RunFileError",
    "RunWriter",
    "open_run",
]
