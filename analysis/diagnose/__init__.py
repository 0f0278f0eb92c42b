"""Model discrepancy: replay measured force through the rig model, find and fit what it misses.

Entry points: `load_run` (run file -> `RunRecord`), `diagnose` (-> `Diagnosis`); the report
module writes the JSON, the extended rig TOML and the HTML page. The effect library is
`LIBRARY` (ids, parameter names and the documented recovery tolerances).

Modules: ``data`` (runs, segments, train/held-out split), ``model`` (the replay through
`rig_model.simulate_response`), ``effects`` (the library), ``fitting`` (output-error
Levenberg-Marquardt), ``start`` (the fitted baseline's start from the data: dynamic stiffness
per dwell or H1 FRF), ``baseline`` (the fitted baseline and its order chosen on held-out
data), ``candidates`` (candidates and findings: criterion, bootstrap, what is not a finding),
``evidence`` (sensor pair, runner-up swap, corroboration), ``engine`` (the steps: baseline,
rounds, verdict, confidence), ``verdict`` (the
baseline and the final model against the held-out signal), ``residual_analysis`` (per dwell /
harmonic / segment numbers), ``report`` (JSON, TOML, HTML + PNG).

Limits, stated:
- ``sensor_gain`` and ``channel_delay`` need two sensors on the axis (two probes, or a probe and
  an accelerometer or velocity sensor: every response sensor is in the fitted objective, weighted
  by its noise), each responding (its 1X above its noise in some dwell). Which of the pair is
  wrong is told by refitting the effect on the other one; a
  gain error on a fitted baseline cannot be told from the partner's inverse gain error with the
  structure scaled, and the finding says so (``cannot_tell_from``).
- The fitted baseline fits one mass and one damping for both axes and a stiffness per axis
  (RigParams has one mass and one residual damping), and the rods' cross stiffness where its
  order takes it in (both axes' responses measured). With a configured baseline (a rig
  description) a cross stiffness the description lacks is no effect of the library.
- Imported runs without a rig description are replayed with the seal off, the film as the
  run file's lubricated flag says, linear (no eccentricity law: that is the library's
  ``amplitude_dependent_damping``), the oil at a constant temperature.
- Lubricated runs are replayed with the film full from sample 0 and the oil temperature of the
  configuration (initial temperature, configured warming): a drift shows as ``viscosity_drift``,
  corroborated by the recorded oil temperature when there is one.
"""

from analysis.diagnose.data import DiagnoseError, RunRecord, Segment, load_run, parse_spans
from analysis.diagnose.effects import LIBRARY
from analysis.diagnose.engine import Diagnosis, Finding, diagnose

__all__ = [
    "LIBRARY", "DiagnoseError", "Diagnosis", "Finding", "RunRecord", "Segment", "diagnose",
    "load_run", "parse_spans",
]
