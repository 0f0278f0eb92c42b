"""Software-timed (on-demand) AI, a part of `simulated_hw.board.device.SimDevice`: a read takes
its samples now, from a rig of its own (which this part owns) that continues the one simulated
last."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from daq.channels import AnalogInput, ChannelMap, DeviceSpec
from rig_model.rig import RigModel
from simulated_hw.board.sensor_wiring import floating
from simulated_hw.board.tasks import SimTask


class Device(Protocol):
    """What on-demand reads take from `simulated_hw.board.device.SimDevice` (a protocol, so
    this part needs no import of the device that holds it)."""

    fast: bool
    spec: DeviceSpec
    wiring: ChannelMap
    carried: tuple[RigModel, float] | None
    floating_rng: np.random.Generator

    def move_idle_clock(self, seconds: float) -> None: ...
    def catch_up(self) -> None: ...
    def now(self) -> float: ...
    def ai_sources(self, task: SimTask) -> tuple[list[AnalogInput],
                                                 list[tuple[str, int] | None]]: ...
    def new_rig(self, rig_map: ChannelMap) -> RigModel: ...
    def present_terminals(self) -> np.ndarray: ...


class OnDemandAi:
    """The rig behind the on-demand reads of one task at a time, and when it was last read."""

    def __init__(self, device: Device) -> None:
        self._device = device
        self._task: SimTask | None = None
        self.rig: RigModel | None = None  # None: the task reads no wired input
        self._rows: list[tuple[str, int] | None] = []
        self._last = 0.0  # device time of the last read [s]

    def release(self) -> None:
        """A hardware-timed acquisition starts: its rig takes over (`SimDevice.carried`)."""
        self._task, self.rig = None, None

    def read(self, task: SimTask, n: int) -> np.ndarray:
        """A software-timed read: ``n`` samples taken now, one sample period apart.

        The rig behind on-demand reads runs at the wiring's sample rate from the previous
        on-demand read to now (at most the last second of it: an approximation, like holding
        the AO terminals at their present values over that stretch). In fast mode each
        on-demand sample moves the device clock by 1 ms."""
        dev = self._device
        fs = dev.wiring.sample_rate_hz
        if dev.fast:
            dev.move_idle_clock(n * 1e-3)
        dev.catch_up()
        now = dev.now()
        if self._task is not task:
            ai, self._rows = dev.ai_sources(task)
            self.rig = None
            if ai:
                self.rig = dev.new_rig(ChannelMap(device=dev.spec, sample_rate_hz=fs,
                                                  ai=tuple(ai), ao=dev.wiring.ao,
                                                  do=dev.wiring.do))
            self._task, self._last = task, now - n / fs
        if dev.carried is not None and dev.carried[0] is self.rig:
            self._last = max(self._last, dev.carried[1])  # a relay switch ran it on already
        steps = int(min(max(round((now - self._last) * fs), n), fs))
        terminals = dev.present_terminals()
        drive = np.repeat(terminals[:, None], steps, axis=1)
        wired = [dev.spec.ao_channels().index(c.physical_channel) for c in dev.wiring.ao]
        rig_out = self.rig.process(drive[wired])[:, -n:] if self.rig is not None else None
        self._last = now
        if self.rig is not None:
            dev.carried = (self.rig, now)
        out = np.empty((len(self._rows), n))
        for i, source in enumerate(self._rows):
            if source is None:
                out[i] = floating(dev.spec, dev.floating_rng, n)
            elif source[0] == "ao":
                out[i] = terminals[source[1]]
            else:
                assert rig_out is not None
                out[i] = rig_out[source[1]]
        return out
