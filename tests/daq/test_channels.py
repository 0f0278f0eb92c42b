"""Channel map and calibration: the report's rig as default, TOML round trip, bad input named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from daq import ChannelConfigError, ChannelKind, default_channel_map, load_channel_map
from daq.channels import channel_map_from_dict

MIL = 25.4e-6


def _as_dict():
    return default_channel_map().to_json_dict()


def test_default_map_is_the_reports_rig():
    cm = default_channel_map()
    assert cm.ai_names[:13] == ["fx", "fy", "x1", "x2", "y1", "y2", "ax", "ay", "p_in", "p_rec",
                                "q_in", "q_out", "t_oil"]
    # Table A1 probe gains, mV/mil -> V/m
    assert cm.ai_channel("x1").gain_v_per_unit * MIL == pytest.approx(0.202)
    assert cm.ai_channel("x2").gain_v_per_unit * MIL == pytest.approx(0.195)
    assert cm.ai_channel("y1").gain_v_per_unit * MIL == pytest.approx(0.204)
    assert [c.axis for c in cm.ao] == ["x", "y"]
    assert cm.relay("pump").physical_channel == "Dev1/port0/line0"
    assert len(cm.ai_of_kind(ChannelKind.EDDY_CURRENT_PROBE)) == 4


def test_calibration_round_trip_volts_units():
    cm = default_channel_map()
    values = np.array([[100.0], [-50.0], [25e-6], [25e-6], [0.0], [0.0], [9.8], [0.0],
                       [15.5e3], [5.7e3], [0.5], [0.5], [24.0], [0.0]])
    volts = np.array([[c.to_volts(v[0])] for c, v in zip(cm.ai, values, strict=True)])
    assert volts[2, 0] == pytest.approx(0.202 * 25e-6 / MIL)  # ~0.199 V for 25 um
    assert volts[8, 0] == pytest.approx(1.0 + 4.0 * 15.5e3 / 206_843.0)  # 4-20 mA: 1-5 V
    np.testing.assert_allclose(cm.to_engineering(volts), values, rtol=1e-12)


def test_toml_file_loads(tmp_path: Path):
    text = """
sample_rate_hz = 5000.0
[[ai]]
name = "fx"
physical_channel = "Dev1/ai0"
kind = "load_cell"
units = "N"
gain_v_per_unit = 0.02
[[ai]]
name = "x1"
physical_channel = "Dev1/ai1"
kind = "eddy_current_probe"
units = "m"
gain_v_per_unit = 7950.0
[[ao]]
name = "shaker_x"
physical_channel = "Dev1/ao0"
axis = "x"
[[do]]
name = "pump"
physical_channel = "Dev1/port0/line0"
"""
    p = tmp_path / "channels.toml"
    p.write_text(text)
    cm = load_channel_map(p)
    assert cm.sample_rate_hz == 5000.0
    assert cm.ai_names == ["fx", "x1"]


@pytest.mark.parametrize(
    "mutate,expect",
    [
        (lambda d: d["ai"][1].update(physical_channel="Dev1/ai0"),
         "duplicate physical_channel 'Dev1/ai0'"),
        (lambda d: d["ai"][0].update(units="lbf"), "units 'lbf' not allowed for kind 'load_cell'"),
        (lambda d: d["ai"][0].update(kind="strain_gauge"), "ai.0.kind"),
        (lambda d: d["ai"][2].update(gain_v_per_unit=0.0), "ai.2.gain_v_per_unit = 0.0"),
        (lambda d: d["ai"][3].update(gain_v_per_unit=-7.0), "ai.3.gain_v_per_unit = -7.0"),
        (lambda d: d["ao"][0].update(range_v=[-12.0, 12.0]), "exceeds the board's +/-10 V"),
        (lambda d: d.update(sample_rate_hz=2.0e6), "sample_rate_hz = 2e+06 is outside"),
        (lambda d: d.update(sample_rate_hz=-1.0), "sample_rate_hz = -1.0"),
        (lambda d: d["ai"][0].update(physical_channel="Dev1/ai99"),
         "'Dev1/ai99' is not a AI channel of device Dev1"),
        (lambda d: d["ao"][1].update(axis="x"),
         "ao[1] (shaker_y): axis 'x' is driven by ao[0] (shaker_x) already"),
        (lambda d: d["ai"][4].update(name="X 1"), "ai.4.name = 'X 1'"),
        (lambda d: d["ai"][5].update(kind="relay"), "kind 'relay' is not an analog-input kind"),
    ],
)
def test_bad_channel_maps_are_refused_naming_field_and_value(mutate, expect):
    d = _as_dict()
    mutate(d)
    with pytest.raises(ChannelConfigError) as err:
        channel_map_from_dict(d, "rig.toml")
    assert "rig.toml" in str(err.value)
    assert expect in str(err.value)


def test_unreadable_and_malformed_toml(tmp_path: Path):
    with pytest.raises(ChannelConfigError, match="cannot read"):
        load_channel_map(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("sample_rate_hz = = 3\n")
    with pytest.raises(ChannelConfigError, match="bad.toml: not valid TOML"):
        load_channel_map(bad)
