"""Model discrepancy: replay measured force through the rig model, find and fit what it misses.

Entry points: `load_run` (run file -> `RunRecord`), `diagnose` (-> `Diagnosis`),
`write_report` (HTML + PNG figures), `diagnosis_json`. The effect library is `LIBRARY`.
"""

from analysis.diagnose.data import DiagnoseError, RunRecord, Segment, load_run, parse_spans
from analysis.diagnose.effects import LIBRARY
from analysis.diagnose.engine import Diagnosis, Finding, diagnose

__all__ = [
    "LIBRARY", "DiagnoseError", "Diagnosis", "Finding", "RunRecord", "Segment", "diagnose",
    "load_run", "parse_spans",
]
