"""HDF5 run files (SWMR writer, reader), the run catalog, importers of measured data and
exporters of runs (MAT, CSV, TDMS), and the run's records (`storage.records`).

Imports no sibling package: channel metadata arrives as plain dicts / JSON. The records and the
errors load without h5py (a client of the daemon, the page, reads records off the wire); the
writer, the reader and the layout load on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from storage.errors import ImportDataError, MissingSignalError, RunFileError
from storage.records import EVENT_KINDS, STATUSES

if TYPE_CHECKING:
    from storage.layout import FORMAT, FORMAT_VERSION, KINDS
    from storage.reader import CANONICAL_SIGNALS, RunData, open_run
    from storage.runfile import RunWriter

_ON_FIRST_USE = {"FORMAT": "storage.layout", "FORMAT_VERSION": "storage.layout",
                 "KINDS": "storage.layout", "CANONICAL_SIGNALS": "storage.reader",
                 "RunData": "storage.reader", "open_run": "storage.reader",
                 "RunWriter": "storage.runfile"}


def __getattr__(name: str) -> object:
    module = _ON_FIRST_USE.get(name)
    if module is None:
        raise AttributeError(f"module 'storage' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


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
