"""A channel map against the device it is meant for, through nidaqmx: what the device offers
(`read_inventory`), what in the map it cannot do (`check_map`, one line per problem, naming the
channel and its physical channel), and the map's inputs read live at rest (`LiveReader`).

Nothing here drives an output: the checks ask the driver (or the NI gRPC Device Server) about
the device, and the live reader runs one finite AI task of the map's inputs.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from daq.channels import AnalogInput, ChannelMap, TerminalConfig
from daq.errors import DEVICE_NOT_FOUND, DaqError
from daq.nidaqmx_backend import terminal_configuration
from daq.nidaqmx_session import NidaqmxSession, _nidaqmx, close_task, translate_errors

_log = logging.getLogger(__name__)

Range = tuple[float, float]

_TERMINAL_NAMES = {"RSE": TerminalConfig.RSE, "NRSE": TerminalConfig.NRSE,
                   "DIFF": TerminalConfig.DIFFERENTIAL,
                   "PSEUDO_DIFF": TerminalConfig.PSEUDO_DIFFERENTIAL}


@dataclass(frozen=True)
class DeviceInventory:
    """What one device offers, as its driver reports it."""

    name: str
    product: str
    ai: tuple[str, ...]
    ao: tuple[str, ...]
    lines: tuple[str, ...]  # digital lines (the relays' outputs, the emergency stop's input)
    ai_ranges_v: tuple[Range, ...]
    ao_ranges_v: tuple[Range, ...]
    #: per AI physical channel (as the device names it), the terminal configurations it allows
    ai_terminal_configs: dict[str, frozenset[TerminalConfig]]


class DeviceNotFoundError(DaqError):
    """The map's device is not on this driver or device server; ``present`` names what is."""

    def __init__(self, message: str, present: tuple[str, ...]) -> None:
        super().__init__(message, DEVICE_NOT_FOUND)
        self.present = present


def read_inventory(session: NidaqmxSession, device_name: str,
                   ai_channels: Iterable[str] = ()) -> DeviceInventory:
    """Ask the driver what ``device_name`` offers; the AI terminal configurations are read for
    ``ai_channels`` (those of them the device has). Raises `DeviceNotFoundError` when the
    driver has no such device."""
    _nidaqmx()  # the package, or DaqConnectionError saying it is missing
    from nidaqmx.system import Device, PhysicalChannel, System

    options = session.grpc_options()
    where = f"asking {device_name}{session.where}"
    with translate_errors(where):
        device = Device(device_name, grpc_options=options)
    try:
        with translate_errors(f"{where} for its product"):
            product = str(device.product_type)
    except DaqError as err:
        if err.code != DEVICE_NOT_FOUND:
            raise
        with translate_errors(f"listing the devices{session.where}"):
            present = tuple(System(grpc_options=options).devices.device_names)
        raise DeviceNotFoundError(
            f"no device {device_name!r}{session.where} (it has "
            f"{', '.join(present) or 'none'})", present) from None
    with translate_errors(f"{where} for its channels and ranges"):
        ai = tuple(device.ai_physical_chans.channel_names)
        ao = tuple(device.ao_physical_chans.channel_names)
        lines = tuple(device.do_lines.channel_names)
        ai_ranges = _pairs(device.ai_voltage_rngs)
        ao_ranges = _pairs(device.ao_voltage_rngs) if ao else ()
    have = {a.lower(): a for a in ai}
    configs: dict[str, frozenset[TerminalConfig]] = {}
    for name in ai_channels:
        canonical = have.get(name.lower())
        if canonical is None or canonical in configs:
            continue
        with translate_errors(f"{where} for the terminal configurations of {canonical}"):
            cfgs = PhysicalChannel(canonical, grpc_options=options).ai_term_cfgs
        configs[canonical] = frozenset(_TERMINAL_NAMES[c.name] for c in cfgs)
    return DeviceInventory(device_name, product, ai, ao, lines, ai_ranges, ao_ranges, configs)


def _pairs(flat: list[float]) -> tuple[Range, ...]:
    return tuple((float(flat[i]), float(flat[i + 1])) for i in range(0, len(flat) - 1, 2))


