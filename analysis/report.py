"""The identification report: a JSON document of every table, a folder of PNG figures and one
self-contained HTML page showing both (figures as relative <img>).

`write_report(run_paths, out_dir)` is what ``sfdrig identify --report`` and ``sfdrig demo`` call.
"""

from __future__ import annotations

import html
import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from analysis.figures import all_figures
from analysis.identify import Identification, identify, write_results

UM = 1e6


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return html.escape(str(v))


def _table(title: str, header: Sequence[str], rows: Iterable[Sequence[Any]],
           note: str = "") -> str:
    body = "".join("<tr>" + "".join(f"<td>{_fmt(c)}</td>" for c in r) + "</tr>" for r in rows)
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    n = f"<p class='note'>{html.escape(note)}</p>" if note else ""
    return f"<h3>{html.escape(title)}</h3><table><tr>{head}</tr>{body}</table>{n}"


def _pm(v: float | None, u: float | None, scale: float = 1.0, digits: int = 4) -> str:
    if v is None:
        return "–"
    if u is None:
        return f"{v * scale:.{digits}g}"
    return f"{v * scale:.{digits}g} ± {u * scale:.2g}"


def tables_html(doc: dict[str, Any]) -> str:
    """Every table of the JSON document as HTML."""
    parts = _structure_tables(doc)
    dry = doc.get("dry")
    if dry:
        t4 = dry["table4"]
        ide = t4["identified"]
        parts.append(_table(
            "Table 4 – dry friction force and residual damping (energy balance, eq. 2-4)",
            ["test, load", "F_µ [N]", "C_rv [N.s/m]", "r²", "dwells"],
            [[r["label"], _pm(r["F_mu_N"], r["U_F_mu_N"]),
              _pm(r["C_rv_Ns_per_m"], r["U_C_rv_Ns_per_m"]), r["r2"], r["n_points"]]
             for r in t4["rows"]] + [["all (identified)", _pm(ide["F_mu_N"], ide["U_F_mu_N"]),
                                      _pm(ide["C_rv_Ns_per_m"], ide["U_C_rv_Ns_per_m"]),
                                      ide["r2"], ""]],
            "Uncertainty: regression (95 %), instruments (App. B) and scatter across tests."))
    lub = doc.get("lubricated")
    if lub:
        parts += _lubricated_tables(lub)
    ref = doc.get("simulated_reference")
    if ref:
        parts.append(_table("Simulated rig (true values)", ["quantity", "value"],
                            [[k, v] for k, v in ref.items() if not isinstance(v, list)]))
    return "\n".join(parts)


