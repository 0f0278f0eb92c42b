"""Acceptance: the report's identification on the simulated rig, through the real sweep engine.

Runs (fast mode, seeded): a dry circular-load sweep (40 N and 33 N), a static load test (seal
removed, as the report's static tests had no journal) and a lubricated unidirectional sweep along
X (25 um and 38 um, 20-60 Hz), each written as a run file by `storage.RunWriter`; then
`analysis.identify` on the files. The simulated values are the rig's parameters, and for the SFD
damping the energy-equivalent coefficient of eq. 16 with the instantaneous eccentricity over a
cycle of the identified amplitude (`rig_model.film.energy_equivalent_damping`).
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis.identify import identify, write_results
from analysis.report import build_report
from control.run.files import create_run_writer
from control.run.programs.procedures import StaticSpec, run_static_test
from control.run.pump import PumpRelay
from control.run.safety import SafetyLimits
from control.run.sweep.engine import SweepEngine, SweepSpec
from daq.channels import default_channel_map
from rig_model.film import energy_equivalent_damping
from rig_model.params import RigParams
from simulated_hw.backend import SimulatedBackend

DRY_FREQS = [20.0, 30.0, 60.0, 80.0, 100.0, 150.0, 200.0]  # 40-50 Hz: resonance, > 100 um
LUB_FREQS = [20.0, 30.0, 40.0, 50.0, 60.0]
AMPLITUDES_M = [25e-6, 38e-6]


def _backend(params: RigParams, seed: int) -> SimulatedBackend:
    b = SimulatedBackend(params, seed=seed)
    b.configure(default_channel_map())
    return b


def run_sweep(path: Path, spec: SweepSpec, seed: int, params: RigParams | None = None,
              limits: SafetyLimits | None = None) -> Path:
    """One sweep through `SweepEngine` on the simulated rig, written to ``path``."""
    params = params or RigParams()
    b = _backend(params, seed)
    w = create_run_writer(path, "sweep", b.channel_map, run_id=path.stem, rig_config=params,
                          test_spec=spec, lubricated=spec.lubricated)
    pump = None
    if spec.lubricated:
        pump = PumpRelay(b)
        pump.set(True)
    try:
        out = SweepEngine(b, spec, limits=limits, listener=w, pump=pump).run()
    finally:
        if pump is not None and not pump.shakers_active:
            pump.set(False)
    w.close("completed" if out.status == "completed" else "aborted", out.reason)
    assert out.status == "completed", out.reason
    return path


def dry_spec(record_cycles: int = 10) -> SweepSpec:
    return SweepSpec(motion="circular_forward", load_n=[40.0, 33.0], freq_hz=DRY_FREQS,
                     settle_cycles=10, record_cycles=record_cycles)


def lub_spec(record_cycles: int = 10) -> SweepSpec:
    return SweepSpec(motion="x", lubricated=True, amplitude_m=AMPLITUDES_M, freq_hz=LUB_FREQS,
                     settle_cycles=10, record_cycles=record_cycles)


DRY_LIMITS = SafetyLimits(max_displacement_m=100e-6)  # dry: no film; 40 N circular reaches 64 um


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("acceptance")
    out = {
        "dry": run_sweep(d / "dry.h5", dry_spec(), seed=11, limits=DRY_LIMITS),
        "lub": run_sweep(d / "lub.h5", lub_spec(), seed=12),
    }
    no_seal = RigParams()
    no_seal.seal.enabled = False
    b = _backend(no_seal, 13)
    spec = StaticSpec(axes=("x",), forces_n=(-80.0, -40.0, 0.0, 40.0, 80.0), repeats=2)
    w = create_run_writer(d / "static.h5", "static", b.channel_map, run_id="static",
                          rig_config=no_seal, test_spec=spec)
    assert run_static_test(b, w, spec).completed
    w.close()
    out["static"] = d / "static.h5"
    return out


@pytest.fixture(scope="module")
def ident(runs: dict[str, Path]):
    return identify([runs["static"], runs["dry"], runs["lub"]])


def test_dry_friction_and_residual_damping(ident) -> None:
    dry = ident.dry
    assert dry is not None
    # measured (seeds 11-13): F_mu within 0.021 %, C_rv within 0.15 % (the limits were 5 % and
    # 15 %: a regression by 100x passed); held to a few times that
    assert abs(dry.f_mu_n - 26.0) / 26.0 < 0.001
    assert abs(dry.c_rv_ns_per_m - 370.0) / 370.0 < 0.005
    assert dry.overall.r2 > 0.98
    assert len(dry.by_test) == 2  # one row per load, as Table 4
    assert 0 < dry.u_f_mu_n < 0.1 * dry.f_mu_n


def test_static_stiffness(ident) -> None:
    (fit,) = ident.static
    assert fit.axis == "x"
    assert abs(fit.k_n_per_m - 788e3) / 788e3 < 2e-5  # measured 3e-6 (the limit was 3 %)
    assert 0.005 < fit.u_k_n_per_m / fit.k_n_per_m < 0.08  # Table 2: about 4 %


def test_lubricated_stiffness_and_added_mass(ident) -> None:
    params = RigParams()
    d_true = params.film.added_mass()
    fits = [f for f in ident.lubricated.mass_fits if f.method == "stick_slip"]
    assert len(fits) == 2
    for f in fits:  # measured: K within 1.1 % and 0.02 %, D within 3.0 % and 2.2 %
        assert abs(f.k_n_per_m - 788e3) / 788e3 < 0.03, f
        assert abs(f.added_mass_kg - d_true) / d_true < 0.08, f
        assert f.r2 > 0.99


def test_report_procedure_shows_the_seal_bias(ident) -> None:
    """Eq. 9 leaves the seal's in-phase force (sticking at 20-30 Hz) in the dynamic stiffness:
    the free fit's K comes out well below the structure's, as the stick-slip removal does not."""
    eq9 = {round(f.amplitude_m * 1e6): f for f in ident.lubricated.mass_fits
           if f.method == "eq9"}
    ss = {round(f.amplitude_m * 1e6): f for f in ident.lubricated.mass_fits
          if f.method == "stick_slip"}
    for amp in eq9:
        assert eq9[amp].k_n_per_m < 0.9 * ss[amp].k_n_per_m
    sticking = [p.stick_fraction for p in ident.lubricated.points if p.freq_hz == 20.0]
    assert min(sticking) > 0.1


def test_sfd_damping_against_simulated_value(ident) -> None:
    params = RigParams()
    lub = ident.lubricated
    assert {round(g["amplitude_m"] * 1e6) for g in lub.sfd_by_amplitude} == {25, 38}
    for g in lub.sfd_by_amplitude:
        ref = energy_equivalent_damping(params, g["amplitude_m"], "x", g["t_oil_c"])
        # measured: stick-slip 0.18 % and 0.39 % (the limit was 5 %); eq. 9 4.8 % and 2.4 %
        # (its seal bias: 10 % kept)
        assert abs(g["stick_slip"]["C_sfd_mean_Ns_per_m"] - ref) / ref < 0.012, (g, ref)
        assert abs(g["eq9"]["C_sfd_mean_Ns_per_m"] - ref) / ref < 0.10, (g, ref)
    for p in lub.points:
        ref = energy_equivalent_damping(params, p.amplitude_m, "x", p.t_oil_c)
        assert abs(p.c_sfd_ss - ref) / ref < 0.02, p  # measured: at most 0.59 % (was 5 %)


def test_report_trends(ident) -> None:
    """C_t falls with frequency and with amplitude; the SFD damping alone is nearly constant."""
    pts = ident.lubricated.points
    by_amp: dict[int, dict[float, float]] = {}
    for p in pts:
        by_amp.setdefault(round(p.amplitude_m * 1e6), {})[p.freq_hz] = p.c_t
    for amp, ct in by_amp.items():
        vals = [ct[f] for f in sorted(ct)]
        assert all(a > b for a, b in zip(vals, vals[1:], strict=False)), (amp, vals)
    for f in LUB_FREQS:
        assert by_amp[25][f] > by_amp[38][f]
    for g in ident.lubricated.sfd_by_amplitude:
        assert g["stick_slip"]["C_sfd_rel_spread"] < 0.015  # measured 0.38-0.49 % (was 5 %)
        assert g["eq9"]["C_sfd_rel_spread"] < 0.15
        # the total falls by tens of percent over 20-60 Hz; the film alone by a few at most
        assert g["dC_t_df_Ns_per_m_per_Hz"] < -50


def test_report_and_results_written(ident, runs: dict[str, Path], tmp_path: Path) -> None:
    page = build_report(ident, tmp_path / "report")
    assert page.name == "index.html"
    doc = json.loads((tmp_path / "report" / "report.json").read_text())
    assert doc["dry"]["table4"]["identified"]["F_mu_N"] == pytest.approx(ident.dry.f_mu_n)
    for fig in doc["figures"]:
        assert (tmp_path / "report" / fig["file"]).stat().st_size > 1000
        assert f"src='{fig['file']}'" in page.read_text()
    names = {Path(f["file"]).name for f in doc["figures"]}
    assert {"dynamic_stiffness.png", "damping_vs_frequency.png", "damping_vs_amplitude.png",
            "dry_work_energy.png", "dry_im_f_over_x.png", "synchronous.png",
            "static.png"} <= names
    assert any(n.startswith("waterfall_") for n in names)
    assert any(n.startswith("orbits_") for n in names)
    assert write_results(ident) == []
    with h5py.File(runs["lub"], "r") as f:
        share = json.loads(f["results/identify/json"][()])
        pts = f["results/identify/lubricated_points"][()]
    assert share["lubricated"]["points"]
    assert pts.shape == (len(LUB_FREQS) * len(AMPLITUDES_M), 7)
    assert np.all(np.isfinite(pts))