def _ranges_text(ranges: tuple[Range, ...]) -> str:
    return ", ".join(f"+/-{hi:g}" if lo == -hi else f"{lo:g} to {hi:g}" for lo, hi in ranges)


def _range_problem(rng: Range, ranges: tuple[Range, ...], kind: str, dev: str) -> str | None:
    """Why ``rng`` is not a range of the device (DAQmx takes the smallest range holding it),
    or None. A map's range must be one the device sets exactly: overload checks and the guide
    read it as the input's range."""
    if not ranges:
        return f"{dev} reports no {kind} voltage ranges"
    lo, hi = rng
    holding = [r for r in ranges if r[0] <= lo + 1e-9 and hi <= r[1] + 1e-9]
    if not holding:
        return (f"range_v ({lo:g}, {hi:g}) V is beyond every {kind} range of {dev} "
                f"({_ranges_text(ranges)} V)")
    best = min(holding, key=lambda r: r[1] - r[0])
    if abs(best[0] - lo) > 1e-9 or abs(best[1] - hi) > 1e-9:
        return (f"range_v ({lo:g}, {hi:g}) V is not an {kind} range of {dev} "
                f"({_ranges_text(ranges)} V): DAQmx would measure on ({best[0]:g}, {best[1]:g}) V;"
                f" write that")
    return None


def check_map(cm: ChannelMap, inv: DeviceInventory) -> list[str]:
    """Every problem of ``cm`` on the device ``inv`` describes, one line each, led by the
    channel's group, name and physical channel. Empty: the device can do what the map says."""
    problems: list[str] = []
    dev = f"{inv.name} ({inv.product})"
    if cm.device.product != inv.product:
        problems.append(f"device {cm.device.name}: the map describes a {cm.device.product}, "
                        f"the device is a {inv.product}")

    def has(names: tuple[str, ...], physical: str) -> str | None:
        return {n.lower(): n for n in names}.get(physical.lower())

    def missing(kind: str, names: tuple[str, ...]) -> str:
        span = f"{names[0]} to {names[-1]}" if names else "none"
        return f"{dev} has no such {kind} (its {kind}s: {span})"

    for ch in cm.ai:
        where = f"ai {ch.name} ({ch.physical_channel})"
        canonical = has(inv.ai, ch.physical_channel)
        if canonical is None:
            problems.append(f"{where}: {missing('AI channel', inv.ai)}")
            continue
        if (why := _range_problem(ch.range_v, inv.ai_ranges_v, "AI", dev)) is not None:
            problems.append(f"{where}: {why}")
        allowed = inv.ai_terminal_configs.get(canonical)
        if ch.terminal_config is not TerminalConfig.DEFAULT and allowed is not None \
                and ch.terminal_config not in allowed:
            names = ", ".join(sorted(c.value for c in allowed)) or "none"
            problems.append(f"{where}: terminal_config {ch.terminal_config.value!r} is not "
                            f"allowed on {canonical} (it allows {names})")
        if (why := _offset_problem(ch)) is not None:
            problems.append(f"{where}: {why}")
    for ao in cm.ao:
        where = f"ao {ao.name} ({ao.physical_channel})"
        if has(inv.ao, ao.physical_channel) is None:
            problems.append(f"{where}: {missing('AO channel', inv.ao)}")
        elif (why := _range_problem(ao.range_v, inv.ao_ranges_v, "AO", dev)) is not None:
            problems.append(f"{where}: {why}")
    lines = [(f"do {d.name}", d.physical_channel) for d in cm.do]
    if cm.estop is not None:
        lines.append((f"estop {cm.estop.name}", cm.estop.physical_channel))
    for label, physical in lines:
        if has(inv.lines, physical) is None:
            problems.append(f"{label} ({physical}): {missing('digital line', inv.lines)}")
    return problems


