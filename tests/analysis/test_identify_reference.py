"""The simulated reference is the configuration the sweeps ran with, not the structure runs'."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.identify import identify
from rig_model.params import RigParams
from storage.runfile import RunWriter


def _run(path: Path, kind: str, params: RigParams) -> Path:
    channels = [{"name": "fx", "units": "N", "kind": "load_cell", "sensor": "",
                 "physical_channel": ""}]
    with RunWriter.create(path, path.stem, kind, channels, [], 1000.0, swmr=False,
                          flush_interval_s=0, rig_config=params.model_dump(mode="json")) as w:
        w.on_block(0, np.zeros((1, 100)), None)
    return path


def test_reference_seal_comes_from_the_sweeps(tmp_path: Path) -> None:
    seal_off = RigParams.model_validate({"seal": {"enabled": False}})
    runs = [_run(tmp_path / "a-static.h5", "static", seal_off),
            _run(tmp_path / "b-impact.h5", "impact", seal_off),
            _run(tmp_path / "z-sweep.h5", "sweep", RigParams())]
    ident = identify(runs)
    assert ident.simulated
    assert ident.params.seal.enabled and ident.params.seal.friction_force_n == 26.0
