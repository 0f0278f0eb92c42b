"""The page's sweep check: the sweep model's own verdict by field, and the summary in numbers."""

from __future__ import annotations

import tomllib

import pytest

from control.wire.sweep_spec import SweepSpec
from web.sweep_form import check

SAFETY = {"displacement_limit_m": 63.5e-6, "load_limit_n": 448.0, "drive_limit_v": 9.0,
          "radial_clearance_m": 127e-6}


def test_a_valid_sweep_is_summarised_and_written_as_the_toml_sweep_reads():
    spec = {"name": "lub X", "motion": "x", "lubricated": True, "amplitude_m": [13e-6, 25e-6],
            "freq_start_hz": 20.0, "freq_stop_hz": 60.0, "freq_step_hz": 10.0,
            "settle_cycles": 10, "record_cycles": 40, "control": {"window_cycles": 3}}
    out = check(spec, SAFETY)
    assert out["ok"] and out["errors"] == []
    m = out["summary"]
    assert m["steps"] == 10 and m["frequencies"] == 5 and m["pump"] == "on"
    assert m["targets"] == pytest.approx([13.0, 25.0]) and m["target_unit"] == "um"
    # 2 targets x 50 cycles at 20, 30, 40, 50, 60 Hz
    assert m["settle_record_s"] == pytest.approx(2 * 50 * (1/20 + 1/30 + 1/40 + 1/50 + 1/60))
    assert (m["freq_first_hz"], m["freq_last_hz"]) == (20.0, 60.0)
    assert m["limits"]["load_limit_n"] == 448.0
    back = SweepSpec.model_validate(tomllib.loads(out["toml"]))
    assert back == SweepSpec.model_validate(spec)
    assert "window_cycles = 3" in out["toml"] and "settle_cycles" not in out["toml"]


@pytest.mark.parametrize(("spec", "errors"), [
    ({"load_n": [40.0], "freq_hz": [70.0, -5.0]},
     [("freq_hz.1", "Input should be greater than 0 (got -5.0)")]),
    ({"load_n": [40.0], "freq_hz": [70.0], "motion": "z", "control": {"block_s": 1.0}},
     [("motion", "Input should be 'x', 'y', 'circular_forward', 'circular_backward' or "
                 "'elliptical' (got z)"),
      ("control.block_s", "Input should be less than or equal to 0.02 (got 1.0)")]),
    ({"load_n": [40.0], "freq_hz": [70.0], "settle_cycles": "10"},
     [("settle_cycles", "Input should be a valid integer (got 10)")]),
    ({"load_n": [40.0], "amplitude_m": [1e-5], "freq_hz": [70.0]},
     [("", "give exactly one of amplitude_m (hold displacement) or load_n (hold load)")]),
    ([1, 2, 3], [("", "a sweep is a table of fields")]),
])
def test_each_problem_is_named_by_its_field(spec, errors):
    out = check(spec, SAFETY)
    assert not out["ok"] and out["summary"] is None
    assert [(e["field"], e["message"]) for e in out["errors"]] == errors
