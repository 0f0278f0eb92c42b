"""`sfdrig sweep --check`: a sweep checked offline, no daemon, as the daemon's start checks it:
the sweep's fields (`control.wire.sweep_spec.SweepSpec`; a field it does not have gets the one
it probably means), then its steps against the daemon's default limits and a channel map (the
default one, or the ``--channels`` file the daemon is started with): every target within the
limits and within what the controller reaches, the frequencies, the shutdown budget
(`control.run.sweep.engine.check_sweep`). Not a client command: it imports the run's checks."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import ValidationError

from control.run.safety import SafetyLimits
from control.run.sweep.engine import check_sweep
from control.wire.errors import TargetError
from control.wire.sweep_spec import SweepSpec
from daq.channels import default_channel_map, load_channel_map
from daq.config_files import validation_problems


def sweep_problems(fields: dict[str, Any],
                   channels: Path | None = None) -> tuple[SweepSpec | None, list[str]]:
    """(the sweep, or None when its fields are invalid; one line per problem, [] when the
    daemon would start it). Raises `daq.errors.ChannelConfigError` for a bad ``channels``."""
    try:
        spec = SweepSpec.model_validate(fields)
    except ValidationError as err:
        return None, validation_problems(err, SweepSpec)
    cm = load_channel_map(channels) if channels is not None else default_channel_map()
    try:
        check_sweep(spec, SafetyLimits(), cm)
    except TargetError as err:
        # "sweep refused...:" then one indented line per problem, or a single line
        lines = str(err).splitlines()
        return spec, [ln.strip() for ln in lines[1:]] or lines
    return spec, []


def limits_line() -> str:
    """The limits an offline check used (the daemon's defaults)."""
    lim = SafetyLimits()
    return (f"the daemon's default limits: displacement {lim.displacement_limit_m * 1e6:.4g} um, "
            f"load {lim.max_load_n:g} N, {lim.min_freq_hz:g}-{lim.max_freq_hz:g} Hz")
