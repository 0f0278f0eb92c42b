"""A sweep recorded as the daemon records it: the real sweep engine on the simulated rig, written
by the run writer to an HDF5 run file (the pump on for a lubricated sweep)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from control.run.pump import PumpRelay
from control.run.sweep.engine import SweepEngine
from daq.channels import default_channel_map
from rig_model import RigParams
from simulated_hw import SimulatedBackend
from storage.runfile import RunWriter


def record_sweep(rig: RigParams, spec: dict[str, Any], path: Path, seed: int,
                 lubricated: bool = True, described: RigParams | None = None) -> str:
    """Record ``spec`` on the simulated ``rig`` into ``path``, the file's rig description
    ``described`` (default: ``rig``; another where the rig hides an effect); the sweep's
    status."""
    backend = SimulatedBackend(rig, seed=seed)
    cm = default_channel_map()
    backend.configure(cm)
    pump = PumpRelay(backend)
    pump.set(lubricated)
    writer = RunWriter.create(path, path.stem, "sweep", cm.to_json_dict()["ai"], cm.ao_names,
                              cm.sample_rate_hz, channel_map=cm.to_json_dict(),
                              rig_config=(described or rig).model_dump(mode="json"),
                              lubricated=lubricated, flush_interval_s=0, swmr=False)
    outcome = SweepEngine(backend, spec, pump=pump, listener=writer).run()
    writer.close()
    return outcome.status
