"""PNG figures mirroring the report's (matplotlib, Agg backend): waterfalls, synchronous responses,
work against dissipated energy, Im(F/X), equivalent damping, dynamic stiffness with its fit, damping
against frequency and amplitude, orbits, static, impact, calibration and flow plots.

Each function draws one figure into ``out_dir`` and returns ``(file name, caption)``; none raises on
missing data (the caller only asks for figures whose data exist).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from analysis.identify import Identification  # noqa: E402
from analysis.lubricated import LubPoint, LubResult  # noqa: E402
from analysis.sync import synthesize  # noqa: E402

UM = 1e6
Figure = tuple[str, str]
_NAMES = {"fx": "load X [N]", "fy": "load Y [N]", "x": "displacement X [um]",
          "y": "displacement Y [um]", "ax": "acceleration X [m/s^2]",
          "ay": "acceleration Y [m/s^2]"}
_SCALE = {"x": UM, "y": UM}


def _save(fig: plt.Figure, out_dir: Path, name: str, tight: bool = True) -> str:
    if tight:  # tight_layout is the slow part of many-panel figures: those space themselves
        fig.tight_layout()
    fig.savefig(out_dir / name, dpi=90)
    plt.close(fig)
    return name


def _legend(ax: plt.Axes, fontsize: int) -> None:
    """A legend only where something is labelled (matplotlib warns otherwise)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=fontsize)


