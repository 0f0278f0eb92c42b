"""Maps read strictly (`load_channel_map`): a name the software does not know (with the name it
probably meant), a known name of another kind, a relay other than the pump, a terminal or a
name used twice, a drive axis twice, a required channel missing: one line per entry, naming the
file and the entry. The shipped example and a one-axis map load; a wiring map may lack any
channel (an empty terminal) but not carry an unknown name."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from daq.channels import KNOWN_INPUTS, default_channel_map, load_channel_map, rig_map_problems
from daq.errors import ChannelConfigError
from tests.conftest import REPO_ROOT
from tests.e2e.test_channels_e2e import _map as _write  # the example, changed, as TOML

EXAMPLE = REPO_ROOT / "examples" / "channels_report_rig.toml"
KNOWN = ", ".join(KNOWN_INPUTS)


def _named(which: str, /, **update: Any) -> Callable[[dict[str, Any]], None]:
    def change(data: dict[str, Any]) -> None:
        entry = next(e for e in data["ai"] if e["name"] == which)
        entry.update(update)
    return change


def _drop(group: str, name: str) -> Callable[[dict[str, Any]], None]:
    return lambda d: d.update({group: [e for e in d[group] if e["name"] != name]})


@pytest.mark.parametrize("change,lines", [
    (_named("x2", name="x3"),
     [f"ai[3] (x3): unknown input name 'x3' (did you mean 'x2'?); the software knows {KNOWN}"]),
    (_named("fy", name="fz"),
     [f"ai[1] (fz): unknown input name 'fz' (did you mean 'fy'?); the software knows {KNOWN}",
      "ai: missing the Y load cell (force control, load trip) for ao[1] (shaker_y): add an "
      "input named fy"]),
    (_named("p_in", name="p_inlet"),
     [f"ai[8] (p_inlet): unknown input name 'p_inlet' (did you mean 'p_in'?); the software "
      f"knows {KNOWN}"]),
    (_named("ax", name="a_x"),
     [f"ai[6] (a_x): unknown input name 'a_x' (did you mean 'ax'?); the software knows "
      f"{KNOWN}"]),
    (_named("ax", kind="eddy_current_probe", units="m"),
     ["ai[6] (ax): kind 'eddy_current_probe', but ax must be kind 'accelerometer'"]),
    (_named("x2", physical_channel="Dev1/ai2"),
     ["ai[3] (x2): duplicate physical_channel 'Dev1/ai2' (also ai[2] (x1))"]),
    (_named("y2", name="y1"),
     ["ai[5] (y1): duplicate channel name 'y1'"]),
    (lambda d: d["ao"][1].update(axis="x"),
     ["ao[1] (shaker_y): axis 'x' is driven by ao[0] (shaker_x) already: one drive per axis"]),
    (lambda d: d["do"][0].update(name="valve"),
     ["do[0] (valve): unknown relay 'valve'; the software switches only pump",
      "do: missing the pump relay (the daemon's interlock): add a relay named pump"]),
    (lambda d: d["do"].append({"name": "pmup", "physical_channel": "Dev1/port0/line2"}),
     ["do[1] (pmup): unknown relay 'pmup' (did you mean 'pump'?); the software switches only "
      "pump"]),
    (_drop("ai", "fx"),
     ["ai: missing the X load cell (force control, load trip) for ao[0] (shaker_x): add an "
      "input named fx"]),
    (lambda d: (_drop("ai", "y1")(d), _drop("ai", "y2")(d)),
     ["ai: missing an eddy-current probe on Y (displacement trip) for ao[1] (shaker_y): add an "
      "input named y1 or y2"]),
    (lambda d: d.update(ao=[]),
     ["ao: no shaker drive: add one per axis driven ([[ao]] with axis = 'x' or 'y')"]),
])
def test_a_map_the_software_cannot_use_is_refused_naming_each_entry(tmp_path, change, lines):
    path = _write(tmp_path, change)
    with pytest.raises(ChannelConfigError) as err:
        load_channel_map(path)
    assert err.value.lines() == [f"{path}: {line}" for line in lines]


def test_the_shipped_example_and_the_default_map_pass():
    assert rig_map_problems(load_channel_map(EXAMPLE)) == []
    assert rig_map_problems(default_channel_map()) == []


def test_optional_channels_may_be_left_out_and_a_one_axis_rig_loads(tmp_path):
    """Only the second probe, the accelerometers, the oil's instruments and the hammer: then a
    one-axis rig (the X drive, its load cell and one probe, the pump)."""
    optional = ("x2", "y2", "ax", "ay", "p_in", "p_rec", "q_in", "q_out", "t_oil", "hammer")
    path = _write(tmp_path, lambda d: d.update(ai=[e for e in d["ai"]
                                                   if e["name"] not in optional]))
    assert load_channel_map(path).ai_names == ["fx", "fy", "x1", "y1"]
    keep = ("fx", "x1")
    path = _write(tmp_path, lambda d: d.update(ai=[e for e in d["ai"] if e["name"] in keep],
                                               ao=d["ao"][:1]))
    cm = load_channel_map(path)
    assert (cm.ai_names, [ao.axis for ao in cm.ao]) == (["fx", "x1"], ["x"])


def test_a_wiring_map_may_lack_a_sensor_but_not_name_an_unknown_one(tmp_path):
    path = _write(tmp_path, _drop("ai", "fx"))  # a dead load cell: an empty terminal
    assert "fx" not in load_channel_map(path, wiring=True).ai_names
    with pytest.raises(ChannelConfigError):
        load_channel_map(path)
    path = _write(tmp_path, _named("x2", name="x3"))
    with pytest.raises(ChannelConfigError) as err:
        load_channel_map(path, wiring=True)
    assert err.value.lines()[0].startswith(f"{path}: ai[3] (x3): unknown input name 'x3'")
