"""Identification over a set of run files: picks the analysis each run calls for, runs them in
the order the report does (structure, dry, lubricated), and keeps what was skipped and why.

`identify(paths)` returns an `Identification`; `Identification.to_json()` is every table; and
`write_results` stores each run's share under its ``/results/identify`` group (contract B).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple

import h5py
import numpy as np

from analysis.dry import DryResult, identify_dry
from analysis.dwells import (
    DYNAMIC_SIGNALS,
    Dwell,
    load_dwells,
    read_channel,
    run_label,
    signal_channels,
)
from analysis.errors import Skipped
from analysis.lubricated import SEAL_HARMONICS, LubResult, identify_lubricated
from analysis.seal_setting import SealSetting, declared_seal, fit_seal_friction
from analysis.structure import (
    FlowResult,
    ImpactFit,
    ProbeCal,
    StaticFit,
    identify_flow,
    identify_impact,
    identify_probe_calibration,
    identify_static,
)
from analysis.sync import amplitude_spectrum
from analysis.uncertainty import U_DISPLACEMENT_REL
from rig_model.film import energy_equivalent_damping, eq16_damping
from rig_model.params import RigParams
from storage import RunData, RunFileError, open_run

ANALYSES = ("sync", "dry", "lubricated", "static", "impact", "probe_calibration", "flow")
#: Report defaults used when no run identifies them (Table 4, Table 1, section VI.2).
REPORT_F_MU_N = 26.0
REPORT_C_RV_NS_PER_M = 370.0
U_MASS_REL = 0.01  # Table 1: +/- 1 %
U_FLUID_MASS_KG = 0.01  # section VI.2: 0.62 +/- 0.01 kg
WATERFALL_HARMONICS = 5.5  # spectra shown up to this multiple of the highest dwell frequency



# Per-dwell tables stored as plain arrays in /results (columns named in an attribute).
_RESULT_TABLES: dict[str, tuple[str, ...]] = {
    "lubricated": ("freq_hz", "amplitude_m", "C_t_Ns_per_m", "K_dyn_N_per_m",
                   "C_seal_Ns_per_m", "C_sfd_Ns_per_m", "U_C_sfd_Ns_per_m"),
    "dry": ("freq_hz", "work_J", "dissipated_J", "C_eq_x_Ns_per_m", "C_eq_y_Ns_per_m",
            "Im_Fx_over_X_N_per_m", "Im_Fy_over_Y_N_per_m"),
}

def wanted_analysis(run: RunData) -> str:
    """The analysis a run calls for, from its kind and whether it ran with oil."""
    kind = run.kind
    if kind in ("static", "impact", "probe_calibration", "flow"):
        return kind
    if kind in ("sweep", "imported"):
        return "lubricated" if bool(run.attrs.get("lubricated", False)) else "dry"
    return "unknown"


@dataclass
class RunSummary:
    path: str
    label: str
    run_id: str
    kind: str
    lubricated: bool
    status: str
    n_steps: int
    analysis: str

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class Identification:
    """Everything identified from a set of runs (the report's tables and figure data)."""

    runs: list[RunSummary] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)
    #: what the reader should know that is not a skip (a run aborted: its steps are used)
    notes: list[str] = field(default_factory=list)
    dwells: dict[str, list[Dwell]] = field(default_factory=dict)
    waterfalls: dict[str, dict[str, Any]] = field(default_factory=dict)
    dry: DryResult | None = None
    lubricated: LubResult | None = None
    static: list[StaticFit] = field(default_factory=list)
    impact: list[ImpactFit] = field(default_factory=list)
    probe: list[ProbeCal] = field(default_factory=list)
    flow: list[FlowResult] = field(default_factory=list)
    params: RigParams = field(default_factory=RigParams)
    params_source: str = "report defaults"
    simulated: bool = False
    rig_described: bool = False  # imported runs carrying a rig description
    references: dict[str, Any] = field(default_factory=dict)

    # --- tables ---------------------------------------------------------------------------
    def synchronous_table(self) -> list[dict[str, Any]]:
        rows = []
        for label, dws in self.dwells.items():
            for d in dws:
                row: dict[str, Any] = {"run": label, "step": d.step, "freq_hz": d.freq_hz,
                                       "motion": d.motion, "cycles": d.cycles,
                                       "converged": d.converged}
                for name, h in d.harmonics.items():
                    row[name] = [[float(z.real), float(z.imag)] for z in h[:5]]
                    row[name + "_1x_abs"] = float(abs(h[0]))
                rows.append(row)
        return rows

    def dry_table(self) -> dict[str, Any] | None:
        if self.dry is None:
            return None
        pts = []
        for p in self.dry.points:
            ex, ey = p.equivalent_damping()
            ix, iy = p.im_f_over_x()
            pts.append({"run": p.run, "step": p.step, "freq_hz": p.freq_hz, "load_n": p.load_n,
                        "work_J": p.work_j,
                        "dissipated_J": p.dissipated_j(self.dry.f_mu_n, self.dry.c_rv_ns_per_m),
                        "Im_Fx_over_X_N_per_m": ix, "Im_Fy_over_Y_N_per_m": iy,
                        "C_eq_x_Ns_per_m": ex, "C_eq_y_Ns_per_m": ey})
        return {"table4": self.dry.table4(), "points": pts}

    def lubricated_tables(self) -> dict[str, Any] | None:
        lub = self.lubricated
        if lub is None:
            return None
        table6 = [f.to_dict() for f in lub.mass_fits]
        preds = self.predictions()
        return {
            "seal_friction_N": lub.f_mu_n, "seal_friction_source": lub.f_mu_source,
            "C_rv_Ns_per_m": lub.c_rv_ns_per_m,
            "points": [p.to_dict() for p in lub.points],
            "k_static_N_per_m": lub.k_static,
            "table6_and_appendix_E": table6,
            "sfd_damping_by_amplitude": lub.sfd_by_amplitude,
            "predictions": preds,
        }

    def predictions(self) -> dict[str, Any]:
        """Eq. 15 and eq. 16 beside the identified values (and the simulator's own values)."""
        film = self.params.film
        mu_cfg = film.reference_viscosity()[0]
        out: dict[str, Any] = {
            "eq15_added_mass_kg": film.eq15_added_mass_kg(),
            "eq16_centred_Ns_per_m": film.eq16_damping_centred(mu_cfg),
            "viscosity_Pa_s": mu_cfg, "viscosity_source": film.viscosity_source,
            "by_amplitude": [],
        }
        if self.lubricated is not None:
            for g in self.lubricated.sfd_by_amplitude:
                amp = g["amplitude_m"]
                row = {"axis": g["axis"], "amplitude_m": amp,
                       "eq16_at_eps_Ns_per_m": eq16_damping(self.params, amp / film.clearance_m),
                       "identified_eq9_Ns_per_m": g["eq9"]["C_sfd_mean_Ns_per_m"],
                       "identified_stick_slip_Ns_per_m": g["stick_slip"]["C_sfd_mean_Ns_per_m"]}
                if self.simulated:
                    row["simulated_energy_equivalent_Ns_per_m"] = energy_equivalent_damping(
                        self.params, amp, g["axis"], g.get("t_oil_c"))
                out["by_amplitude"].append(row)
        return out

    def to_json(self) -> dict[str, Any]:
        """Every table, JSON-safe (NaN as null)."""
        doc = {
            "generated": datetime.now(UTC).isoformat(timespec="seconds"),
            "rig_parameters_source": self.params_source,
            "simulated": self.simulated,
            "runs": [r.to_dict() for r in self.runs],
            "skipped": [s.to_dict() for s in self.skipped],
            "notes": list(self.notes),
            "synchronous_components": self.synchronous_table(),
            "dry": self.dry_table(),
            "lubricated": self.lubricated_tables(),
            "static_table2": [f.to_dict() for f in self.static],
            "impact_table3": [
                {k: v for k, v in f.to_dict().items() if k not in ("freq_hz", "frf_m_per_n")}
                for f in self.impact],
            "probe_calibration_tableA1": [c.to_dict() for c in self.probe],
            "flow": [f.to_dict() for f in self.flow],
            "simulated_reference": self.references,
        }
        return _json_safe(doc)


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, complex | np.complexfloating):
        return [_json_safe(float(obj.real)), _json_safe(float(obj.imag))]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _params_of(runs: list[RunData], ident: Identification) -> None:
    # The sweeps' configuration is the reference of the dynamic coefficients; the structure
    # runs (static, impact) are made with the seal off and must not stand in for it.
    sweeps = [r for r in runs if r.rig_config and r.kind in ("sweep", "imported")]
    configs = {json.dumps(r.rig_config, sort_keys=True) for r in (sweeps or runs)
               if r.rig_config}
    if not configs:
        ident.params, ident.params_source, ident.simulated = RigParams(), (
            "report defaults (no run carries a rig configuration)"), False
        return
    try:
        ident.params = RigParams.model_validate(json.loads(sorted(configs)[0]))
    except ValueError as err:
        ident.skipped.append(Skipped("-", "setup", f"rig_config unreadable ({err}); report "
                                     "defaults used"))
        return
    if all(r.kind == "imported" for r in (sweeps or runs) if r.rig_config):
        ident.rig_described = True
        ident.params_source = "rig_config of the imported runs (their rig description)"
        return
    ident.simulated = True
    ident.params_source = "rig_config of the runs (simulated rig)"
    if len(configs) > 1:
        ident.params_source += f"; {len(configs)} different configurations, the first used"