def _one_axes_figure(fig: plt.Figure, ax: plt.Axes, xlabel: str, ylabel: str, fontsize: int,
                     out_dir: Path, name: str, caption: str) -> Figure:
    """A figure of one axes labelled, its legend and grid drawn, saved as ``name``."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    _legend(ax, fontsize)
    ax.grid(alpha=0.3)
    return _save(fig, out_dir, name), caption


def _safe(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label.split(" (")[0])[:40]


def waterfalls(ident: Identification, out_dir: Path) -> list[Figure]:
    """Figures 10-12, 26-27: spectra of each dwell stacked along the excitation frequency, one
    figure per run and target (load or amplitude); the driven axis only for x/y motions."""
    figs = []
    for label, wf in ident.waterfalls.items():
        if not wf or not wf.get("spectra"):
            continue
        dws = ident.dwells.get(label, [])
        groups: dict[tuple[str, float], list[int]] = defaultdict(list)
        for i, d in enumerate(dws):
            groups[(d.motion, round(d.target_value, 9))].append(i)
        for (motion, target), idx in sorted(groups.items()):
            axes_ = (motion,) if motion in ("x", "y") else ("x", "y")
            names = [n for a in axes_ for n in (f"f{a}", a, f"a{a}") if n in wf["spectra"]]
            if not names:
                continue
            ncol = 3
            nrow = (len(names) + ncol - 1) // ncol
            fig = plt.figure(figsize=(4.2 * ncol, 3.4 * nrow))
            for k, name in enumerate(names):
                ax = fig.add_subplot(nrow, ncol, k + 1, projection="3d")
                for i in idx:
                    row = wf["spectra"][name][i]
                    if row is None:
                        continue
                    f, amp = row
                    ax.plot(f, np.full_like(f, dws[i].freq_hz), amp * _SCALE.get(name, 1.0),
                            lw=0.7)
                ax.set_xlabel("frequency [Hz]", fontsize=7)
                ax.set_ylabel("excitation [Hz]", fontsize=7)
                ax.set_title(_NAMES[name], fontsize=8)
                ax.tick_params(labelsize=6)
            tag = (f"{target * UM:g} um" if dws[idx[0]].target_kind == "displacement"
                   else f"{target:g} N")
            fig.suptitle(f"{label}: {motion}, {tag}", fontsize=9)
            fig.subplots_adjust(left=0.02, right=0.97, bottom=0.05, top=0.85, wspace=0.15,
                                hspace=0.25)
            fname = _save(fig, out_dir, f"waterfall_{_safe(label)}_{motion}_{_safe(tag)}.png",
                          tight=False)
            figs.append((fname, f"Waterfalls of load, displacement and acceleration, {label}, "
                                f"{motion} {tag} (cf. Figures 10-12, 26-27)."))
    return figs


def synchronous(ident: Identification, out_dir: Path) -> list[Figure]:
    """Figures 13-15, 28-29: 1X amplitude of load and displacement against frequency."""
    if not ident.dwells:
        return []
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for label, dws in ident.dwells.items():
        groups: dict[tuple[str, float], list] = defaultdict(list)
        for d in dws:
            groups[(d.motion, round(d.target_value, 7))].append(d)
        for (motion, target), ds in sorted(groups.items()):
            ds = sorted(ds, key=lambda d: d.freq_hz)
            tag = f"{label.split(' (')[0]} {motion} {target * (UM if target < 1e-3 else 1):g}"
            for ax, sig, scale in ((axes[0], "f", 1.0), (axes[1], "", UM)):
                for axis in ("x", "y"):
                    name = f"{sig}{axis}"
                    if motion in ("x", "y") and axis != motion:
                        continue
                    pts = [(d.freq_hz, abs(d.harmonics[name][0]) * scale) for d in ds
                           if name in d.harmonics]
                    if pts:
                        f, a = zip(*pts, strict=True)
                        ax.plot(f, a, "o-", ms=3, label=f"{tag} ({axis.upper()})")
    axes[0].set_ylabel("1X load amplitude [N]")
    axes[1].set_ylabel("1X displacement amplitude [um]")
    for ax in axes:
        ax.set_xlabel("excitation frequency [Hz]")
        ax.grid(alpha=0.3)
        _legend(ax, 6)
    return [(_save(fig, out_dir, "synchronous.png"),
             "Synchronous (1X) load and displacement against frequency (cf. Figures 13-15, "
             "28-29).")]


def dry_figures(ident: Identification, out_dir: Path) -> list[Figure]:
    """Figures 16-19: work against dissipated energy, Im(F/X), equivalent damping."""
    dry = ident.dry
    if dry is None:
        return []
    pts = sorted(dry.points, key=lambda p: (p.run, p.load_n, p.freq_hz))
    figs = []
    fig, ax = plt.subplots(figsize=(6, 4))
    groups: dict[tuple[str, float], list] = defaultdict(list)
    for p in pts:
        groups[(p.run, p.load_n)].append(p)
    for (run, load), ps in groups.items():
        f = [p.freq_hz for p in ps]
        ax.plot(f, [p.work_j * 1e3 for p in ps], "o", ms=4,
                label=f"work, {run.split(' (')[0]} {load:g} N")
        ax.plot(f, [p.dissipated_j(dry.f_mu_n, dry.c_rv_ns_per_m) * 1e3 for p in ps], "-",
                label="E_dry + E_rv (fit)")
    ax.set_xlabel("excitation frequency [Hz]")
    ax.set_ylabel("energy per cycle [mJ]")
    ax.set_title(f"F_mu = {dry.f_mu_n:.1f} +/- {dry.u_f_mu_n:.1f} N, C_rv = "
                 f"{dry.c_rv_ns_per_m:.0f} +/- {dry.u_c_rv_ns_per_m:.0f} N.s/m", fontsize=9)
    _legend(ax, 6)
    ax.grid(alpha=0.3)
    figs.append((_save(fig, out_dir, "dry_work_energy.png"),
                 "Work of the input force and energy dissipated by the combined model "
                 "(cf. Figures 16-17)."))
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    fq = np.array([p.freq_hz for p in pts])
    w = 2 * np.pi * fq
    imx = np.array([p.im_f_over_x()[0] for p in pts])
    imy = np.array([p.im_f_over_x()[1] for p in pts])
    axes[0].plot(fq, imx / 1e3, "o", ms=3, label="Im(Fx/X)")
    axes[0].plot(fq, imy / 1e3, "s", ms=3, label="Im(Fy/Y)")
    order = np.argsort(fq)
    axes[0].plot(fq[order], dry.c_rv_ns_per_m * w[order] / 1e3, "k-", label="C_rv w")
    axes[0].set_ylabel("Im(F/X) [kN/m]")
    axes[1].plot(fq, imx / w, "o", ms=3, label="X")
    axes[1].plot(fq, imy / w, "s", ms=3, label="Y")
    axes[1].axhline(dry.c_rv_ns_per_m, color="k", label="C_rv")
    axes[1].set_ylabel("equivalent damping Im(F/X)/w [N.s/m]")
    for ax in axes:
        ax.set_xlabel("excitation frequency [Hz]")
        _legend(ax, 7)
        ax.grid(alpha=0.3)
    figs.append((_save(fig, out_dir, "dry_im_f_over_x.png"),
                 "Imaginary part of F/X and equivalent viscous damping of the dry system "
                 "(cf. Figures 18-19)."))
    return figs


def lubricated_figures(ident: Identification, out_dir: Path) -> list[Figure]:
    """Figures 30-37, E1-E2, F1: dynamic stiffness, C_t and C_sfd against frequency, amplitude."""
    lub = ident.lubricated
    if lub is None:
        return []
    groups: dict[tuple[str, float], list[LubPoint]] = defaultdict(list)
    for p in lub.points:
        groups[(p.axis, round(p.target_m, 7))].append(p)
    preds = ident.predictions()
    figs = [_dynamic_stiffness_figure(lub, groups, out_dir),
            _damping_vs_frequency_figure(groups, preds["eq16_centred_Ns_per_m"], out_dir),
            _damping_vs_amplitude_figure(lub, preds, out_dir)]
    if lub.mass_fits:
        figs.append(_added_mass_figure(lub, preds["eq15_added_mass_kg"], out_dir))
    return figs


def _dynamic_stiffness_figure(lub: LubResult, groups: dict[tuple[str, float], list[LubPoint]],
                              out_dir: Path) -> Figure:
    """Figure 30: the dynamic stiffness against frequency with its fit, per axis and level."""
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for fit in lub.mass_fits:
        if fit.method != "eq9":
            continue
        ps = [p for (a, _), v in groups.items() if a == fit.axis for p in v
              if abs(p.amplitude_m - fit.amplitude_m) < 2e-6]
        f = np.array([p.freq_hz for p in ps])
        kd = np.array([p.k_dyn for p in ps])
        uk = np.array([p.u_k_dyn for p in ps])
        ax.errorbar(f, kd / 1e6, uk / 1e6, fmt="o", ms=3, capsize=2,
                    label=f"{fit.axis.upper()} {fit.amplitude_m * UM:.0f} um")
        ff = np.linspace(f.min(), f.max(), 50)
        w2 = (2 * np.pi * ff) ** 2
        kd_ss = np.array([p.k_dyn_ss for p in ps])
        ax.plot(f, kd_ss / 1e6, "x", ms=4, label="seal removed (stick-slip)")
        ax.plot(ff, (fit.k_n_per_m - w2 * fit.m_t_kg) / 1e6, "-", lw=0.8,
                label=f"fit K={fit.k_n_per_m / 1e3:.0f} kN/m, M_T={fit.m_t_kg:.1f} kg, "
                      f"R2={fit.r2:.2f}")
    return _one_axes_figure(
        fig, ax, "excitation frequency [Hz]", "K - w^2 M_T = Re(F/Z) [MN/m]", 6, out_dir,
        "dynamic_stiffness.png",
        "Dynamic stiffness from unidirectional tests and its fit (cf. Figure 30).")


def _damping_vs_frequency_figure(groups: dict[tuple[str, float], list[LubPoint]],
                                 eq16_centred: float, out_dir: Path) -> Figure:
    """Figures 31-34, E2: the system's and the film's damping against frequency, with eq. 16's
    centred damping ``eq16_centred`` [N.s/m]."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for (axis, _), ps in sorted(groups.items()):
        ps = sorted(ps, key=lambda p: p.freq_hz)
        freqs = [p.freq_hz for p in ps]
        amp = np.mean([p.amplitude_m for p in ps]) * UM
        axes[0].errorbar(freqs, [p.c_t / 1e3 for p in ps], [p.u_c_t / 1e3 for p in ps],
                         fmt="o-", ms=3, capsize=2, label=f"C_t{axis} {amp:.0f} um")
        axes[1].errorbar(freqs, [p.c_sfd / 1e3 for p in ps], [p.u_c_sfd / 1e3 for p in ps],
                         fmt="o-", ms=3, capsize=2, label=f"C_{axis}{axis} {amp:.0f} um (eq. 9)")
        axes[1].errorbar(freqs, [p.c_sfd_ss / 1e3 for p in ps], [p.u_c_sfd_ss / 1e3 for p in ps],
                         fmt="x--", ms=4, capsize=2,
                         label=f"C_{axis}{axis} {amp:.0f} um (stick-slip)")
    axes[1].axhline(eq16_centred / 1e3, color="k", ls="--",
                    label="eq. 16, centred")
    axes[0].set_ylabel("system damping C_t [kN.s/m]")
    axes[1].set_ylabel("SFD damping C = C_t - C_seal - C_rv [kN.s/m]")
    for ax in axes:
        ax.set_xlabel("excitation frequency [Hz]")
        _legend(ax, 6)
        ax.grid(alpha=0.3)
    return (_save(fig, out_dir, "damping_vs_frequency.png"),
            "System and squeeze-film damping against frequency, with 95 % uncertainty "
            "(cf. Figures 31-34, E2).")


