"""The rig as a model: parameters, film closed forms, equation of motion, the rig block by block.

The bottom floor beside `daq`: the simulated board (`simulated_hw`) runs it behind the DAQ
protocol, and `analysis` uses it to predict and to fit.
"""

from rig_model.params import RigParams, RigParamsError, load_rig_params
from rig_model.rig import RigModel, simulate_response

__all__ = ["RigModel", "RigParams", "RigParamsError", "load_rig_params", "simulate_response"]
