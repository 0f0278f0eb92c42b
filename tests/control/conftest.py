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


class GainJump(WriteLog):
    """The amplifier's gain turned up by ``factor`` from AO sample ``at_sample`` on (a knob, a
    loose connection): what the rig receives changes, what the software wrote does not. No
    controller can foresee it; the limit monitor must catch it."""

    def __init__(self, *args, factor: float = 3.0, at_sample: int = 10_000, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.factor = factor
        self.at_sample = at_sample
        self._ao_samples = 0

    def write_ao(self, block: np.ndarray) -> None:
        block = np.array(block, dtype=np.float64)
        self.written.append(block.copy())
        k = np.arange(self._ao_samples, self._ao_samples + block.shape[1])
        self._ao_samples += block.shape[1]
        SimulatedBackend.write_ao(self, np.where(k >= self.at_sample, block * self.factor, block))