def _damping_vs_amplitude_figure(lub: LubResult, preds: dict[str, Any],
                                 out_dir: Path) -> Figure:
    """Figures 35-37, E1: the system's and the film's damping against amplitude, with eq. 16."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    by_f: dict[tuple[str, float], list] = defaultdict(list)
    for p in lub.points:
        by_f[(p.axis, p.freq_hz)].append(p)
    for (axis, f_hz), ps in sorted(by_f.items()):
        ps = sorted(ps, key=lambda p: p.amplitude_m)
        a = [p.amplitude_m * UM for p in ps]
        axes[0].errorbar(a, [p.c_t / 1e3 for p in ps], [p.u_c_t / 1e3 for p in ps], fmt="o-",
                         ms=3, capsize=2, label=f"C_t{axis} {f_hz:g} Hz")
        axes[1].errorbar(a, [p.c_sfd / 1e3 for p in ps], [p.u_c_sfd / 1e3 for p in ps],
                         fmt="o-", ms=3, capsize=2, label=f"C_{axis}{axis} {f_hz:g} Hz")
    rows = preds["by_amplitude"]
    if rows:
        a = [r["amplitude_m"] * UM for r in rows]
        axes[1].plot(a, [r["eq16_at_eps_Ns_per_m"] / 1e3 for r in rows], "k--",
                     label="eq. 16 at eps = A/c")
        if "simulated_energy_equivalent_Ns_per_m" in rows[0]:
            axes[1].plot(a, [r["simulated_energy_equivalent_Ns_per_m"] / 1e3 for r in rows],
                         "k:", label="simulator (energy equivalent)")
    axes[0].set_ylabel("system damping C_t [kN.s/m]")
    axes[1].set_ylabel("SFD damping [kN.s/m]")
    for ax in axes:
        ax.set_xlabel("displacement amplitude [um]")
        _legend(ax, 6)
        ax.grid(alpha=0.3)
    return (_save(fig, out_dir, "damping_vs_amplitude.png"),
            "System and squeeze-film damping against amplitude with eq. 16 (cf. Figures "
            "35-37, E1).")


def _added_mass_figure(lub: LubResult, eq15_added_mass_kg: float, out_dir: Path) -> Figure:
    """Figure F1: the added mass against amplitude, with eq. 15's ``eq15_added_mass_kg``."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for axis in ("x", "y"):
        for method in ("eq9", "stick_slip"):
            fits = sorted((f for f in lub.mass_fits if f.axis == axis and f.method == method),
                          key=lambda f: f.amplitude_m)
            if fits:
                ax.errorbar([f.amplitude_m * UM for f in fits],
                            [f.added_mass_kg for f in fits],
                            [f.u_added_mass_kg for f in fits], fmt="o-", capsize=2,
                            label=f"D_{axis}{axis} ({method})")
    ax.axhline(eq15_added_mass_kg, color="k", ls="--", label="eq. 15")
    return _one_axes_figure(fig, ax, "displacement amplitude [um]", "added mass D [kg]", 7,
                            out_dir, "added_mass_vs_amplitude.png",
                            "Added mass against amplitude (cf. Figure F1, Table F1).")


