"""`sfdrig sweep --set`: an override of the frequencies or the target replaces whichever form
the sweep file used (issue 21: `--set 'freq_hz=[40.0]'` over a file with a range was refused,
"not both")."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from control.wire.sweep_spec import SweepSpec
from sfdrig.commands.sweep import sweep_fields

RANGE = """
motion = "x"
amplitude_m = [13e-6]
freq_start_hz = 20.0
freq_stop_hz = 60.0
freq_step_hz = 10.0
"""
LIST = """
motion = "x"
load_n = [30.0]
freq_hz = [20.0, 30.0]
"""


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    out = {}
    for name, text in (("range", RANGE), ("list", LIST)):
        out[name] = tmp_path / f"{name}.toml"
        out[name].write_text(text)
    return out


def test_a_frequency_list_replaces_the_files_range(files):
    assert SweepSpec.model_validate(sweep_fields(files["range"], [])).frequencies() == \
        [20.0, 30.0, 40.0, 50.0, 60.0]
    spec = SweepSpec.model_validate(sweep_fields(files["range"], ["freq_hz=[40.0]"]))
    assert spec.frequencies() == [40.0] and spec.targets == [13e-6]


def test_a_range_replaces_the_files_list_and_points_replace_a_step(files):
    spec = SweepSpec.model_validate(sweep_fields(
        files["list"], ["freq_start_hz=10.0", "freq_stop_hz=100.0", "freq_points=3",
                        "spacing='log'"]))
    assert spec.frequencies() == pytest.approx([10.0, 31.6227766, 100.0])
    spec = SweepSpec.model_validate(sweep_fields(files["range"], ["freq_points=3"]))
    assert spec.frequencies() == [20.0, 40.0, 60.0]


def test_a_target_kind_replaces_the_files_other_kind(files):
    spec = SweepSpec.model_validate(sweep_fields(files["range"], ["load_n=[25.0]"]))
    assert (spec.target_kind, spec.targets) == ("load", [25.0])
    spec = SweepSpec.model_validate(sweep_fields(files["list"], ["amplitude_m=[20e-6]"]))
    assert (spec.target_kind, spec.targets) == ("displacement", [20e-6])


def test_both_forms_given_on_the_command_line_are_still_refused(files):
    fields = sweep_fields(files["list"], ["freq_hz=[40.0]", "freq_start_hz=10.0"])
    with pytest.raises(ValidationError, match="not both"):
        SweepSpec.model_validate(fields)
