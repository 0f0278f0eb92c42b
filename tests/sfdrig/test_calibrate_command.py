"""`sfdrig calibrate` and `--rig NAME` refuse bad inputs in one line; the named rigs load."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig_model.params import RigParams, rig_params_named_or_file
from sfdrig.cli import main


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("command", ["calibrate", "demo"])
def test_missing_rig_file_is_one_line(command: str, tmp_path: Path, capsys):
    missing = tmp_path / "nope.toml"
    assert main([command, "--rig", str(missing), "--out", str(tmp_path / "o")]) == 2
    err = _one_line_error(capsys)
    assert str(missing) in err and "cannot read" in err


def test_invalid_rig_field_is_one_line_naming_it(tmp_path: Path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text("[seal]\ncontact_stiffness_n_per_m = -5.0\n")
    assert main(["calibrate", "--rig", str(rig), "--out", str(tmp_path / "o")]) == 2
    err = _one_line_error(capsys)
    assert "contact_stiffness_n_per_m" in err and str(rig) in err


def test_out_that_is_a_file_is_one_line(tmp_path: Path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["calibrate", "--out", str(blocker / "sub"), "--compare-only"]) == 2
    assert str(blocker / "sub") in _one_line_error(capsys)


def test_unknown_plan_is_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "--plan", "huge"])
    assert exc.value.code == 2
    assert "invalid choice: 'huge'" in capsys.readouterr().err


def test_named_rigs():
    assert rig_params_named_or_file("nominal") == RigParams()
    report = rig_params_named_or_file("report")
    assert report != RigParams()
    # the calibrated rig keeps the report's film geometry and oil; it changes fitted terms only
    assert report.film.clearance_m == RigParams().film.clearance_m
    assert report.seal.contact_stiffness_n_per_m is not None


def test_structure_on_the_named_report_rig_identifies_its_springs(tmp_path: Path, capsys):
    from analysis.identify import identify

    assert main(["structure", "--unattended", "--rig", "report", "--only", "static",
                 "--out", str(tmp_path)]) == 0
    report = rig_params_named_or_file("report").structure
    ident = identify(sorted(tmp_path.glob("*-static.h5")))
    k = {f.axis: f.k_n_per_m for f in ident.static}
    assert k["x"] == pytest.approx(report.stiffness_x_n_per_m, rel=0.01)
    assert k["y"] == pytest.approx(report.stiffness_y_n_per_m, rel=0.01)
    # not the nominal rig: the report rig's rods are Table 2's 786 kN/m in Y (the nominal 823),
    # its relaxing stiffness (issue 28) relaxed under the held loads
    assert k["y"] < 0.97 * RigParams().structure.stiffness_y_n_per_m


@pytest.mark.slow
def test_calibrate_from_nominal_fits_the_issue28_terms(tmp_path: Path, capsys):
    """The whole command on the reduced plan (seed 3) from the nominal rig: it fits the three
    terms issue 28 added (they were fitted by hand before) and every row holds on the fixed
    bands. Measured 2026-11-26: fit rows 12 -> 24 of 24, held-out rows 1 -> 5 of 5; k_r in Y
    135.8 kN/m (the impact's 921 against the static 786; in X the two agree within Table 2's
    band, so one spring), contact 33.0 / 21.6 MN/m, wet friction +2.76 N."""
    import json

    from analysis.calibration.compare import Comparison
    from tests.analysis.test_calibration import holds

    out = tmp_path / "cal"
    assert main(["calibrate", "--plan", "reduced", "--seed", "3", "--out", str(out)]) == 0
    cal = json.loads((out / "calibration.json").read_text())
    fitted = {t["name"]: t["fitted"] for t in cal["terms"]}
    assert fitted["effects.relaxing_stiffness.stiffness_y_n_per_m"] == pytest.approx(137e3,
                                                                                     rel=0.05)
    assert fitted["effects.relaxing_stiffness.stiffness_x_n_per_m"] == 0.0
    assert 2e7 < fitted["seal.contact_stiffness_y_n_per_m"] < fitted[
        "seal.contact_stiffness_n_per_m"] < 5e7
    assert 1.0 < fitted["seal.wet_friction_increase_n"] < 4.0
    rows = [Comparison(r["table"], r["quantity"], r["axis"], r["unit"], r["report"],
                       r["calibrated"], r["calibrated_band"], "") for r in cal["comparisons"]]
    assert len(rows) == 29
    missed = [r.key for r in rows if not holds(r)]
    assert missed == []
    rig = rig_params_named_or_file(str(out / "calibrated-rig.toml"))
    assert rig.effects.relaxing_stiffness.enabled
    assert rig.structure.stiffness_y_n_per_m == pytest.approx(786e3, rel=0.01)