def _waterfall(run: RunData, dwells: list[Dwell]) -> dict[str, Any]:
    """Amplitude spectra of load, displacement and acceleration per dwell (Figures 10-12, 26-27)."""
    if not dwells:
        return {}
    fmax = WATERFALL_HARMONICS * max(d.freq_hz for d in dwells)
    out: dict[str, Any] = {"freq_hz": [], "spectra": {}}
    for name in ("fx", "fy", "x", "y", "ax", "ay"):
        if not signal_channels(run, name):
            continue
        rows: list[tuple[np.ndarray, np.ndarray] | None] = []
        for d in dwells:
            if name not in d.harmonics:
                rows.append(None)
                continue
            chans = signal_channels(run, name)
            sig = np.mean([read_channel(run, c, d.first_sample, d.last_sample) for c in chans],
                          axis=0)
            f, a = amplitude_spectrum(sig, run.sample_rate_hz, fmax)
            rows.append((f, a))
        out["spectra"][name] = rows
    out["freq_hz"] = [d.freq_hz for d in dwells]
    return out


def identify(paths: Sequence[str | Path], analyses: Iterable[str] | None = None,
             velocity_harmonics: int = 1) -> Identification:
    """Identify everything the runs allow.

    Parameters
    ----------
    paths : sequence of path
        Run files (contract B).
    analyses : iterable of str, optional
        Restrict to these analyses (from `ANALYSES`). A run that does not fit any asked analysis
        is skipped with a message naming it and its kind.
    velocity_harmonics : int
        Harmonics of the displacement used to rebuild the velocity in eq. 3-4 (the report: 1).
    """
    asked = set(analyses) if analyses is not None else set(ANALYSES)
    unknown = asked - set(ANALYSES)
    if unknown:
        raise ValueError(f"unknown analyses {sorted(unknown)}; choose from {ANALYSES}")
    ident = Identification()
    runs: list[RunData] = []
    for p in paths:
        try:
            runs.append(open_run(p))
        except (RunFileError, OSError) as err:
            ident.skipped.append(Skipped(str(p), "open", str(err)))
    try:
        _params_of(runs, ident)
        _identify_runs(runs, ident, asked, velocity_harmonics)
    finally:
        for r in runs:
            r.close()
    return ident


