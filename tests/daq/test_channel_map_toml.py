"""The channel map written as TOML reads back equal (`ChannelMap.to_toml` -> `load_channel_map`),
for the default map, the shipped example and generated maps; a map with several wiring mistakes
names each of them on its own line."""

from __future__ import annotations

import string
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daq.channels import (
    ChannelMap,
    EmergencyStopInput,
    TerminalConfig,
    channel_map_from_dict,
    default_channel_map,
    load_channel_map,
)
from daq.config_files import to_toml
from daq.errors import ChannelConfigError

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "channels_report_rig.toml"


def test_default_map_round_trips(tmp_path: Path):
    cm = default_channel_map()
    path = tmp_path / "map.toml"
    path.write_text(cm.to_toml())
    assert load_channel_map(path) == cm


def test_shipped_example_loads_and_round_trips(tmp_path: Path):
    cm = load_channel_map(EXAMPLE)
    assert len(cm.ai) == 14 and cm.estop is not None and cm.estop.pressed_level is False
    assert {c.terminal_config for c in cm.ai} == {TerminalConfig.DIFFERENTIAL}
    assert [c.offset_v for c in cm.ai_of_kind(cm.ai[2].kind)] == [-8.5] * 4
    # the report's Table A1 gains, 202 / 195 / 204 mV/mil
    assert [round(c.gain_v_per_unit * 25.4e-6, 6) for c in cm.ai[2:5]] == [0.202, 0.195, 0.204]
    path = tmp_path / "again.toml"
    path.write_text(cm.to_toml())
    assert load_channel_map(path) == cm


_text = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=20)
_finite = st.floats(min_value=-9.0, max_value=9.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(sensors=st.lists(_text, min_size=14, max_size=14),
       offsets=st.lists(_finite, min_size=14, max_size=14),
       gains=st.lists(st.floats(min_value=1e-9, max_value=1e9), min_size=14, max_size=14),
       configs=st.lists(st.sampled_from(list(TerminalConfig)), min_size=14, max_size=14),
       estop=st.booleans(),
       target=st.none() | st.builds("{}:{}".format, st.text(string.ascii_letters, min_size=1,
                                                             max_size=20),
                                    st.integers(1, 65535)))
def test_generated_maps_round_trip(sensors, offsets, gains, configs, estop, target):
    base = default_channel_map()
    ai = tuple(c.model_copy(update={"sensor": s, "offset_v": o, "gain_v_per_unit": g,
                                    "terminal_config": t})
               for c, s, o, g, t in zip(base.ai, sensors, offsets, gains, configs, strict=True))
    cm = base.model_copy(update={
        "ai": ai, "grpc_target": target,
        "estop": EmergencyStopInput(physical_channel="Dev1/port0/line1") if estop else None})
    assert ChannelMap.model_validate(tomllib.loads(cm.to_toml())) == cm


def test_to_toml_writes_nested_tables_and_arrays_of_tables():
    data = {"a": 1, "s": "x\"y\\z\n\x7f\u00e9", "t": {"u": [1.5, 2.0], "v": {"w": True}},
            "rows": [{"k": 1}, {"k": 2, "sub": {"z": "q"}}], "gone": None, "empty": []}
    back = tomllib.loads(to_toml(data))
    assert back == {"a": 1, "s": "x\"y\\z\n\x7f\u00e9", "t": {"u": [1.5, 2.0], "v": {"w": True}},
                    "rows": [{"k": 1}, {"k": 2, "sub": {"z": "q"}}], "empty": []}


def test_every_wiring_mistake_is_named_on_its_own_line():
    d = default_channel_map().model_dump(mode="json")
    d["ai"][3]["physical_channel"] = "Dev1/ai2"  # x2 on x1's terminal
    d["ai"][7]["physical_channel"] = "Dev1/ai6"  # ay on ax's terminal
    d["estop"] = {"physical_channel": "Dev1/port0/line0"}  # the pump's line
    with pytest.raises(ChannelConfigError) as err:
        channel_map_from_dict(d, "rig.toml")
    assert err.value.lines() == [
        "rig.toml: ai[3] (x2): duplicate physical_channel 'Dev1/ai2' (also ai[2] (x1))",
        "rig.toml: ai[7] (ay): duplicate physical_channel 'Dev1/ai6' (also ai[6] (ax))",
        "rig.toml: estop[0] (estop): duplicate physical_channel 'Dev1/port0/line0' "
        "(also do[0] (pump))",
    ]


def test_a_field_error_is_one_line_with_the_file_and_the_field():
    d = default_channel_map().model_dump(mode="json")
    d["ai"][3]["bogus"] = 1
    with pytest.raises(ChannelConfigError) as err:
        channel_map_from_dict(d, "rig.toml")
    assert err.value.lines() == ["rig.toml: ai.3.bogus = 1: Extra inputs are not permitted"]