def _structure_tables(doc: dict[str, Any]) -> list[str]:
    """The structure's and the instruments' tables: Table 2 (static), Table 3 (impact),
    Table A1 (probe gains) and the flow against pressure."""
    parts = []
    if doc["static_table2"]:
        parts.append(_table(
            "Table 2 – structural stiffness from static load tests",
            ["axis", "K [kN/m]", "R²", "SEE [µm]", "levels", "steps", "f_n* [Hz]"],
            [[s["axis"], _pm(s["k_n_per_m"], s["u_k_n_per_m"], 1e-3), s["r2"],
              s["see_m"] * UM, s["n_levels"], s["n_steps"],
              _pm(s["natural_freq_hz"], s["u_natural_freq_hz"])] for s in doc["static_table2"]],
            "Uncertainty: eq. B.6-B.7 (95 %). f_n* from K and the housing mass."))
    if doc["impact_table3"]:
        parts.append(_table(
            "Table 3 – parameters from impact tests",
            ["axis", "K [kN/m]", "M [kg]", "C [N.s/m]", "ζ", "f_n [Hz]", "R²", "impacts"],
            [[i["axis"], _pm(i["k_n_per_m"], i["u_k_n_per_m"], 1e-3), _pm(i["m_kg"], i["u_m_kg"]),
              i["c_ns_per_m"], i["damping_ratio"],
              _pm(i["natural_freq_hz"], i["u_natural_freq_hz"]), i["r2"], i["n_impacts"]]
             for i in doc["impact_table3"]], "Uncertainty: eq. B.10-B.11."))
    if doc["probe_calibration_tableA1"]:
        parts.append(_table(
            "Table A1 – eddy-current probe gains",
            ["probe", "gain [mV/mil]", "gain [V/mm]", "U_G/G", "R²", "points",
             "gain in use [V/mm]"],
            [[c["channel"], c["gain_mv_per_mil"], c["gain_v_per_m"] / 1e3, c["u_gain_rel"],
              c["r2"], c["n_points"], c["gain_in_use_v_per_m"] / 1e3]
             for c in doc["probe_calibration_tableA1"]], "Uncertainty: eq. B.1, B.4-B.5."))
    for fr in doc["flow"]:
        parts.append(_table(
            "Flow against pressure difference (eq. 1, eq. 5)",
            ["P_s [kPa]", "ΔP [kPa]", "Q [L/min]", "U_Q [L/min]", "T [°C]", "µ eq. 1 [cP]",
             "Q/Q_eq5 (eq. 1)", "Q/Q_eq5 (config µ)"],
            [[p["supply_pressure_pa"] / 1e3, p["dp_pa"] / 1e3, p["q_l_per_min"],
              p["U_q_m3_per_s"] * 60_000, p["t_oil_c"], p["mu_eq1_pa_s"] * 1e3,
              p["flow_ratio_eq1"], p["flow_ratio_config"]] for p in fr["points"]],
            f"Slope fit R² = {fr['r2']:.4f}; viscosity implied by eq. 5 = "
            f"{fr['viscosity_fit_pa_s'] * 1e3:.3f} cP; eq. 1 at {fr['mean_temperature_c']:.1f} "
            f"°C = {fr['viscosity_eq1_pa_s'] * 1e3:.3f} cP; rig configuration = "
            f"{fr['viscosity_config_pa_s'] * 1e3:.3f} cP."))
    return parts


def _lubricated_tables(lub: dict[str, Any]) -> list[str]:
    """The lubricated analysis's tables: Table 6 / F1 (total and added mass), the film's
    damping by amplitude (Appendix F) and the coefficients per dwell."""
    parts = [_table(
        "Table 6 / Table F1 – total and added mass (dynamic stiffness against w²)",
        ["axis", "amplitude [µm]", "seal removed by", "K fit [kN/m]", "M_T [kg]", "R²",
         "D [kg]", "M_T, K static [kg]", "R² (K static)", "D (K static) [kg]"],
        [[f["axis"], f["amplitude_m"] * UM, f["method"],
          _pm(f["k_n_per_m"], f["u_k_n_per_m"], 1e-3), _pm(f["m_t_kg"], f["u_m_t_kg"]),
          f["r2"], _pm(f["added_mass_kg"], f["u_added_mass_kg"]), f["m_t_fixed_k_kg"],
          f["r2_fixed_k"], f["added_mass_fixed_k_kg"]]
         for f in lub["table6_and_appendix_E"]],
        f"Predicted added mass (eq. 15): {lub['predictions']['eq15_added_mass_kg']:.2f} kg."
        " D = M_T - M - M_f. 'eq9': the report's procedure (the seal's in-phase force stays "
        "in K - w²M_T); 'stick_slip': the seal force rebuilt from the measured cycle, with "
        "sticking, removed first. K static: "
        + ", ".join(f"{k} {v / 1e3:.0f} kN/m" for k, v in lub["k_static_N_per_m"].items())
        + ".")]
    preds = {(r["axis"], round(r["amplitude_m"], 8)): r
             for r in lub["predictions"]["by_amplitude"]}
    rows = []
    for g in lub["sfd_damping_by_amplitude"]:
        pr = preds.get((g["axis"], round(g["amplitude_m"], 8)), {})
        e9, ss = g["eq9"], g["stick_slip"]
        rows.append([g["axis"], g["amplitude_m"] * UM, g["C_t_mean_Ns_per_m"],
                     g["dC_t_df_Ns_per_m_per_Hz"],
                     _pm(e9["C_sfd_mean_Ns_per_m"], e9["U_C_sfd_Ns_per_m"]),
                     e9["C_sfd_rel_spread"],
                     _pm(ss["C_sfd_mean_Ns_per_m"], ss["U_C_sfd_Ns_per_m"]),
                     ss["C_sfd_rel_spread"], pr.get("eq16_at_eps_Ns_per_m"),
                     pr.get("simulated_energy_equivalent_Ns_per_m")])
    parts.append(_table(
        "Squeeze-film damping by amplitude (Appendix F), mean over frequency",
        ["axis", "amplitude [µm]", "C_t mean", "dC_t/df [N.s/m/Hz]", "C_sfd (eq. 9)",
         "spread/mean", "C_sfd (stick-slip)", "spread/mean", "eq. 16 at ε=A/c",
         "simulator (energy equiv.)"], rows,
        f"C_sfd = C_t - C_seal - C_rv with F_µ = {lub['seal_friction_N']:.2f} N "
        f"({lub['seal_friction_source']}), C_rv = {lub['C_rv_Ns_per_m']:.0f} N.s/m. Eq. 16 "
        f"centred: {lub['predictions']['eq16_centred_Ns_per_m']:.0f} N.s/m. Damping in "
        "N.s/m."))
    parts.append(_table(
        "Identified coefficients per dwell (eq. 14, eq. 9)",
        ["run", "step", "axis", "f [Hz]", "|Z| [µm]", "C_t [N.s/m]", "K-w²M_T [kN/m]",
         "C_seal eq. 9", "C_sfd eq. 9", "C_seal stick-slip", "C_sfd stick-slip",
         "sticking"],
        [[p["run"].split(" (")[0], p["step"], p["axis"], p["freq_hz"],
          p["amplitude_m"] * UM, _pm(p["C_t_Ns_per_m"], p["U_C_t_Ns_per_m"]),
          _pm(p["K_dyn_N_per_m"], p["U_K_dyn_N_per_m"], 1e-3), p["C_seal_Ns_per_m"],
          _pm(p["C_sfd_Ns_per_m"], p["U_C_sfd_Ns_per_m"]), p["C_seal_stick_slip_Ns_per_m"],
          _pm(p["C_sfd_stick_slip_Ns_per_m"], p["U_C_sfd_stick_slip_Ns_per_m"]),
          p["stick_fraction"]] for p in lub["points"]]))
    return parts


