"""The simulated board: the in-process SimulatedBackend and the simulated NI gRPC server, both
running the rig model (`rig_model`) behind the DAQ protocol."""

from simulated_hw.backend import SimulatedBackend

__all__ = ["SimulatedBackend"]
