"""The simulated board (`board`, running the rig model `rig_model`), served by the simulated NI
gRPC server and adapted in process to the DAQ protocol by SimulatedBackend."""

from simulated_hw.backend import SimulatedBackend

__all__ = ["SimulatedBackend"]
