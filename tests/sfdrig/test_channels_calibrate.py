"""`sfdrig channels calibrate`: calibration run files (made by the real programmes on the
simulated rig) flow back into the channel map with a diff and the operator's confirmation; a
gauge entry the probes contradict is questioned and left out."""

from __future__ import annotations

import io
import re
from pathlib import Path

import pytest

from control.run.files import create_run_writer
from control.run.programs.operator import Question
from control.run.programs.procedures import run_probe_calibration, run_static_test
from control.run.programs.specs import ProbeCalSpec, StaticSpec
from daq.channels import load_channel_map
from rig_model.params import RigParams
from sfdrig.cli import main
from sfdrig.simulated_operator import SimulatedHands, StandInOperator
from simulated_hw.backend import SimulatedBackend
from tests.conftest import REPO_ROOT

EXAMPLE = REPO_ROOT / "examples" / "channels_report_rig.toml"
MIL = 25.4e-6


class Mistyping(StandInOperator):
    """Types the first x gauge reading as ``0.0010 in`` (the housing is at about -76 um
    there: -60 N on 788 kN/m), every other reading as the gauge shows it."""

    def __init__(self) -> None:
        super().__init__()
        self.typed = False

    def post(self, question: Question) -> Question:
        if question.entry is not None and not self.typed:
            self.typed = True
            question = question.model_copy(update={"shows": "0.0010 in"})
        return super().post(question)


@pytest.fixture(scope="module")
def probe_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A probe calibration of the example map's rig, x1 reading 10 % high, one entry wrong."""
    path = tmp_path_factory.mktemp("cal") / "probe_cal.h5"
    params = RigParams()
    params.seal.enabled = False
    params.effects.probe_gain_error.enabled = True
    params.effects.probe_gain_error.channel = "x1"
    params.effects.probe_gain_error.gain_ratio = 1.10
    be = SimulatedBackend(params, seed=7)
    be.configure(load_channel_map(EXAMPLE))
    writer = create_run_writer(path, "probe_calibration", be.channel_map, run_id="cal",
                               rig_config=params)
    out = run_probe_calibration(be, writer, Mistyping(), ProbeCalSpec(),
                                hands=SimulatedHands(be, seed=7))
    writer.close()
    assert out.completed
    return path


def _map(tmp_path: Path) -> Path:
    path = tmp_path / "map.toml"
    path.write_text(EXAMPLE.read_text())
    return path


