"""The README's main job, as a user runs it: `sfdrig demo` in a real process, end to end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from storage import open_run


@pytest.mark.e2e
def test_demo_stores_runs_and_writes_the_report(tmp_path: Path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "sfdrig", "demo", "--out", str(out)],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "15/15 steps converged" in proc.stdout  # dry circular orbit
    assert "10/10 steps converged" in proc.stdout  # lubricated X, 13 and 38 um
    runs = sorted((out / "runs").glob("*.h5"))
    kinds = []
    for path in runs:
        with open_run(path) as run:
            assert run.status == "completed", path
            kinds.append(run.kind)
    assert sorted(kinds) == ["flow", "impact", "probe_calibration", "static", "sweep", "sweep"]
    report = json.loads((out / "report" / "report.json").read_text())
    assert report["skipped"] == []
    assert (out / "report" / "index.html").stat().st_size > 1000
    figures = list((out / "report" / "figures").glob("*.png"))
    assert len(figures) >= 10
    # the numbers the report is about (Table 4, Table 2): the simulated rig has the report's
    # the simulated reference is what the sweeps ran with (26 N seal), not the seal-off
    # structure runs' configuration
    assert report["simulated_reference"]["F_mu_N"] == 26.0
    dry = report["dry"]["table4"]["identified"]
    assert dry["F_mu_N"] == pytest.approx(26.0, rel=0.05)
    assert dry["C_rv_Ns_per_m"] == pytest.approx(370.0, rel=0.15)
    k = {row["axis"]: row["k_n_per_m"] for row in report["static_table2"]}
    assert k["x"] == pytest.approx(788e3, rel=0.03)
    assert k["y"] == pytest.approx(823e3, rel=0.03)


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(900)
def test_demo_on_the_calibrated_report_rig(tmp_path: Path):
    from rig_model.params import rig_params_named_or_file

    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "sfdrig", "demo", "--rig", "report", "--out",
                           str(out)], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "simulated rig: report" in proc.stdout
    assert "15/15 steps converged" in proc.stdout and "10/10 steps converged" in proc.stdout
    report = json.loads((out / "report" / "report.json").read_text())
    rig = rig_params_named_or_file("report").structure
    k = {row["axis"]: row["k_n_per_m"] for row in report["static_table2"]}
    assert k["y"] == pytest.approx(rig.stiffness_y_n_per_m, rel=0.03)  # 922 kN/m, not 823
    assert report["dry"]["table4"]["identified"]["F_mu_N"] == pytest.approx(26.0, rel=0.05)