def _by_analysis(runs: list[RunData], ident: Identification,
                 asked: set[str]) -> dict[str, list[RunData]]:
    """The runs by the analysis each calls for, each listed in ``ident.runs``; a run whose
    analysis was not asked for is skipped with why, an aborted or failed one noted."""
    by_analysis: dict[str, list[RunData]] = {a: [] for a in ANALYSES}
    for r in runs:
        want = wanted_analysis(r)
        label = run_label(r)
        ident.runs.append(RunSummary(str(r.path), label, r.run_id, r.kind,
                                     bool(r.attrs.get("lubricated", False)), r.status,
                                     len(r.steps), want))
        if r.status in ("aborted", "failed") and want in asked:
            # nothing is left out: the steps it recorded are analysed, so a note, not a skip
            why = r.attrs.get("status_reason", "") or "no reason recorded"
            ident.notes.append(f"run {label}: {r.status} ({why}); the {len(r.steps)} step(s) "
                               "it recorded are analysed")
        if want not in asked:
            ident.skipped.append(Skipped(label, want, f"run of kind {r.kind!r} "
                                         f"(lubricated={r.attrs.get('lubricated')}) calls for "
                                         f"the {want!r} analysis, which was not asked for "
                                         f"(asked: {sorted(asked)})"))
            continue
        by_analysis[want].append(r)
    return by_analysis


class _SealAndDamping(NamedTuple):
    """The seal's friction [N] and the residual damping [N.s/m] a lubricated analysis removes,
    with their uncertainties and where the friction comes from (NaN: not known, to be fitted
    to the lubricated dwells)."""

    f_mu: float
    u_f_mu: float
    c_rv: float
    u_c_rv: float
    source: str


