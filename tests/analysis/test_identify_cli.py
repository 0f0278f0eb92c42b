"""`sfdrig identify` on run files written by the test programmes (static, flow)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import pytest

from control.run.files import create_run_writer
from control.run.programs.procedures import FlowSpec, StaticSpec, run_flow_test, run_static_test
from daq.channels import default_channel_map
from rig_model.params import RigParams
from sfdrig.cli import main
from sfdrig.simulated_operator import SimulatedHands, StandInOperator
from simulated_hw.backend import SimulatedBackend


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("cli")
    params = RigParams()
    params.seal.enabled = False
    b = SimulatedBackend(params, seed=5)
    b.configure(default_channel_map())
    spec = StaticSpec(axes=("y",), forces_n=(-60.0, 0.0, 60.0), repeats=1, record_s=0.2)
    w = create_run_writer(d / "static.h5", "static", b.channel_map, run_id="st1", rig_config=params)
    assert run_static_test(b, w, spec).completed
    w.close()
    params = RigParams()
    b = SimulatedBackend(params, seed=6)
    b.configure(default_channel_map())
    w = create_run_writer(d / "flow.h5", "flow", b.channel_map, run_id="fl1", rig_config=params,
                          lubricated=True)
    fspec = FlowSpec(supply_pressures_pa=(10e3, 15e3, 20e3), repeats=1, settle_s=2.5)
    assert run_flow_test(b, w, StandInOperator(), fspec, hands=SimulatedHands(b)).completed
    w.close()
    return {"static": d / "static.h5", "flow": d / "flow.h5"}


def test_identify_command(runs: dict[str, Path], tmp_path: Path,
                          capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["identify", str(runs["static"]), str(runs["flow"]), "--report",
               str(tmp_path / "rep"), "--json", str(tmp_path / "t.json")])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert "static y: K = 823.0" in out
    assert "flow: viscosity from eq. 5 fit 3.17 cP; eq. 1 2.78 cP" in out
    assert err == ""
    doc = json.loads((tmp_path / "t.json").read_text())
    # the same K as the line above (823.0 kN/m: within 50 N/m, 6e-5)
    assert doc["static_table2"][0]["k_n_per_m"] == pytest.approx(823e3, rel=1e-4)
    assert (tmp_path / "rep" / "index.html").exists()
    assert (tmp_path / "rep" / "figures" / "flow.png").exists()
    with h5py.File(runs["static"], "r") as f:
        share = json.loads(f["results/identify/json"][()])
    assert share["static_table2"][0]["axis"] == "y"


def test_identify_command_nothing_to_do(runs: dict[str, Path], tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["identify", str(runs["static"]), "--only", "dry", "--no-store"])
    _, err = capsys.readouterr()
    assert rc == 1
    assert "run st1 (static.h5) [static]: run of kind 'static'" in err
    missing = tmp_path / "missing.h5"
    rc = main(["identify", str(missing)])
    _, err = capsys.readouterr()
    assert rc == 2
    assert str(missing) in err and "no run file could be opened" in err
