"""Helpers for the control tests: the simulated rig in fast mode, and a record of what was
written to its outputs (the real SimulatedBackend underneath: nothing the controller reads is
mocked)."""

from __future__ import annotations

import numpy as np
import pytest

from daq.channels import default_channel_map
from simulated_hw.backend import SimulatedBackend
from simulated_hw.params import RigParams


class WriteLog(SimulatedBackend):
    """SimulatedBackend that keeps a copy of every AO block written to it."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.written: list[np.ndarray] = []

    def write_ao(self, block: np.ndarray) -> None:
        super().write_ao(block)
        self.written.append(np.array(block, dtype=np.float64))

    def ao_written(self) -> np.ndarray:
        return np.concatenate(self.written, axis=1)


def make_backend(params: RigParams | None = None, seed: int = 0) -> WriteLog:
    be = WriteLog(params if params is not None else RigParams(), seed=seed)
    be.configure(default_channel_map())
    return be


@pytest.fixture
def backend() -> WriteLog:
    return make_backend()