def orbits(ident: Identification, out_dir: Path, max_plots: int = 4) -> list[Figure]:
    """Appendix C / D: load, displacement and velocity orbits rebuilt from the harmonics."""
    figs = []
    for label, dws in ident.dwells.items():
        usable = [d for d in dws if all(n in d.harmonics for n in ("fx", "fy", "x", "y"))]
        if not usable:
            continue
        pick = usable[:: max(len(usable) // max_plots, 1)][:max_plots]
        fig, axes = plt.subplots(len(pick), 3, figsize=(9, 2.8 * len(pick)), squeeze=False)
        for row, d in zip(axes, pick, strict=True):
            t = np.linspace(0, 1 / d.freq_hz, 200)
            fx = synthesize(d.harmonics["fx"], d.freq_hz, t)
            fy = synthesize(d.harmonics["fy"], d.freq_hz, t)
            x = synthesize(d.harmonics["x"], d.freq_hz, t)
            y = synthesize(d.harmonics["y"], d.freq_hz, t)
            vx = synthesize(d.harmonics["x"][:1], d.freq_hz, t, derivative=1)
            vy = synthesize(d.harmonics["y"][:1], d.freq_hz, t, derivative=1)
            for ax, (a, b), unit in zip(row, ((fx, fy), (x * UM, y * UM), (vx * 1e3, vy * 1e3)),
                                        ("N", "um", "mm/s"), strict=True):
                ax.plot(a, b, lw=1)
                ax.set_aspect("equal", adjustable="datalim")
                ax.set_title(f"{d.freq_hz:g} Hz [{unit}]", fontsize=8)
                ax.tick_params(labelsize=6)
        fig.subplots_adjust(left=0.08, right=0.97, bottom=0.05, top=0.95, wspace=0.35,
                            hspace=0.45)
        fname = _save(fig, out_dir, f"orbits_{_safe(label)}.png", tight=False)
        figs.append((fname, f"Load, displacement and 1X velocity orbits, {label} "
                            "(cf. Appendices C and D)."))
    return figs


def structure_figures(ident: Identification, out_dir: Path) -> list[Figure]:
    """Figure 6 (static), Figures 8-9 (impact FRF with fit), A2 (calibration), 20/25 (flow)."""
    figs = []
    if ident.static:
        fig, ax = plt.subplots(figsize=(6, 4))
        for s in ident.static:
            f = [p["force_n"] for p in s.points]
            d = [p["displacement_m"] * UM for p in s.points]
            ax.plot(f, d, "o", label=f"{s.axis.upper()}: K = {s.k_n_per_m / 1e3:.0f} +/- "
                                     f"{s.u_k_n_per_m / 1e3:.0f} kN/m")
            ff = np.linspace(min(f), max(f), 2)
            ax.plot(ff, ff / s.k_n_per_m * UM, "-", lw=0.8)
        ax.set_xlabel("static load [N]")
        ax.set_ylabel("deflection [um]")
        _legend(ax, 7)
        ax.grid(alpha=0.3)
        figs.append((_save(fig, out_dir, "static.png"),
                     "Deflection against static load (cf. Figure 6, Table 2)."))
    for imp in ident.impact:
        fig, axes = plt.subplots(2, 1, figsize=(6, 5), sharex=True)
        fi = np.array(imp.freq_hz)
        h = np.array([complex(a, b) for a, b in imp.frf_m_per_n])
        hm = imp.model(fi)
        axes[0].semilogy(fi, np.abs(h) * UM, ".", ms=3, label="test")
        axes[0].semilogy(fi, np.abs(hm) * UM, "-", label=f"fit, R2 = {imp.r2:.3f}")
        axes[0].set_ylabel("|X/F| [um/N]")
        axes[1].plot(fi, np.degrees(np.angle(h)), ".", ms=3)
        axes[1].plot(fi, np.degrees(np.angle(hm)), "-")
        axes[1].set_ylabel("phase [deg]")
        axes[1].set_xlabel("frequency [Hz]")
        _legend(axes[0], 7)
        for ax in axes:
            ax.grid(alpha=0.3)
        figs.append((_save(fig, out_dir, f"impact_{imp.axis}.png"),
                     f"Impact transfer function and fit, {imp.axis.upper()} (cf. Figures 8-9)."))
    if ident.probe:
        fig, ax = plt.subplots(figsize=(6, 4))
        for c in ident.probe:
            x = [p["reference_m"] * UM for p in c.points]
            v = [p["volts"] for p in c.points]
            ax.plot(x, v, "o", ms=3, label=f"{c.channel}: {c.gain_mv_per_mil:.1f} mV/mil, "
                                           f"R2 = {c.r2:.4f}")
        ax.set_xlabel("reference displacement [um]")
        ax.set_ylabel("probe output [V]")
        _legend(ax, 7)
        ax.grid(alpha=0.3)
        figs.append((_save(fig, out_dir, "probe_calibration.png"),
                     "Eddy-current probe output against reference displacement (cf. Figure A2)."))
    if ident.flow:
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
        for fr in ident.flow:
            dp = np.array([p["dp_pa"] for p in fr.points]) / 1e3
            q = np.array([p["q_l_per_min"] for p in fr.points])
            uq = np.array([p["U_q_m3_per_s"] for p in fr.points]) * 60_000
            axes[0].errorbar(dp, q, uq, fmt="o", capsize=2,
                             label=f"test, T = {fr.mean_temperature_c:.1f} degC")
            axes[0].plot(dp, [p["q_eq5_eq1_m3_per_s"] * 60_000 for p in fr.points], "--",
                         label="eq. 5, mu from eq. 1")
            axes[0].plot(dp, [p["q_eq5_config_m3_per_s"] * 60_000 for p in fr.points], ":",
                         label="eq. 5, mu of the rig configuration")
            axes[1].plot([p["dp_ratio"] for p in fr.points],
                         [p["flow_ratio_eq1"] for p in fr.points], "o", label="Q / Q_eq5 (eq. 1)")
        axes[1].axhline(1.0, color="k", lw=0.8)
        axes[0].set_xlabel("pressure difference [kPa]")
        axes[0].set_ylabel("flow [L/min]")
        axes[1].set_xlabel("dP / P_s")
        axes[1].set_ylabel("flow ratio")
        for ax in axes:
            _legend(ax, 7)
            ax.grid(alpha=0.3)
        figs.append((_save(fig, out_dir, "flow.png"),
                     "Flow against pressure difference beside eq. 5, and the flow ratio "
                     "(cf. Figures 20 and 25)."))
    return figs


def all_figures(ident: Identification, out_dir: Path) -> list[Figure]:
    out_dir.mkdir(parents=True, exist_ok=True)
    figs: list[Figure] = []
    for fn in (structure_figures, waterfalls, synchronous, dry_figures, lubricated_figures,
               orbits):
        figs.extend(fn(ident, out_dir))
    return figs