_CSS = """body{font-family:sans-serif;max-width:1150px;margin:auto;padding:1em}
table{border-collapse:collapse;margin:.5em 0;font-size:90%}td,th{border:1px solid #bbb;
padding:2px 6px;text-align:right}th{background:#eee}.note{font-size:85%;color:#444}
figure{display:inline-block;margin:.5em;max-width:100%}img{max-width:100%}
.skip{color:#a30}"""


def render_html(doc: dict[str, Any], figures: list[tuple[str, str]], fig_dir: str) -> str:
    runs = "".join(
        f"<tr><td>{_fmt(r['run_id'])}</td><td>{_fmt(r['kind'])}</td><td>{_fmt(r['lubricated'])}"
        f"</td><td>{_fmt(r['status'])}</td><td>{r['n_steps']}</td><td>{_fmt(r['analysis'])}</td>"
        f"<td>{_fmt(Path(r['path']).name)}</td></tr>" for r in doc["runs"])
    skipped = "".join(f"<li>{html.escape(s['message'])}</li>" for s in doc["skipped"])
    figs = "".join(
        f"<figure><img src='{fig_dir}/{html.escape(f)}' alt='{html.escape(c)}'>"
        f"<figcaption>{html.escape(c)}</figcaption></figure>" for f, c in figures)
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>sfdrig identification</title>
<style>{_CSS}</style></head><body>
<h1>Force-coefficient identification</h1>
<p>Generated {html.escape(doc['generated'])}. Rig parameters: {
html.escape(doc['rig_parameters_source'])}. Equation and table numbers refer to the sealed-end SFD
report. Uncertainties are 95 % intervals (Appendix B propagation and scatter across repeats).</p>
<h2>Runs</h2><table><tr><th>run</th><th>kind</th><th>lubricated</th><th>status</th><th>steps</th>
<th>analysis</th><th>file</th></tr>{runs}</table>
<h2>Skipped, and why</h2>{f'<ul class="skip">{skipped}</ul>' if skipped else '<p>Nothing.</p>'}
<h2>Tables</h2>{tables_html(doc)}
<h2>Figures</h2>{figs}
<p class="note">Every table is also in report.json.</p>
</body></html>
"""


def build_report(ident: Identification, out_dir: str | Path) -> Path:
    """Write report.json, figures/*.png and index.html for ``ident``; returns index.html."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = ident.to_json()
    figures = all_figures(ident, out / "figures")
    doc["figures"] = [{"file": f"figures/{f}", "caption": c} for f, c in figures]
    (out / "report.json").write_text(json.dumps(doc, indent=1, allow_nan=False))
    page = out / "index.html"
    page.write_text(render_html(doc, figures, "figures"))
    return page


def write_report(run_paths: Sequence[str | Path], out_dir: str | Path,
                 store_results: bool = True) -> Path:
    """Identify ``run_paths``, store results in each run file, write the report; -> index.html.

    Parameters
    ----------
    run_paths : sequence of path
        Run files (any kinds; each gets the analysis its kind calls for).
    out_dir : path
        Folder for report.json, figures/ and index.html (created).
    store_results : bool
        Also write each run's results under its ``/results/identify`` group.
    """
    ident = identify(run_paths)
    if store_results:
        ident.skipped.extend(write_results(ident))
    return build_report(ident, out_dir)


def summary_lines(ident: Identification) -> list[str]:
    """A short text summary of what was identified (for the command line)."""
    out = []
    for s in ident.static:
        out.append(f"static {s.axis}: K = {s.k_n_per_m / 1e3:.1f} +/- {s.u_k_n_per_m / 1e3:.1f} "
                   f"kN/m (R2 {s.r2:.4f}), f_n* = {s.natural_freq_hz:.1f} Hz")
    for i in ident.impact:
        out.append(f"impact {i.axis}: K = {i.k_n_per_m / 1e3:.0f} kN/m, M = {i.m_kg:.2f} kg, "
                   f"C = {i.c_ns_per_m:.0f} N.s/m, zeta = {i.damping_ratio:.3f}, f_n = "
                   f"{i.natural_freq_hz:.1f} Hz (R2 {i.r2:.3f})")
    for c in ident.probe:
        out.append(f"probe {c.channel}: {c.gain_mv_per_mil:.1f} mV/mil (R2 {c.r2:.4f}; in use "
                   f"{c.gain_in_use_v_per_m * 25.4e-3:.1f})")
    for f in ident.flow:
        out.append(f"flow: viscosity from eq. 5 fit {f.viscosity_fit_pa_s * 1e3:.2f} cP; eq. 1 "
                   f"{f.viscosity_eq1_pa_s * 1e3:.2f} cP at {f.mean_temperature_c:.1f} degC; "
                   f"flow ratio (eq. 1) {f.mean_flow_ratio_eq1:.3f}")
    if ident.dry is not None:
        d = ident.dry
        out.append(f"dry: F_mu = {d.f_mu_n:.2f} +/- {d.u_f_mu_n:.2f} N, C_rv = "
                   f"{d.c_rv_ns_per_m:.0f} +/- {d.u_c_rv_ns_per_m:.0f} N.s/m (r2 "
                   f"{d.overall.r2 if d.overall else float('nan'):.4f}, {len(d.points)} dwells)")
    if ident.lubricated is not None:
        for m in ident.lubricated.mass_fits:
            out.append(f"lubricated {m.axis} {m.amplitude_m * UM:.1f} um [{m.method}]: K = "
                       f"{m.k_n_per_m / 1e3:.0f} kN/m, M_T = {m.m_t_kg:.2f} kg, D = "
                       f"{m.added_mass_kg:.2f} +/- {m.u_added_mass_kg:.2f} kg (R2 {m.r2:.3f})")
        for g in ident.lubricated.sfd_by_amplitude:
            out.append(f"SFD damping {g['axis']} {g['amplitude_m'] * UM:.1f} um: "
                       f"{g['eq9']['C_sfd_mean_Ns_per_m']:.0f} (eq. 9), "
                       f"{g['stick_slip']['C_sfd_mean_Ns_per_m']:.0f} (stick-slip) N.s/m")
    return out