def _seal_and_damping(ident: Identification, declared: SealSetting) -> _SealAndDamping:
    """From the runs' stated seal, the dry runs, the rig configuration or the report's Table 4,
    in that order (`analysis.seal_setting`)."""
    params = ident.params
    c_rv = params.structure.residual_damping_ns_per_m if ident.rig_described \
        else REPORT_C_RV_NS_PER_M
    u_c_rv = 0.1 * c_rv
    if ident.dry is not None:
        c_rv, u_c_rv = ident.dry.c_rv_ns_per_m, ident.dry.u_c_rv_ns_per_m
    if declared.state in ("none", "given"):
        f_mu = declared.f_mu_n or 0.0
        u_f_mu = 0.1 * f_mu
        source = declared.source
    elif ident.dry is not None:
        f_mu, u_f_mu = ident.dry.f_mu_n, ident.dry.u_f_mu_n
        source = "identified from the dry runs (energy balance, eq. 2-4)"
    elif declared.state == "unknown":
        f_mu, u_f_mu, source = math.nan, 0.0, declared.source  # fitted once dwells load
    elif ident.simulated or ident.rig_described:
        f_mu = params.seal.friction_force_n if params.seal.enabled else 0.0
        c_rv = params.structure.residual_damping_ns_per_m
        u_f_mu, u_c_rv = 0.1 * f_mu, 0.1 * c_rv
        source = "rig configuration (no dry run given)"
    else:
        f_mu, c_rv = REPORT_F_MU_N, REPORT_C_RV_NS_PER_M
        u_f_mu, u_c_rv = 0.1 * f_mu, 0.1 * c_rv
        source = "report's Table 4 (no dry run given)"
    return _SealAndDamping(f_mu, u_f_mu, c_rv, u_c_rv, source)


def _identify_runs(runs: list[RunData], ident: Identification, asked: set[str],
                   velocity_harmonics: int) -> None:
    params = ident.params
    by_analysis = _by_analysis(runs, ident, asked)
    # structure and instruments first: their results feed the dynamic analyses
    for r in by_analysis["probe_calibration"]:
        ident.probe.extend(identify_probe_calibration(r, ident.skipped))
    u_gain = (max(c.u_gain_rel for c in ident.probe) if ident.probe else U_DISPLACEMENT_REL)
    for r in by_analysis["static"]:
        ident.static.extend(identify_static(r, ident.skipped, params.structure.mass_kg,
                                            U_MASS_REL, u_gain))
    for r in by_analysis["impact"]:
        ident.impact.extend(identify_impact(r, ident.skipped))
    for r in by_analysis["flow"]:
        fr = identify_flow(r, ident.skipped, params)
        if fr is not None:
            ident.flow.append(fr)
    # dry sweeps: seal friction and residual damping
    dry_dwells: list[Dwell] = []
    for r in by_analysis["dry"]:
        dws = load_dwells(r, "dry", DYNAMIC_SIGNALS, ident.skipped, require=("x", "y"))
        ident.dwells[run_label(r)] = dws
        ident.waterfalls[run_label(r)] = _waterfall(r, dws) if "sync" in asked else {}
        dry_dwells.extend(dws)
    if dry_dwells:
        ident.dry = identify_dry(dry_dwells, ident.skipped, velocity_harmonics)
    lub_runs = by_analysis["lubricated"]
    try:
        declared = declared_seal([r.test_spec for r in lub_runs], [run_label(r) for r in lub_runs])
    except ValueError as err:
        ident.skipped.append(Skipped("-", "lubricated", str(err)))
        by_analysis["lubricated"] = []
        declared = SealSetting("", None, "")
    f_mu, u_f_mu, c_rv, u_c_rv, source = _seal_and_damping(ident, declared)
    # lubricated sweeps
    lub_dwells: list[Dwell] = []
    for r in by_analysis["lubricated"]:
        dws = load_dwells(r, "lubricated", (*DYNAMIC_SIGNALS, "t_oil"), ident.skipped,
                          n_harmonics=SEAL_HARMONICS)
        ident.dwells[run_label(r)] = dws
        ident.waterfalls[run_label(r)] = _waterfall(r, dws) if "sync" in asked else {}
        lub_dwells.extend(dws)
    if lub_dwells and math.isnan(f_mu):
        try:
            f_mu, u_f_mu, _, n_pts = fit_seal_friction(lub_dwells)
            source += (f"; F_mu = {f_mu:.1f} +/- {u_f_mu:.1f} N fitted to {n_pts} lubricated "
                       "dwells (C_t linear in 1/(w|Z|), eq. 9; the uncertainty is the "
                       "regression's only: eq. 9 assumes the seal never sticks)")
        except ValueError as err:
            ident.skipped.append(Skipped("-", "lubricated", f"seal friction unknown and not "
                                         f"fitted ({err}); give a dry run"))
            lub_dwells = []
    if lub_dwells:
        k_static = {"x": params.structure.stiffness_x_n_per_m,
                    "y": params.structure.stiffness_y_n_per_m}
        for s in ident.static:
            k_static[s.axis] = s.k_n_per_m
        ident.lubricated = identify_lubricated(
            lub_dwells, ident.skipped, f_mu_n=f_mu, u_f_mu_n=u_f_mu, c_rv=c_rv, u_c_rv=u_c_rv,
            f_mu_source=source, k_static=k_static, m_housing_kg=params.structure.mass_kg,
            m_fluid_kg=params.film.fluid_mass_kg,
            u_m_housing_kg=U_MASS_REL * params.structure.mass_kg,
            u_m_fluid_kg=U_FLUID_MASS_KG)
    if ident.simulated:
        ident.references = simulated_reference(params, ident)


