"""The diagnosis as JSON, an extended rig TOML, and an HTML page with PNG figures (matplotlib Agg).
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from analysis.diagnose import residual_analysis as ra
from analysis.diagnose.baseline import baseline_modes
from analysis.diagnose.engine import Diagnosis
from analysis.diagnose.hysteresis import describing_function_text
from analysis.diagnose.model import Residuals
from analysis.diagnose.residual_structure import Z_STRUCTURE


def jsonable(v: Any) -> Any:
    """``v`` with numpy scalars as Python numbers and NaN/inf as None (JSON-safe)."""
    if isinstance(v, dict):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [jsonable(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def diagnosis_json(diag: Diagnosis, extended_model_path: str | None) -> dict[str, Any]:
    """The JSON document of ``sfdrig diagnose --json`` (NaN/inf written as null)."""
    return jsonable(diag.to_dict(extended_model_path))


def write_json(diag: Diagnosis, path: Path, extended_model_path: str | None) -> None:
    path.write_text(json.dumps(diagnosis_json(diag, extended_model_path), indent=2) + "\n")


def order_label(row: dict[str, Any]) -> str:
    """One row of the fitted baseline's order table in words: modes per axis (and the mode a
    row adds beyond the kernel's), and the axes uncoupled or coupled (with the fitted cross
    stiffness)."""
    n = row["modes_per_axis"]
    per_axis = row.get("modes")
    if per_axis and len(set(per_axis.values())) > 1:
        text = ", ".join(f"{ax} {k}" for ax, k in per_axis.items()) + " modes"
    else:
        text = f"{n} mode{'s' if n > 1 else ''} per axis"
    added = row.get("extra_mode")
    if added:
        text += f" (+ {added['axis']} {added['natural_frequency_hz']:.4g} Hz)"
    text += ", axes "
    if not row.get("coupled_axes"):
        return text + "uncoupled"
    k_xy = row.get("parameters", {}).get("stiffness_xy_N_per_m")
    return text + "coupled" + (f" (k_xy {k_xy:.4g} N/m)" if k_xy is not None else "")


def order_status(row: dict[str, Any]) -> str:
    """Whether the order of ``row`` was chosen, and if not, why (or why it was not tried)."""
    if row["chosen"]:
        return "chosen"
    if "not_tried" in row:
        return f"not tried: {row['not_tried']}"
    return str(row.get("not_chosen", "not chosen"))


def write_extended_model(diag: Diagnosis, path: Path) -> None:
    """The extended rig model as TOML (`rig_model.load_rig_params` loads it as it is)."""
    head = "# Extended rig model written by sfdrig diagnose"
    found = ", ".join(f.effect for f in diag.findings) or "no effect found"
    path.write_text(f"{head} ({diag.baseline_kind} baseline; {found})\n"
                    + diag.extended_rig.to_toml())


# --- figures -----------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _fig_time(diag: Diagnosis, path: Path) -> None:
    plt = _plt()
    seg = max(diag.test, key=lambda s: max(np.std(v) for v in diag.baseline_test.per_segment[s]
                                          .values()))
    rec = diag.records[seg.run]
    ch = next(iter(diag.baseline_test.per_segment[seg]))
    t = np.arange(seg.start, seg.stop) / rec.sample_rate_hz
    n = min(seg.n, int(rec.sample_rate_hz * (4 / seg.freq_hz if seg.freq_hz else 0.5)))
    meas = rec.responses[ch][seg.start:seg.stop]
    fig, axs = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    axs[0].plot(t[:n], meas[:n], "k", lw=1.2, label="measured")
    for res, lab in ((diag.baseline_test, "baseline"), (diag.final_test, "extended")):
        axs[0].plot(t[:n], (meas - res.per_segment[seg][ch])[:n], lw=1, label=lab)
        axs[1].plot(t[:n], res.per_segment[seg][ch][:n], lw=1, label=lab)
    axs[0].set_ylabel(f"{ch} [{diag.units}]")
    axs[1].set_ylabel("residual [m]")
    axs[1].set_xlabel("time [s]")
    axs[0].legend()
    axs[0].set_title(f"held-out segment {seg.label}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fig_dwell(rows_b: list[dict], rows_a: list[dict], path: Path) -> None:
    plt = _plt()
    fig, axs = plt.subplots(2, 3, figsize=(12, 6.5))
    for rows, mk, lab in ((rows_b, "o", "baseline"), (rows_a, "x", "extended")):
        for j, key in enumerate(("freq_hz", "amplitude_m", "time_s")):
            x = [r[key] for r in rows]
            axs[0, j].plot(x, [100 * r["amplitude_error"] for r in rows], mk, label=lab)
            axs[1, j].plot(x, [r["phase_error_deg"] for r in rows], mk, label=lab)
            axs[1, j].set_xlabel({"freq_hz": "frequency [Hz]", "amplitude_m": "amplitude [m]",
                                  "time_s": "time [s]"}[key])
    axs[0, 0].set_ylabel("1X amplitude error [%]")
    axs[1, 0].set_ylabel("1X phase error [deg]")
    axs[0, 0].legend()
    fig.suptitle("held-out dwells: fundamental error against frequency, amplitude and time")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fig_harmonics(rows_b: list[dict], rows_a: list[dict], path: Path) -> None:
    plt = _plt()
    sb, sa = ra.summary(rows_b), ra.summary(rows_a)
    k = np.arange(1, ra.N_HARMONICS + 1)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.bar(k - 0.2, sb["residual_harmonic_rms_m"], 0.4, label="baseline")
    ax.bar(k + 0.2, sa["residual_harmonic_rms_m"], 0.4, label="extended")
    ax.set_yscale("log")
    ax.set_xlabel("harmonic (kX)")
    ax.set_ylabel("residual amplitude, RMS over dwells [m]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fig_segments(diag: Diagnosis, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4))
    for res, mk, lab in ((diag.baseline_test, "o", "baseline"),
                         (diag.final_test, "x", "extended")):
        rows = ra.segment_table(diag.records, res, diag.test)
        ax.semilogy([r["time_s"] for r in rows], [r["residual_rms_m"] for r in rows], mk,
                    label=lab)
    if diag.noise_floor:
        ax.axhline(diag.noise_floor, color="gray", ls="--", label="noise floor")
    ax.set_xlabel("time [s] (segment centre)")
    ax.set_ylabel(f"held-out RMS residual [{diag.units}]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fig_spectrum(diag: Diagnosis, path: Path) -> None:
    plt = _plt()
    from scipy.signal import welch

    fig, ax = plt.subplots(figsize=(7, 4))
    for res, lab in ((diag.baseline_test, "baseline"), (diag.final_test, "extended")):
        seg = max(diag.test, key=lambda s: s.n)
        fs = diag.records[seg.run].sample_rate_hz
        sig = next(iter(res.per_segment[seg].values()))
        f, p = welch(sig, fs=fs, nperseg=min(sig.size, 4096))
        ax.semilogy(f, np.sqrt(p), label=lab)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"residual ASD [{diag.units}/sqrt(Hz)]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fig_gains(diag: Diagnosis, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    labels = ["baseline"] + [f.effect for f in diag.findings]
    # from the first finding's error before it: a second mode the fitted baseline's order
    # chose is reported against the one-mode baseline
    errs = ([diag.findings[0].error_before if diag.findings else diag.baseline_rms]
            + [f.error_after for f in diag.findings])
    ax.bar(range(len(errs)), errs)
    ax.set_xticks(range(len(errs)), labels, rotation=20)
    ax.set_yscale("log")
    ax.set_ylabel(f"held-out RMS error [{diag.units}]")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fig_amplitude(diag: Diagnosis, path: Path) -> None:
    """Natural frequency and damping ratio of the main mode against level (+/- 1 sd)."""
    plt = _plt()
    dep = diag.amplitude
    assert dep is not None
    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    for levels, style, lab in ((dep.levels, "o-", "measured"),
                               (dep.baseline_levels, "s--", "baseline model")):
        for ax in sorted({lv.axis for lv in levels}):
            lvs = sorted((lv for lv in levels if lv.axis == ax), key=lambda lv: lv.level)
            x = [lv.level * (1e6 if lv.level_by == "response" else 1.0) for lv in lvs]
            axs[0].errorbar(x, [lv.natural_hz for lv in lvs],
                            [lv.natural_hz_sd for lv in lvs], fmt=style, label=f"{lab} {ax}")
            axs[1].errorbar(x, [lv.damping_ratio for lv in lvs],
                            [lv.damping_ratio_sd for lv in lvs], fmt=style, label=f"{lab} {ax}")
    by = dep.levels[0].level_by
    for a, ylab in zip(axs, ("natural frequency [Hz]", "damping ratio [-]"), strict=True):
        a.set_xscale("log")
        a.set_xlabel("force amplitude [N]" if by == "force" else "response amplitude [um]")
        a.set_ylabel(ylab)
        a.legend(fontsize=8)
    axs[0].set_title(dep.text[:90], fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _amplitude_html(diag: Diagnosis) -> list[str]:
    dep = diag.amplitude
    if dep is None:
        return []
    out = ["<h2>Amplitude dependence (the linear model per level)</h2>",
           f"<p><b>{html.escape(dep.text)}</b></p>"]
    if not dep.levels:
        return out
    out.append(_table([lv.to_dict() for lv in dep.levels],
                      ["level", "axis", "force_amplitude_N", "response_amplitude_m", "segments",
                       "natural_frequency_hz", "natural_frequency_sd_hz",
                       "natural_frequency_determined", "damping_ratio", "damping_ratio_sd",
                       "damping_ratio_determined"]))
    if dep.baseline_levels:
        out.append("<p>The same levels fitted on the baseline model's prediction:</p>")
        out.append(_table([lv.to_dict() for lv in dep.baseline_levels],
                          ["level", "axis", "natural_frequency_hz", "damping_ratio"]))
    for ax, eff in dep.effects.items():
        out.append(f"<p>{ax}: effects of the library with this pattern: "
                   f"{html.escape(', '.join(eff) or 'none (linear over the levels)')}.</p>")
    for found, why in dep.contradicted.items():
        out.append(f"<p>Finding <b>{html.escape(found)}</b> contradicted by the levels: "
                   f"{html.escape(why)} (its confidence is low).</p>")
    out.append("<img src='amplitude.png' alt='natural frequency and damping against level'>")
    return out


def baseline_modes_text(rows: list[dict[str, Any]]) -> str:
    """The fitted baseline's modes per axis in words (``baseline.baseline_modes``' rows)."""
    parts = []
    for ax in dict.fromkeys(r["axis"] for r in rows):
        mine = sorted((r for r in rows if r["axis"] == ax),
                      key=lambda r: r["natural_frequency_hz"])
        parts.append(f"{ax}: " + ", ".join(f"{r['natural_frequency_hz']:.4g} Hz "
                                            f"({100 * r['damping_ratio']:.2g} %)" for r in mine))
    return "; ".join(parts)


def _modes_html(diag: Diagnosis) -> list[str]:
    modes = diag.modes
    if modes is None:
        return []
    base = baseline_modes(diag.baseline_model, diag.records)
    out = ["<h2>Modes of the baseline (one model for every level)</h2>",
           f"<p><b>{html.escape(baseline_modes_text(base))}</b></p>",
           _table(base, ["axis", "natural_frequency_hz", "damping_ratio", "modal_mass_kg",
                         "source"]),
           "<h2>Modes in the band (modal fit per level, order by the points' noise)</h2>",
           f"<p><b>{html.escape(modes.text)}</b></p>"]
    rows = [{"level": lv.label, "axis": lv.axis, "force_amplitude_N": lv.force_n,
             "points": lv.points, "mode": i + 1, **m.to_dict(), "shown": lv.shown(m),
             "why_not": "; ".join(lv.why_not(m)),
             "chi2_per_dof": lv.chi2_per_dof}
            for lv in modes.levels for i, m in enumerate(lv.modes)]
    if rows:
        out.append(_table(rows, ["level", "axis", "force_amplitude_N", "points", "mode",
                                 "natural_frequency_hz", "natural_frequency_sd_hz",
                                 "damping_ratio", "damping_ratio_sd", "shown", "why_not",
                                 "chi2_per_dof"]))
    trends = [{"axis": t.axis, "mode": t.index, "levels": len(t.levels),
               "frequency": t.frequency.verdict if t.frequency else "",
               "frequency_change": t.frequency.change if t.frequency else "",
               "damping": t.damping.verdict if t.damping else "",
               "damping_change": t.damping.change if t.damping else ""}
              for t in modes.tracks if t.shown]
    if trends:
        out.append("<p>Each mode against the level:</p>")
        out.append(_table(trends, ["axis", "mode", "levels", "frequency", "frequency_change",
                                   "damping", "damping_change"]))
    return out


def _table(rows: list[dict], keys: list[str]) -> str:
    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return html.escape(str(v))
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{fmt(r.get(k, ''))}</td>" for k in keys) + "</tr>"
                   for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _verdict_html(diag: Diagnosis) -> list[str]:
    """The verdict against the signal: explained fractions and what is missing."""
    v = diag.verdict
    if v is None:
        return []
    out = [f"<h2>Verdict: {html.escape(v.text)}</h2>",
           f"<p>Held-out fraction of the signal above the noise floor explained (threshold "
           f"{v.threshold:.0%} for an adequate model; more than "
           f"{1 - v.to_dict()['unexplained_share']:.0%} and a residual within "
           f"{v.to_dict()['noise_margin']:g}x the noise floor (RMS) for nothing "
           "unexplained):</p>"]
    rows = [{"model": "baseline", **v.baseline.to_dict()}, {"model": "final", **v.final.to_dict()}]
    for r in rows:
        r["per channel"] = ", ".join(f"{k}: {x:.3f}" for k, x in
                                     r.pop("explained_fraction_per_channel").items())
    out.append(_table(rows, ["model", "explained_fraction", "signal_rms", "residual_rms",
                             "noise_rms", "per channel"]))
    for model in ("baseline", "final"):
        peaks = v.missing.get(model, {}).get("residual_peaks", [])
        if peaks:
            out.append(f"<p>Peaks of the {model} model's residual spectrum (what it misses): "
                       + ", ".join(f"{p['freq_hz']:.4g} Hz ({p['share_of_residual_power']:.0%} "
                                   "of the residual power)" for p in peaks) + ".</p>")
    if "modes" in v.missing:
        out.append("<p>The baseline lacks a degree of freedom: a second mass-spring term "
                   "(frame tuned to " + ", ".join(f"{m['frequency_hz']:.4g} Hz"
                                                  for m in v.missing["modes"])
                   + ") explains part of what it misses.</p>")
        if "baseline_parameters_on_bound" in v.missing:
            out.append("<p>Baseline parameters on a bound of the fit: "
                       f"{html.escape(str(v.missing['baseline_parameters_on_bound']))}.</p>")
    out += _structure_html(v.structure_tests)
    out += _record_html(v.record_tests)
    if not v.adequate:
        out.append("<p><b>The baseline does not describe the data; no cause is named with "
                   "confidence on top of it.</b></p>")
    return out


def _structure_html(tests: list[dict[str, Any]]) -> list[str]:
    """The final residual's tests for structure above its own noise (``residual_structure``)."""
    if not tests:
        return []
    found = [t for t in tests if t["structure"]]
    if not found:
        top = tests[0]
        return [f"<p>No structure above the noise in the final model's residual (largest: "
                f"{html.escape(top['text'])}; structure from {Z_STRUCTURE:g} sd).</p>"]
    rows = [{"test": t["test"], "channel": t["channel"], "part": t["part"],
             "size": t["size"], "sd": t["z"], "what": t["text"]} for t in found]
    return [f"<p><b>Structure above the noise in the final model's residual</b> ({len(found)} "
            f"tests at {Z_STRUCTURE:g} sd or more: the verdict cannot be \"explained\"):</p>",
            _table(rows, ["test", "channel", "part", "size", "sd", "what"])]


