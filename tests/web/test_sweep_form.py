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


def _number_fields(s: dict, props: dict, prefix: str = "") -> dict[str, dict]:
    """The properties of the schema ``s`` that hold numbers (alone, optional or in a list), by
    dotted path, read from the JSON schema itself (the types the page builds its inputs from)."""
    out = {}
    for name, prop in props.items():
        alts = prop.get("anyOf", [prop])
        if any("$ref" in a for a in alts):
            ref = next(a["$ref"] for a in alts if "$ref" in a).rsplit("/", 1)[-1]
            out.update(_number_fields(s, s["$defs"][ref]["properties"], f"{prefix}{name}."))
            continue
        types = {a.get("type") for a in alts} | {a.get("items", {}).get("type") for a in alts}
        if types & {"number", "integer"}:
            out[prefix + name] = prop
    return out


def test_every_number_field_of_a_sweep_has_its_unit_and_the_form_shows_it_so():
    """Every number field of the sweep (the model's own schema, 32 of them) has a unit, and the
    form shows it in the unit an operator reads: lengths in um (value x 1e6), every other in its
    own unit (a stiffness of 1e6 N/m is 1000000 N/m, never um)."""
    from control.wire.sweep_spec import field_units
    from web.sweep_form import schema

    s = schema()
    numbers = _number_fields(s, s["properties"])
    assert len(numbers) == 32 and set(numbers) == set(field_units())
    for path, prop in numbers.items():
        si = prop["unit"]
        assert si == field_units()[path]
        assert (prop["shown_unit"], prop["shown_power"]) == (("um", 6) if si == "m" else (si, 0))
    units = field_units()
    assert units["control.initial_stiffness_n_per_m"] == "N/m"
    assert units["control.nominal_damping_ns_per_m"] == "N.s/m"
    assert units["control.lubricated_damping_ns_per_m"] == "N.s/m"
    assert units["amplitude_m"] == "m" and units["load_n"] == "N"
    assert units["control.block_s"] == "s" and units["freq_points"] == ""
    # the only lengths are the displacement targets: nothing else is shown x 1e6
    assert [p for p, u in units.items() if u == "m"] == ["amplitude_m"]