def _offset_problem(ch: AnalogInput) -> str | None:
    """A sensor whose zero (``offset_v``) lies outside the input range reads clipped at rest
    (a proximitor's gap voltage, -8 to -12 V, on a +/-10 V range)."""
    lo, hi = ch.range_v
    if lo <= ch.offset_v <= hi:
        return None
    return (f"offset_v {ch.offset_v:g} V (the sensor's output at zero) is outside range_v "
            f"({lo:g}, {hi:g}) V: the input reads clipped at rest")


def device_problems(cm: ChannelMap, session: NidaqmxSession) -> list[str]:
    """`check_map` against the device ``cm`` names, read through ``session``; a device that is
    not there is one problem per channel."""
    try:
        inv = read_inventory(session, cm.device.name, [c.physical_channel for c in cm.ai])
    except DeviceNotFoundError as err:
        chans: list[Any] = [*cm.ai, *cm.ao, *cm.do]
        if cm.estop is not None:
            chans.append(cm.estop)
        there = ", ".join(err.present) or "none"
        return [f"{_group(cm, c)} {c.name} ({c.physical_channel}): no device "
                f"{cm.device.name!r}{session.where} (it has {there})" for c in chans]
    return check_map(cm, inv)


def _group(cm: ChannelMap, ch: Any) -> str:
    if ch in cm.ai:
        return "ai"
    if ch in cm.ao:
        return "ao"
    return "do" if ch in cm.do else "estop"


@dataclass(frozen=True)
class LiveValues:
    """One acquisition of the map's inputs: per channel (the map's order) the mean and the
    standard deviation in engineering units, the mean in volts, and the extreme volts."""

    mean: np.ndarray
    std: np.ndarray
    mean_v: np.ndarray
    min_v: np.ndarray
    max_v: np.ndarray
    samples: int

    @classmethod
    def of(cls, cm: ChannelMap, volts: np.ndarray) -> LiveValues:
        """The values of an acquisition of ``cm``'s inputs, volts of shape (n_ai, n)."""
        eng = cm.to_engineering(volts)
        return cls(eng.mean(axis=1), eng.std(axis=1), volts.mean(axis=1), volts.min(axis=1),
                   volts.max(axis=1), volts.shape[1])


class LiveReader:
    """The map's analog inputs as one finite AI task (its ranges and terminal
    configurations), read again on each `read`. Drives nothing; close it (or use ``with``)."""

    def __init__(self, cm: ChannelMap, session: NidaqmxSession) -> None:
        self.cm = cm
        self._task: Any = None
        self._task = session.new_task("live")
        try:
            for ch in cm.ai:
                lo, hi = ch.range_v
                with translate_errors(f"AI channel {ch.name} on {ch.physical_channel}"):
                    self._task.ai_channels.add_ai_voltage_chan(
                        ch.physical_channel, name_to_assign_to_channel=ch.name,
                        terminal_config=terminal_configuration(ch.terminal_config),
                        min_val=lo, max_val=hi)
        except DaqError:
            self.close()
            raise

    def read(self, duration_s: float = 0.1) -> LiveValues:
        """``duration_s`` of every input at the map's sample rate (at least 2 samples)."""
        nidaqmx = _nidaqmx()
        from nidaqmx.constants import AcquisitionType

        fs = self.cm.sample_rate_hz
        n = max(int(round(duration_s * fs)), 2)
        out = np.zeros((len(self.cm.ai), n))
        with translate_errors(f"reading {n} samples of {len(self.cm.ai)} inputs at {fs:g} S/s"):
            self._task.timing.cfg_samp_clk_timing(fs, sample_mode=AcquisitionType.FINITE,
                                                  samps_per_chan=n)
            reader = nidaqmx.stream_readers.AnalogMultiChannelReader(self._task.in_stream)
            reader.verify_array_shape = False
            self._task.start()
            try:
                reader.read_many_sample(out, number_of_samples_per_channel=n,
                                        timeout=duration_s + 10.0)
            finally:
                self._task.stop()
        return LiveValues.of(self.cm, out)

    def close(self) -> None:
        """Clear the task; safe to call twice. A failure (the server gone) is logged: there is
        nothing left to release."""
        task, self._task = self._task, None
        if task is None:
            return
        close_task(task)

    def __enter__(self) -> LiveReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