def test_probe_gains_flow_back_and_the_wrong_entry_is_questioned(
        probe_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    map_path = _map(tmp_path)
    assert main(["channels", "calibrate", str(probe_run), "--map", str(map_path), "--yes"]) == 0
    out = capsys.readouterr().out
    (question,) = [line for line in out.splitlines() if line.startswith("QUESTION")]
    m = re.search(r"step 1 \(x\): the gauge entry '0.0010 in' \(\+25.4 um\) while the probes "
                  r"read (-\d+\.\d) um \(x1 -\d+\.\d, x2 -\d+\.\d um\): the sign and the size "
                  r"disagree \((-0\.00\d+) in would match\); left out of the fit "
                  r"\(--keep-step 1 keeps it\)", question)
    assert m, question
    # -60 N on 788 kN/m is -76.1 um; x1 reads it 10 % high: the probes' mean is -79.9 um
    assert float(m.group(1)) == pytest.approx(-79.9, abs=1.5)
    assert float(m.group(2)) == pytest.approx(-79.9e-6 / 0.0254, abs=1e-4)
    changes = [line for line in out.splitlines() if line.startswith("change")]
    assert len(changes) == 1 and changes[0].startswith("change ai x1: gain_v_per_unit = ")
    new = load_channel_map(map_path)
    old = load_channel_map(EXAMPLE)
    assert new.ai_channel("x1").gain_v_per_unit / old.ai_channel("x1").gain_v_per_unit == \
        pytest.approx(1.10, rel=0.01)
    for name in ("x2", "y1", "y2"):
        assert new.ai_channel(name) == old.ai_channel(name)
    text = map_path.read_text()
    assert text.count("\n#") == EXAMPLE.read_text().count("\n#")  # its comments kept
    assert "-gain_v_per_unit = 7952.755905511811\n+gain_v_per_unit = " in out


def test_keeping_the_wrong_entry_spoils_the_fit(probe_run: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    map_path = _map(tmp_path)
    assert main(["channels", "calibrate", str(probe_run), "--map", str(map_path), "--yes",
                 "--keep-step", "1"]) == 0
    out = capsys.readouterr().out
    assert "kept in the fit (--keep-step)" in out
    (x1,) = [line for line in out.splitlines() if line.startswith("note x1:")]
    assert re.search(r"R\^2 0\.\d+, .*: R\^2 under 0.99, not proposed", x1), x1
    assert map_path.read_text() == EXAMPLE.read_text()


def test_without_confirmation_nothing_is_written(probe_run: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    map_path = _map(tmp_path)
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["channels", "calibrate", str(probe_run), "--map", str(map_path)]) == 1
    out = capsys.readouterr().out
    assert "write 1 change to" in out and out.rstrip().endswith(f"{map_path}: not written")
    assert map_path.read_text() == EXAMPLE.read_text()


def test_a_static_test_by_the_shakers_gives_the_drives_gain(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = RigParams()
    params.seal.enabled = False
    params.shaker.force_per_volt_n = 62.0  # the amplifier's knob; the map says 50 N/V
    be = SimulatedBackend(params, seed=2)
    be.configure(load_channel_map(EXAMPLE))
    run = tmp_path / "static.h5"
    writer = create_run_writer(run, "static", be.channel_map, run_id="st", rig_config=params)
    spec = StaticSpec(forces_n=(-60.0, -30.0, 30.0, 60.0), repeats=1, record_s=0.3)
    assert run_static_test(be, writer, spec).completed
    writer.close()
    map_path = _map(tmp_path)
    out_path = tmp_path / "new.toml"
    assert main(["channels", "calibrate", str(run), "--map", str(map_path), "--yes",
                 "--out", str(out_path)]) == 0
    new = load_channel_map(out_path)
    for ao in new.ao:
        assert ao.nominal_force_n_per_v == pytest.approx(62.0, rel=0.01)
    assert map_path.read_text() == EXAMPLE.read_text()
    assert "change ao shaker_x: nominal_force_n_per_v = 62" in capsys.readouterr().out


@pytest.mark.parametrize("args,line", [
    (["missing.h5"], r"channels calibrate: .*missing\.h5"),
    (["SWEEP"], r"channels calibrate: .*: a 'sweep' run holds no calibration for the channel "
                r"map \(give a probe_calibration or a static run\)"),
])
def test_bad_inputs_are_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                        args: list[str], line: str) -> None:
    if args == ["SWEEP"]:
        be = SimulatedBackend(RigParams())
        be.configure(load_channel_map(EXAMPLE))
        create_run_writer(tmp_path / "sweep.h5", "sweep", be.channel_map, run_id="s").close()
        args = [str(tmp_path / "sweep.h5")]
    assert main(["channels", "calibrate", *args, "--map", str(EXAMPLE)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and re.match(line, err), err


@pytest.mark.parametrize("kept,line", [
    ("0", r"channels calibrate: .*probe_cal\.h5: --keep-step 0: no such step \(the run has "
          r"\d+, counted from 1\)"),
    ("99", r"channels calibrate: .*probe_cal\.h5: --keep-step 99: no such step"),
])
def test_a_kept_step_the_run_lacks_is_refused(probe_run: Path, tmp_path: Path, kept: str,
                                              line: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Steps are counted from 1, as the QUESTION lines show them; 0 or past the last is a typo,
    refused before anything is fitted or written."""
    map_path = _map(tmp_path)
    assert main(["channels", "calibrate", str(probe_run), "--map", str(map_path), "--yes",
                 "--keep-step", kept]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and re.match(line, err), err
    assert map_path.read_text() == EXAMPLE.read_text()