def _record_html(tests: list[dict[str, Any]]) -> list[str]:
    """What the whole record holds that the model does not (``whole_record``): harmonics to
    10X, lines at other frequencies, the 1X against the noise and the replay's own error."""
    if not tests:
        return []
    found = [t for t in tests if t["structure"]]
    if not found:
        return [f"<p>The whole record accounted for: no harmonic to 10X, no line between the "
                f"harmonics and no 1X error above the noise (largest: "
                f"{html.escape(tests[0]['text'])}).</p>"]
    rows = [{"test": t["test"], "channel": t["channel"], "frequency Hz": t.get("freq_hz"),
             "size": t.get("amplitude", t["size"]), "unit": t.get("unit", ""), "sd": t["z"],
             "what": t["text"]} for t in found]
    return ["<p><b>In the record, not in the model</b> (the verdict cannot be "
            "\"explained\"):</p>",
            _table(rows, ["test", "channel", "frequency Hz", "size", "unit", "sd", "what"])]


def write_report(diag: Diagnosis, out_dir: Path, extended_model_path: str | None) -> Path:
    """Write ``index.html`` and its PNG figures into ``out_dir``; return the page's path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows_b = ra.dwell_table(diag.records, diag.baseline_test, diag.test)
    rows_a = ra.dwell_table(diag.records, diag.final_test, diag.test)
    figs = [("time.png", "Measured and predicted response, and the residual, in time",
             lambda p: _fig_time(diag, p)),
            ("segments.png", "Held-out residual per segment against time",
             lambda p: _fig_segments(diag, p)),
            ("spectrum.png", "Residual spectrum (longest held-out segment)",
             lambda p: _fig_spectrum(diag, p)),
            ("errors.png", "Held-out error after each finding", lambda p: _fig_gains(diag, p))]
    if rows_b:
        figs += [("dwells.png", "Per dwell: fundamental's amplitude and phase error",
                  lambda p: _fig_dwell(rows_b, rows_a, p)),
                 ("harmonics.png", "Residual per harmonic",
                  lambda p: _fig_harmonics(rows_b, rows_a, p))]
    for name, _, fn in figs:
        fn(out_dir / name)
    if diag.amplitude is not None and diag.amplitude.levels:
        _fig_amplitude(diag, out_dir / "amplitude.png")
    doc = diagnosis_json(diag, extended_model_path)
    u = diag.units
    noise = f"{diag.noise_floor:.3g} {u}" if diag.noise_floor else "n/a (no dwells)"
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>sfdrig diagnose</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
        "table{border-collapse:collapse;font-size:90%}td,th{border:1px solid #bbb;"
        "padding:2px 6px}</style></head><body>",
        "<h1>Model discrepancy</h1>",
        f"<p>Runs: {html.escape(', '.join(r.name for r in diag.records))} (trained on "
        f"{html.escape(', '.join(doc['train_runs']))}; judged on "
        f"{html.escape(', '.join(doc['test_runs']))}). "
        f"{len(diag.train)} training and {len(diag.test)} held-out segments.</p>",
        f"<h2>Baseline ({diag.baseline_kind})</h2><p>Held-out RMS error "
        f"<b>{diag.baseline_rms:.4g} {u}</b>; noise floor "
        f"{noise}.</p>",
    ]
    if diag.baseline_params:
        parts.append(_table([{"parameter": k, "value": v}
                             for k, v in diag.baseline_params.items()], ["parameter", "value"]))
    if diag.order:
        parts.append("<p>The fitted baseline's order, chosen on the held-out data:</p>")
        parts.append(_table([{
            "order": order_label(r), "held-out RMS error": r.get("held_out_error", ""),
            "criterion": r.get("criterion", ""), "parameters": r.get("n_params", ""),
            "chosen": "yes" if r["chosen"] else order_status(r)} for r in diag.order],
            ["order", "held-out RMS error", "criterion", "parameters", "chosen"]))
    parts.append("<h2>Findings</h2>")
    if diag.findings:
        parts.append(_table([{
            "effect": f.effect,
            "parameters (+- sd)": f.parameters_text(),
            "error before": f.error_before, "error after": f.error_after, "gain": f.gain,
            "gain 95% interval": f"{f.gain_interval[0]:.3g} .. {f.gain_interval[1]:.3g}",
            "confidence": f.evidence.get("confidence", ""),
        } for f in diag.findings], ["effect", "parameters (+- sd)", "error before", "error after",
                                    "gain", "gain 95% interval", "confidence"]))
        for f in diag.findings:
            if f.evidence.get("describing_function"):
                parts.append(f"<p>{html.escape(f.effect)}: describing function per amplitude "
                             "level</p><ul>" + "".join(
                                 f"<li>{html.escape(describing_function_text(r))}</li>"
                                 for r in f.evidence["describing_function"]) + "</ul>")
    else:
        parts.append("<p>No effect of the library improves the held-out error significantly."
                     "</p>")
    parts.extend(_verdict_html(diag))
    parts.extend(_amplitude_html(diag))
    parts.extend(_modes_html(diag))
    if extended_model_path:
        parts.append(f"<p>Extended model: <code>{html.escape(extended_model_path)}</code></p>")
    for i, rnd in enumerate(diag.rounds, 1):
        parts.append(f"<h3>Round {i}: candidates (best first)</h3>")
        parts.append(_table([{**c, "parameters": json.dumps(jsonable(c["parameters"]))}
                             for c in rnd], ["effect", "parameters", "held_out_error", "gain",
                                             "criterion", "train_error", "n_params",
                                             "not_a_finding"]))
    if diag.skipped:
        parts.append("<h3>Not applicable</h3>" + _table(
            [{"effect": k, "reason": v} for k, v in diag.skipped.items()], ["effect", "reason"]))
    for name, title, _ in figs:
        parts.append(f"<h2>{html.escape(title)}</h2><img src='{name}' alt='{html.escape(title)}'>")
    if rows_b:
        parts.append("<h2>Held-out dwells (baseline)</h2>")
        parts.append(_table(rows_b, ["segment", "channel", "freq_hz", "amplitude_m",
                                     "amplitude_error", "phase_error_deg", "residual_rms_m",
                                     "noise_rms_m"]))
    parts.append("<h2>JSON</h2><pre>" + html.escape(json.dumps(
        {k: doc[k] for k in ("verdict", "baseline", "findings", "unexplained",
                             "extended_model", "train_runs", "test_runs")},
        indent=1)) + "</pre>")
    if diag.notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>"
                                                    for n in diag.notes) + "</ul>")
    parts.append("</body></html>")
    page = out_dir / "index.html"
    page.write_text("\n".join(parts))
    return page


__all__ = ["Residuals", "diagnosis_json", "write_extended_model", "write_json", "write_report"]
