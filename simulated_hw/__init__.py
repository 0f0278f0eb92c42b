"""The rig in software: physics, the in-process SimulatedBackend, the simulated NI gRPC server."""

from simulated_hw.backend import SimulatedBackend
from simulated_hw.params import RigParams, RigParamsError, load_rig_params
from simulated_hw.rig import RigModel, simulate_response

__all__ = [
    "RigModel", "RigParams", "RigParamsError", "SimulatedBackend", "load_rig_params",
    "simulate_response",
]