def simulated_reference(params: RigParams, ident: Identification) -> dict[str, Any]:
    """The simulated rig's true values, beside which the identified ones are judged."""
    st, film = params.structure, params.film
    ref: dict[str, Any] = {
        "F_mu_N": params.seal.friction_force_n if params.seal.enabled else 0.0,
        "C_rv_Ns_per_m": st.residual_damping_ns_per_m,
        "K_x_N_per_m": st.stiffness_x_n_per_m, "K_y_N_per_m": st.stiffness_y_n_per_m,
        "M_kg": st.mass_kg, "M_f_kg": film.fluid_mass_kg, "D_kg": film.added_mass(),
        "M_T_kg": st.mass_kg + film.fluid_mass_kg + film.added_mass(),
        "sfd_damping_note": ("energy-equivalent of eq. 16 with the instantaneous eccentricity "
                             "over a cycle of the identified amplitude (rig_model.film)"),
        "sfd_damping_by_amplitude": [],
    }
    if ident.lubricated is not None:
        for g in ident.lubricated.sfd_by_amplitude:
            ref["sfd_damping_by_amplitude"].append({
                "axis": g["axis"], "amplitude_m": g["amplitude_m"],
                "C_sfd_Ns_per_m": energy_equivalent_damping(params, g["amplitude_m"], g["axis"],
                                                             g.get("t_oil_c"))})
    return ref


def run_share(ident: Identification, label: str) -> dict[str, Any]:
    """The part of the results that concerns one run (for its /results group)."""
    doc = ident.to_json()
    share: dict[str, Any] = {"run": label, "generated": doc["generated"],
                             "rig_parameters_source": doc["rig_parameters_source"],
                             "skipped": [s for s in doc["skipped"] if s["run"] == label],
                             "synchronous_components": [r for r in doc["synchronous_components"]
                                                        if r["run"] == label]}
    if doc["dry"] and any(p["run"] == label for p in doc["dry"]["points"]):
        share["dry"] = {"table4": doc["dry"]["table4"],
                        "points": [p for p in doc["dry"]["points"] if p["run"] == label]}
    if doc["lubricated"] and any(p["run"] == label for p in doc["lubricated"]["points"]):
        lub = dict(doc["lubricated"])
        lub["points"] = [p for p in lub["points"] if p["run"] == label]
        share["lubricated"] = lub
    for key in ("static_table2", "impact_table3", "probe_calibration_tableA1", "flow"):
        if doc[key]:
            share[key] = doc[key]
    return share


def write_results(ident: Identification) -> list[Skipped]:
    """Store each run's share under ``/results/identify`` (file reopened r+ after the run closed).

    Returns the runs whose file could not be written (still being written, read-only...).
    """
    problems: list[Skipped] = []
    for run in ident.runs:
        if run.status == "running":
            problems.append(Skipped(run.label, "results", "run is still being written; results "
                                    "not stored in the file"))
            continue
        share = run_share(ident, run.label)
        try:
            with h5py.File(run.path, "r+") as f:
                grp = f.require_group("results")
                if "identify" in grp:
                    del grp["identify"]
                g = grp.create_group("identify")
                g.attrs["generated"] = share["generated"]
                g.attrs["software"] = "sfdrig analysis.identify"
                g.create_dataset("json", data=json.dumps(share))
                for key, cols in _RESULT_TABLES.items():
                    section = share.get(key)
                    if section and section["points"]:
                        arr = np.array([[p[c] if p[c] is not None else np.nan for c in cols]
                                        for p in section["points"]])
                        ds = g.create_dataset(f"{key}_points", data=arr)
                        ds.attrs["columns"] = json.dumps(cols)
        except OSError as err:
            problems.append(Skipped(run.label, "results", f"cannot write /results: {err}"))
    return problems
