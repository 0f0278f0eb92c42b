"""The sweep description: TOML, frequency lists and ranges, clear errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from control.run.sweep.engine import SweepSpec, load_sweep_spec, sweep_spec_from_dict
from control.wire.errors import SpecError, TargetError

REPORT_TOML = """
name = "lubricated X, 13-38 um"
motion = "x"
lubricated = true
amplitude_m = [13e-6, 19e-6, 25e-6, 32e-6, 38e-6]
freq_start_hz = 20.0
freq_stop_hz = 60.0
freq_step_hz = 10.0
settle_cycles = 12
record_cycles = 50
tolerance_amplitude_pct = 1.0
tolerance_phase_deg = 1.0
max_updates = 6

[control]
window_cycles = 3
"""


def test_report_sweep_from_toml(tmp_path):
    path = tmp_path / "sweep.toml"
    path.write_text(REPORT_TOML)
    spec = load_sweep_spec(path)
    assert spec.target_kind == "displacement" and spec.lubricated
    assert spec.frequencies() == [20.0, 30.0, 40.0, 50.0, 60.0]
    steps = spec.steps()
    assert len(steps) == 25
    assert [s.target_value for s in steps[:6]] == [13e-6] * 5 + [19e-6]
    assert spec.control.window_cycles == 3 and spec.max_updates == 6
    assert spec.ideal_step_s(20.0) == pytest.approx(62 / 20.0)


def test_frequency_forms():
    base = {"motion": "x", "load_n": [10.0, 20.0]}
    down = SweepSpec.model_validate({**base, "freq_start_hz": 200, "freq_stop_hz": 20,
                                     "freq_step_hz": 10})
    assert down.frequencies()[:3] == [200.0, 190.0, 180.0] and down.frequencies()[-1] == 20.0
    log = SweepSpec.model_validate({**base, "freq_start_hz": 20, "freq_stop_hz": 200,
                                    "freq_points": 5, "spacing": "log"})
    np.testing.assert_allclose(log.frequencies(), np.geomspace(20, 200, 5))
    listed = SweepSpec.model_validate({**base, "freq_hz": [50, 30, 70],
                                       "order": "frequency_major"})
    assert [(s.freq_hz, s.target_value) for s in listed.steps()[:3]] == [
        (50.0, 10.0), (50.0, 20.0), (30.0, 10.0)]


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"motion": "x", "freq_hz": [20.0]}, "exactly one of amplitude_m"),
        ({"motion": "x", "amplitude_m": [1e-5], "load_n": [3.0], "freq_hz": [20.0]},
         "exactly one of amplitude_m"),
        ({"motion": "x", "amplitude_m": [1e-5]}, "give freq_hz"),
        ({"motion": "x", "amplitude_m": [1e-5], "freq_hz": [20.0], "freq_start_hz": 10},
         "not both"),
        ({"motion": "x", "amplitude_m": [1e-5], "freq_start_hz": 10, "freq_stop_hz": 20},
         "exactly one of freq_step_hz or freq_points"),
        ({"motion": "x", "amplitude_m": [1e-5], "freq_start_hz": 10, "freq_stop_hz": 20,
          "freq_step_hz": 1, "spacing": "log"}, "log spacing needs freq_points"),
        ({"motion": "spiral", "amplitude_m": [1e-5], "freq_hz": [20.0]}, "motion = 'spiral'"),
        ({"motion": "x", "amplitude_m": [1e-5], "freq_hz": [-20.0]}, "freq_hz.0 = -20.0"),
        ({"motion": "x", "amplitude_m": [1e-5], "freq_hz": [20.0], "settle": 3},
         "settle = 3: Extra inputs are not permitted"),
    ],
)
def test_bad_specs_name_the_field(data, message):
    with pytest.raises(SpecError, match="invalid sweep spec in <dict>") as info:
        sweep_spec_from_dict(data)
    assert message in str(info.value)
    assert isinstance(info.value, TargetError) and isinstance(info.value, ValueError)


def test_bad_toml_names_the_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("motion = \n")
    with pytest.raises(SpecError, match="bad.toml: not valid TOML"):
        load_sweep_spec(path)
    with pytest.raises(SpecError, match="cannot read"):
        load_sweep_spec(tmp_path / "missing.toml")


@given(
    f0=st.floats(1.0, 1000.0), f1=st.floats(1.0, 1000.0), step=st.floats(0.5, 200.0),
)
def test_linear_ranges_stay_inside_and_are_evenly_stepped(f0, f1, step):
    spec = SweepSpec.model_validate({"motion": "y", "load_n": [5.0], "freq_start_hz": f0,
                                     "freq_stop_hz": f1, "freq_step_hz": step})
    fr = np.array(spec.frequencies())
    assert fr[0] == pytest.approx(f0)
    lo, hi = min(f0, f1), max(f0, f1)
    assert np.all((fr >= lo - 1e-6) & (fr <= hi + 1e-6))
    if fr.size > 1:
        np.testing.assert_allclose(np.abs(np.diff(fr)), step, rtol=1e-6, atol=1e-6)
    assert abs(abs(fr[-1] - f0) - abs(f1 - f0)) < step + 1e-6


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ({"load_n": ["20"]}, "load_n.0 = '20': Input should be a valid number"),
        ({"load_n": [True]}, "load_n.0 = True: Input should be a valid number"),
        ({"settle_cycles": True}, "settle_cycles = True: Input should be a valid integer"),
        ({"lubricated": "no"}, "lubricated = 'no': Input should be a valid boolean"),
        ({"record_cycles": 40.0}, "record_cycles = 40.0: Input should be a valid integer"),
        ({"control": {"initial_stiffness_n_per_m": float("inf")}},
         "control.initial_stiffness_n_per_m = inf: Input should be a finite number"),
        ({"control": {"predict": 1}}, "control.predict = 1: Input should be a valid boolean"),
        ({"name": "a\x00b"}, "name"),
    ],
)
def test_strict_types_and_finite_numbers(extra, message):
    with pytest.raises(SpecError) as info:
        sweep_spec_from_dict({"motion": "x", "load_n": [20.0], "freq_hz": [30.0], **extra})
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ({"freq_start_hz": 20, "freq_stop_hz": 1e308, "freq_step_hz": 50},
         "2e+306 frequencies); at most 10,000"),
        ({"freq_start_hz": 20, "freq_stop_hz": 200, "freq_step_hz": 1.8e-4},
         "1e+06 frequencies); at most 10,000"),
        ({"freq_hz": [5.0] * 3, "settle_cycles": 100_000, "record_cycles": 100_000},
         "settles and records for 33.33 h; at most 24 h"),
    ],
)
def test_the_work_of_a_sweep_is_bounded_before_it_is_listed(extra, message):
    with pytest.raises(SpecError) as info:
        sweep_spec_from_dict({"motion": "x", "load_n": [20.0], **extra})
    assert message in str(info.value)


def test_the_largest_sweep_allowed_lists_quickly():
    spec = sweep_spec_from_dict({"motion": "x", "load_n": [20.0, 30.0], "freq_start_hz": 20,
                                 "freq_stop_hz": 500, "freq_points": 5000, "record_cycles": 10,
                                 "settle_cycles": 2})
    assert len(spec.steps()) == 10_000 == spec.frequency_count() * 2
