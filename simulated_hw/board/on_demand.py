"""Software-timed (on-demand) AI, as a mixin of `simulated_hw.board.device.SimDevice`: a read
takes its samples now, from a rig of its own that continues the one simulated last."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from daq.channels import AnalogInput, ChannelMap, DeviceSpec
from rig_model.rig import RigModel
from simulated_hw.board.tasks import SimTask


class OnDemandAi:
    """`_read_on_demand`; needs the device's state declared below."""

    spec: DeviceSpec
    wiring: ChannelMap
    fast: bool
    _vtime: float
    _idle: tuple[SimTask, RigModel | None, list[tuple[str, int] | None], float] | None
    _floating_rng: np.random.Generator
    catch_up: Callable[[], None]
    now: Callable[[], float]
    _ai_rows: Callable[[SimTask], tuple[list[AnalogInput], list[tuple[str, int] | None]]]
    _new_rig: Callable[[ChannelMap], RigModel]
    _present_terminals: Callable[[], Any]
    carried: tuple[RigModel, float] | None

    def _read_on_demand(self, task: SimTask, n: int) -> np.ndarray:
        """A software-timed read: ``n`` samples taken now, one sample period apart.

        The rig behind on-demand reads runs at the wiring's sample rate from the previous
        on-demand read to now (at most the last second of it: an approximation, like holding
        the AO terminals at their present values over that stretch). In fast mode each
        on-demand sample moves the device clock by 1 ms."""
        fs = self.wiring.sample_rate_hz
        if self.fast:
            self._vtime += n * 1e-3
        self.catch_up()
        now = self.now()
        if self._idle is None or self._idle[0] is not task:
            ai, rows = self._ai_rows(task)
            rig = None
            if ai:
                rig = self._new_rig(ChannelMap(device=self.spec, sample_rate_hz=fs,
                                               ai=tuple(ai), ao=self.wiring.ao,
                                               do=self.wiring.do))
            self._idle = (task, rig, rows, now - n / fs)
        _, rig, rows, last = self._idle
        steps = int(min(max(round((now - last) * fs), n), fs))
        terminals = self._present_terminals()
        drive = np.repeat(terminals[:, None], steps, axis=1)
        wired = [self.spec.ao_channels().index(c.physical_channel) for c in self.wiring.ao]
        rig_out = rig.process(drive[wired])[:, -n:] if rig is not None else None
        self._idle = (task, rig, rows, now)
        if rig is not None:
            self.carried = (rig, now)
        out = np.empty((len(rows), n))
        lsb = 2 * self.spec.ai_range_v / 2**self.spec.ai_bits
        for i, source in enumerate(rows):
            if source is None:
                out[i] = np.round(self._floating_rng.normal(0.0, lsb, n) / lsb) * lsb
            elif source[0] == "ao":
                out[i] = terminals[source[1]]
            else:
                assert rig_out is not None
                out[i] = rig_out[source[1]]
        return out
