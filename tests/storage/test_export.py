"""`sfdrig export` and the round trip back through `sfdrig import`, on run files from the simulated
rig (a lubricated X sweep through the real sweep engine, a static test with steps at 0 Hz), and
run files that explain themselves (format_version 2) to a reader without our code."""

from __future__ import annotations

import ast
import csv
import json
import math
import re
import shlex
import subprocess
import sys
import tempfile
import tomllib
from datetime import UTC, datetime
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
from hypothesis import given
from hypothesis import strategies as st
from nptdms import TdmsFile

from control.run.files import create_run_writer
from control.run.programs.procedures import StaticSpec, run_static_test
from control.run.pump import PumpRelay
from control.run.sweep.engine import SweepEngine, SweepSpec
from daq.channels import default_channel_map
from rig_model.params import RigParams
from sfdrig.cli import main
from simulated_hw.backend import SimulatedBackend
from storage import RunWriter, open_run
from storage.errors import ExportError
from storage.exporters import column_name, export_run
from storage.exporters.common import select
from storage.exporters.mat_format import write_mat
from storage.importers import import_file
from storage.importers.conditions import read_conditions_file, resolve_conditions
from storage.records import StepRecord
from tests.storage import doc_reader

FORMATS = ("csv", "mat", "tdms")


def _backend(seed: int) -> SimulatedBackend:
    b = SimulatedBackend(RigParams(), seed=seed)
    b.configure(default_channel_map())
    return b


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("export_runs")
    b = _backend(seed=3)
    spec = SweepSpec(motion="x", lubricated=True, amplitude_m=[25e-6], freq_hz=[30.0, 50.0],
                     settle_cycles=10, record_cycles=10)
    w = create_run_writer(d / "lub.h5", "sweep", b.channel_map, run_id="lub-1",
                          rig_config=RigParams(), test_spec=spec, lubricated=True)
    pump = PumpRelay(b)
    pump.set(True)
    out = SweepEngine(b, spec, listener=w, pump=pump).run()
    pump.set(False)
    w.close(out.status, out.reason)
    assert out.status == "completed", out.reason
    b = _backend(seed=4)
    w = create_run_writer(d / "static.h5", "static", b.channel_map, run_id="st-1",
                          rig_config=RigParams())
    assert run_static_test(b, w, StaticSpec(axes=("x",), forces_n=(-40.0, 40.0), repeats=1,
                                            record_s=0.2)).completed
    w.close()
    return {"lub": d / "lub.h5", "static": d / "static.h5"}


def _same_run(a_path: Path, b_path: Path) -> None:
    """Same samples (bit for bit), channel attributes, steps with harmonics, events and
    conditions."""
    with open_run(a_path) as a, open_run(b_path) as b:
        assert b.channel_names == a.channel_names and b.drive_names == a.drive_names
        assert b.n_samples == a.n_samples > 0
        for c in a.channel_names + a.drive_names:
            assert np.array_equal(a.channel(c), b.channel(c), equal_nan=True), c
            assert json.dumps(b.channel_attrs(c), sort_keys=True) == json.dumps(
                a.channel_attrs(c), sort_keys=True), c
        assert json.dumps(b.steps) == json.dumps(a.steps)  # NaN targets of imported dwells too
        assert b.events == a.events
        for key in ("run_id", "kind", "lubricated", "status", "status_reason", "start_time",
                    "stop_time", "sample_rate_hz", "operator", "notes"):
            assert b.attrs[key] == a.attrs[key], key
        assert (b.channel_map, b.rig_config, b.test_spec) == (a.channel_map, a.rig_config,
                                                              a.test_spec)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("which", ["lub", "static"])
def test_round_trip(runs: dict[str, Path], tmp_path: Path, fmt: str, which: str) -> None:
    files = export_run(runs[which], fmt, tmp_path / "out")
    back = import_file(files[0], tmp_path / "back.h5")
    _same_run(runs[which], back)
    with open_run(back) as b, open_run(runs[which]) as a:
        assert json.loads(b.attrs["imported_from"])["run_id"] == a.run_id


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_of_an_imported_run(tmp_path: Path, fmt: str) -> None:
    """Data from elsewhere (no targets: NaN; conditions with their sources in test_spec) goes
    out and comes back with its conditions."""
    fs, n = 2000.0, 6000
    t = np.arange(n) / fs
    freq = np.where(t < 1.5, 20.0, 40.0)
    rng = np.random.default_rng(7)
    x = 20e-6 * np.sin(2 * np.pi * freq * t) + 1e-8 * rng.standard_normal(n)
    fx = 60.0 * np.sin(2 * np.pi * freq * t + 0.3)
    src = tmp_path / "lab.csv"
    src.write_text("time_s,freq_hz,fx_N,x_m\n" + "\n".join(
        f"{a!r},{f!r},{b!r},{c!r}" for a, f, b, c in zip(t.tolist(), freq.tolist(), fx.tolist(),
                                                         x.tolist(), strict=True)) + "\n")
    cond = resolve_conditions(src, lubricated=True, motion="x", seal="none")
    run = import_file(src, tmp_path / "lab.h5", conditions=cond)
    (path,) = export_run(run, fmt, tmp_path / "out")[:1]
    back = import_file(path, tmp_path / "back.h5")
    _same_run(run, back)
    with open_run(back) as b:
        assert b.test_spec["conditions"]["seal"] == "none"
        assert math.isnan(b.steps[0]["target_value"]) and b.steps[1]["freq_hz"] == 40.0


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_of_one_step_and_two_channels(runs: dict[str, Path], tmp_path: Path,
                                                 fmt: str) -> None:
    """The restored run starts at the step's first sample; its harmonics are re-referred to that
    time and still describe its samples (fitted here without our code)."""
    files = export_run(runs["lub"], fmt, tmp_path / "out", steps="2", channels=["fx,x1"])
    back = import_file(files[0], tmp_path / "back.h5")
    with open_run(runs["lub"]) as a, open_run(back) as b:
        step = a.steps[1]
        s0, s1 = step["first_sample"], step["last_sample"]
        assert b.channel_names == ["fx", "x1"] and b.drive_names == a.drive_names
        assert b.n_samples == s1 - s0
        assert np.array_equal(b.channel("x1"), a.channel("x1", s0, s1))
        assert np.array_equal(b.channel("shaker_x"), a.channel("shaker_x", s0, s1))
        (st,) = b.steps
        assert (st["first_sample"], st["last_sample"], st["index"]) == (0, s1 - s0, 1)
        assert abs(st["harmonics"]["x1"][0][0] + 1j * st["harmonics"]["x1"][0][1]) == \
            pytest.approx(abs(complex(*step["harmonics"]["x1"][0])), rel=1e-12)
        assert b.attrs["lubricated"] is True or b.attrs["lubricated"] == 1
    rebuilt, stored, _ = doc_reader.step_harmonics_from_samples(back, "x1", 0)
    assert np.max(np.abs(rebuilt - stored)) < 1e-11 * np.max(np.abs(stored))


def test_mat_v5_reads_in_scipy(runs: dict[str, Path], tmp_path: Path) -> None:
    (path,) = export_run(runs["lub"], "mat", tmp_path)
    m = scipy.io.loadmat(path, squeeze_me=True)
    with open_run(runs["lub"]) as r:
        assert m["Fs"] == r.sample_rate_hz
        assert np.array_equal(m["x1_m"], r.channel("x1"))
        assert np.array_equal(m["fx_N"], r.channel("fx"))
        assert np.array_equal(m["shaker_x_V"], r.channel("shaker_x"))
        assert m["time_s"][1] - m["time_s"][0] == pytest.approx(1 / r.sample_rate_hz)
        ch = m["channels"]
        names = list(ch["channel"].item())
        k = names.index("x1")
        assert ch["units"].item()[k] == "m" and ch["sensor"].item()[k] == "H-108912"
        z = m["harmonics"]["Z"].item()
        hnames = list(m["harmonics"]["channels"].item())
        for i, st in enumerate(r.steps):
            assert z[i, hnames.index("x1"), 0] == complex(*st["harmonics"]["x1"][0])
        steps = m["steps"]
        assert list(steps["target_units"].item()) == ["m", "m"]
        assert list(steps["freq_hz"].item()) == [30.0, 50.0]
        cond = m["conditions"]
        assert bool(cond["lubricated"].item()) and cond["run_id"].item() == "lub-1"
        inside = m["step"] == 1
        assert np.all(m["freq_hz"][inside] == 50.0)
        assert np.flatnonzero(inside)[[0, -1]].tolist() == [r.steps[1]["first_sample"],
                                                             r.steps[1]["last_sample"] - 1]


def test_mat_v73_past_the_v5_size(runs: dict[str, Path], tmp_path: Path) -> None:
    with open_run(runs["lub"]) as r:
        (path,) = write_mat(select(r), tmp_path, v5_max_bytes=0)
    assert path.read_bytes()[:19] == b"MATLAB 7.3 MAT-file"
    with h5py.File(path, "r") as f:
        assert f["x1_m"].attrs["MATLAB_class"] == b"double"
        assert f["steps"].attrs["MATLAB_class"] == b"struct"
        assert f["x1_m"].shape[0] == 1  # MATLAB n x 1, stored transposed
    back = import_file(path, tmp_path / "back.h5")
    _same_run(runs["lub"], back)


def test_tdms_channel_properties(runs: dict[str, Path], tmp_path: Path) -> None:
    (path,) = export_run(runs["lub"], "tdms", tmp_path)
    t = TdmsFile.read(path)
    with open_run(runs["lub"]) as r:
        x1 = t["channels"]["x1_m"]
        assert np.array_equal(x1[:], r.channel("x1"))
        p = x1.properties
        assert p["unit_string"] == "m" and p["sensor"] == "H-108912"
        assert p["gain_v_per_unit"] == pytest.approx(7952.755905511811)
        assert p["wf_increment"] == pytest.approx(1 / r.sample_rate_hz)
        assert t["drive"]["shaker_x_V"].properties["unit_string"] == "V"
        assert t.properties["lubricated"] is True and t.properties["run_id"] == "lub-1"
        assert list(t["steps"]["target_kind"][:]) == ["displacement"] * 2
        amp = t["harmonics"]["amplitude"][:]
        assert amp[0] == abs(complex(*r.steps[0]["harmonics"]["fx"][0]))


def test_csv_tables_and_conditions(runs: dict[str, Path], tmp_path: Path) -> None:
    files = export_run(runs["static"], "csv", tmp_path)
    names = {f.name for f in files}
    assert {"static.csv", "static.steps.csv", "static.harmonics.csv", "static.channels.csv",
            "static.events.csv", "static.csv.conditions.toml", "static.run.json"} == names
    cond = read_conditions_file(tmp_path / "static.csv.conditions.toml")
    assert cond == {"lubricated": False, "motion": "x", "seal": repr(26.0)}
    steps = (tmp_path / "static.steps.csv").read_text().splitlines()
    assert steps[0].startswith("index,freq_hz,target_kind,target_value,target_units")
    assert steps[1].split(",")[1:5] == ["0.0", "load", "-40.0", "N"]
    header = (tmp_path / "static.csv").read_text().splitlines()[0].split(",")
    assert header[:5] == ["time_s", "step", "freq_hz", "fx_N", "fy_N"]
    assert "x1_m" in header and "oil_temp_C" in header and "shaker_y_V" in header


def test_progress_reaches_the_end(runs: dict[str, Path], tmp_path: Path) -> None:
    seen: list[tuple[int, int]] = []
    export_run(runs["lub"], "tdms", tmp_path, progress=lambda d, n: seen.append((d, n)))
    with open_run(runs["lub"]) as r:
        n = r.n_samples
    assert seen[-1] == (n, n) and len(seen) == math.ceil(n / (1 << 18))
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)


def test_cli_export_then_import(runs: dict[str, Path], tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", str(runs["lub"]), "--to", "csv", "--out", str(tmp_path)]) == 0
    assert main(["import", str(tmp_path / "lub.csv"), "--out", str(tmp_path / "b.h5")]) == 0
    out = capsys.readouterr().out
    assert "restored from an sfdrig export (csv) of run 'lub-1'" in out
    assert "lubricated: yes [export]" in out
    _same_run(runs["lub"], tmp_path / "b.h5")


@pytest.mark.parametrize("args, message", [
    (["missing.h5", "--to", "csv"], "missing.h5: no such file"),
    (["LUB", "--to", "csv", "--channels", "x9"], "no channel 'x9' (channels fx, fy, x1"),
    (["LUB", "--to", "csv", "--channels", "shaker_x"], "--channels names no input channel"),
    (["LUB", "--to", "mat", "--steps", "2-5"], "--steps 2-5: the run has steps 1-2 (counted "
                                               "from 1)"),
    (["LUB", "--to", "mat", "--steps", "0"], "--steps 0: the run has steps 1-2 (counted from 1)"),
    (["LUB", "--to", "mat", "--steps", "0-1"], "--steps 0-1: the run has steps 1-2"),
    (["LUB", "--to", "mat", "--steps", "1-0"], "--steps 1-0: the range runs backwards"),
    (["LUB", "--to", "tdms", "--steps", "one"], "--steps 'one': expected N or N-M"),
    (["LUB", "--to", "csv", "--out", "LUB"], "is a file, not a folder"),
    (["LUB", "--to", "csv", "--out", "LUB/sub"], "cannot create the folder"),
])
def test_bad_input_is_one_line(runs: dict[str, Path], tmp_path: Path,
                               capsys: pytest.CaptureFixture[str], args: list[str],
                               message: str) -> None:
    args = [str(runs["lub"]) if a == "LUB" else str(runs["lub"]) + "/sub" if a == "LUB/sub"
            else a for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "out")]
    assert main(["export", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()  # nothing half written, not even the folder


def test_existing_export_is_kept(runs: dict[str, Path], tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    export_run(runs["lub"], "mat", tmp_path)
    before = (tmp_path / "lub.mat").read_bytes()
    assert main(["export", str(runs["lub"]), "--to", "mat", "--out", str(tmp_path)]) == 2
    assert "lub.mat: exists already" in capsys.readouterr().err
    assert (tmp_path / "lub.mat").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lub.mat"]


def test_import_refuses_a_contradicting_motion(runs: dict[str, Path], tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    (path,) = export_run(runs["lub"], "tdms", tmp_path)
    assert main(["import", str(path), "--out", str(tmp_path / "b.h5"), "--motion", "y"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "states each step's motion (x)" in err
    assert main(["import", str(path), "--out", str(tmp_path / "b.h5"), "--dry"]) == 0
    with open_run(tmp_path / "b.h5") as b:
        assert not b.attrs["lubricated"]


# --- run files that explain themselves --------------------------------------------------------
def test_run_file_describes_itself(runs: dict[str, Path]) -> None:
    with h5py.File(runs["lub"], "r") as f:
        assert f.attrs["format_version"] == 2 and "/step_harmonics" in f.attrs["layout"]
        fs = f.attrs["sample_rate_hz"]
        for group in ("channels", "drive"):
            for ds in f[group].values():
                assert ds.attrs["time_start"] == 0.0 and ds.attrs["time_units"] == "s"
                assert ds.attrs["time_increment"] == 1.0 / fs and ds.attrs["units"]
        steps = f["steps"]
        for name in steps.dtype.names:
            assert f"{name}_units" in steps.attrs and steps.attrs[f"{name}_description"]
        assert "N for load" in steps.attrs["target_value_description"]
        assert json.loads(steps.attrs["target_value_units_by_target_kind"]) == {
            "displacement": "m", "load": "N", "pressure": "Pa"}
        assert "freq_hz 0" in json.loads(steps.attrs["step_fields_by_kind"])["impact"]
        h = f["step_harmonics"].attrs
        assert h["amplitude_convention"].startswith("peak")
        assert "counted from sample 0 of the run" in h["phase_reference"]
        assert json.loads(h["units"])[:3] == ["N", "N", "m"]


@pytest.mark.parametrize("channel", ["x1", "fx", "ax"])
@pytest.mark.parametrize("step", [0, 1])
def test_reader_from_the_docs_matches_the_stored_harmonics(runs: dict[str, Path], channel: str,
                                                           step: int) -> None:
    rebuilt, stored, units = doc_reader.step_harmonics_from_samples(runs["lub"], channel, step)
    assert units in ("m", "N", "m/s^2")
    assert np.max(np.abs(rebuilt - stored)) < 1e-11 * np.abs(stored[0])
    assert np.abs(stored[0]) > 0


def test_doc_reader_imports_nothing_of_sfdrig() -> None:
    tree = ast.parse(Path(doc_reader.__file__).read_text())
    mods = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    mods |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert mods == {"__future__", "json", "pathlib", "h5py", "numpy"}


def test_version_1_files_still_read(runs: dict[str, Path], tmp_path: Path) -> None:
    """A file as version 1 wrote it (no descriptions) reads and exports the same."""
    old = tmp_path / "old.h5"
    old.write_bytes(runs["lub"].read_bytes())
    with h5py.File(old, "r+") as f:
        f.attrs["format_version"] = 1
        for key in ("layout", "time_axis"):
            del f.attrs[key]
        for ds in [*f["channels"].values(), *f["drive"].values()]:
            for key in ("time_start", "time_increment", "time_units", "time_reference"):
                del ds.attrs[key]
        for key in list(f["steps"].attrs):
            del f["steps"].attrs[key]
        for key in list(f["step_harmonics"].attrs):
            if key != "channels":
                del f["step_harmonics"].attrs[key]
    with open_run(old) as a, open_run(runs["lub"]) as b:
        assert a.attrs["format_version"] == 1
        assert a.steps == b.steps and np.array_equal(a.channel("x1"), b.channel("x1"))
    (path,) = export_run(old, "mat", tmp_path / "out")
    with open_run(runs["lub"]) as b:
        assert np.array_equal(scipy.io.loadmat(path, squeeze_me=True)["x1_m"], b.channel("x1"))


# --- any run, any format ------------------------------------------------------------------------
_NAMES = st.text(alphabet="abxyz_1 ä-", min_size=1, max_size=6).filter(
    lambda s: s.strip() == s and s not in (".", ".."))
_TEXT = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",),
                                       exclude_characters="\x00"), max_size=30)


@given(
    fmt=st.sampled_from(FORMATS),
    names=st.lists(_NAMES, min_size=1, max_size=3, unique=True),
    units=st.lists(st.sampled_from(["N", "m", "m/s^2", "degC", "Pa", "kN", ""]), min_size=3,
                   max_size=3),
    values=st.lists(st.floats(width=64), min_size=1, max_size=40),
    n_ao=st.integers(0, 1),
    steps=st.lists(st.tuples(st.integers(0, 39), st.integers(1, 40),
                             st.floats(0, 500, allow_nan=False), _TEXT), max_size=3),
    events=st.lists(st.tuples(st.integers(0, 40), _TEXT), max_size=3),
)
def test_any_run_round_trips(fmt: str, names: list[str], units: list[str], values: list[float],
                             n_ao: int, steps: list, events: list) -> None:
    """Any values (NaN, infinities, subnormals, -0), names, units, step and event texts come
    back the same through every format."""
    n = len(values)
    data = np.array(values)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        chans = [{"name": nm, "units": units[i], "sensor": f"s,{i}\n\"q\""}
                 for i, nm in enumerate(names)]
        with RunWriter.create(d / "r.h5", "r", "sweep", chans, ["drv"][:n_ao], 1234.5,
                              flush_interval_s=0, swmr=False) as w:
            w.on_block(0, np.stack([np.roll(data, i) for i in range(len(names))]),
                       data[None, ::-1].copy() if n_ao else None)
            for i, (a, length, f, reason) in enumerate(steps):
                w.on_step(StepRecord.from_wire({
                    "index": i, "freq_hz": f, "target_kind": "load", "target_value": f,
                           "motion": "x", "first_sample": min(a, n - 1),
                           "last_sample": min(a + length, n), "updates": 1, "converged": False,
                           "reason": reason, "note": reason,
                           "harmonics": {names[0]: [[f, -f]] * 5}}))
            for sample, text in events:
                w.on_event("info", text, sample)
        try:
            (path,) = export_run(d / "r.h5", fmt, d / "out")[:1]
        except ExportError as err:  # two names that share a column are refused, not merged
            assert "would share the column" in str(err)
            return
        with open_run(d / "r.h5") as a:
            assert all(re.fullmatch(r"[A-Za-z]\w{0,62}", column_name(c, a.units(c)))
                       for c in a.channel_names)  # MATLAB variable names
        _same_run(d / "r.h5", import_file(path, d / "back.h5"))


def test_cli_progress_is_a_line_per_tenth(capsys: pytest.CaptureFixture[str]) -> None:
    from sfdrig.commands.export import _Progress

    p = _Progress(Path("big.h5"))
    for done in range(0, 1_000_001, 65_536):
        p(done, 1_000_000)
    p(1_000_000, 1_000_000)
    lines = capsys.readouterr().err.splitlines()
    assert [ln.split(":")[1].split("%")[0].strip() for ln in lines] == [
        str(10 * k) for k in range(1, 11)]
    assert lines[-1].startswith("  big.h5: 100 % (1,000,000 of 1,000,000 samples")


# --- exports every reader takes -----------------------------------------------------------------
def _csv_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


#: the numeric columns of a CSV export's tables
NUMERIC_COLUMNS = {
    "harmonics": ("step", "harmonic", "freq_hz", "amplitude", "phase_deg", "re", "im"),
    "steps": ("index", "freq_hz", "target_value", "first_sample", "last_sample", "t_start_s",
              "t_stop_s", "updates", "converged"),
    "channels": ("gain_v_per_unit", "offset_v"),
    "events": ("sample",),
}


def test_csv_tables_hold_numbers_as_numbers(runs: dict[str, Path], tmp_path: Path) -> None:
    """Python's csv module and float() read every number of every table (once the harmonics'
    cells read "np.float64(29.9...)")."""
    export_run(runs["lub"], "csv", tmp_path)
    tables = {name: _csv_rows(tmp_path / f"lub.{name}.csv") for name in NUMERIC_COLUMNS}
    for name, columns in NUMERIC_COLUMNS.items():
        assert tables[name], name
        for row in tables[name]:
            for col in columns:
                float(row[col])  # raises on a cell no reader takes for a number
            assert not any("np." in cell for cell in row.values()), row
    with open_run(runs["lub"]) as r:
        want = r.steps[1]["harmonics"]["x1"][0]
    (row,) = [h for h in tables["harmonics"] if h["step"] == "1" and h["channel"] == "x1"
              and h["harmonic"] == "1"]
    assert (float(row["re"]), float(row["im"])) == tuple(want)  # 17 digits: bit for bit
    assert float(row["amplitude"]) == abs(complex(*want)) > 0


@pytest.mark.parametrize("steps", [None, "1", "2"])
def test_tdms_time_under_nptdms(runs: dict[str, Path], tmp_path: Path,
                                steps: str | None) -> None:
    """npTDMS's time track is the run's time (time_s) and its absolute time track the wall
    clock, for a whole run and for an export of some steps (once late by the first sample's run
    time: the start moved to it and the offset added again)."""
    (path,) = export_run(runs["lub"], "tdms", tmp_path, steps=steps)
    with open_run(runs["lub"]) as r:
        first = r.steps[int(steps) - 1]["first_sample"] if steps else 0  # counted from 1
        fs = r.sample_rate_hz
        start = datetime.fromisoformat(r.start_time).astimezone(UTC).replace(tzinfo=None)
    assert first > 0 or steps is None
    ch = TdmsFile.read(path)["channels"]["x1_m"]
    rel = ch.time_track()
    assert rel[0] == pytest.approx(first / fs, abs=1e-9)
    assert rel[-1] - rel[0] == pytest.approx((len(ch) - 1) / fs, abs=1e-9)
    wall = ch.time_track(absolute_time=True, accuracy="us")
    want = np.datetime64(start, "us") + np.timedelta64(round(first / fs * 1e6), "us")
    assert abs((wall[0] - want) / np.timedelta64(1, "us")) <= 1


def test_closed_stdout_is_quiet(runs: dict[str, Path], tmp_path: Path) -> None:
    """`sfdrig export RUN --to csv --out DIR | head -c 10`: the reader gone before the command
    prints ends quietly with 141 (128 + SIGPIPE, as a shell shows a command the pipe's signal
    ended), not "BrokenPipeError", exit 2; the export itself is complete. (The other commands
    that answer their own errors: tests/sfdrig/test_cli.py.)"""
    args = ["export", str(runs["lub"]), "--to", "csv", "--out", str(tmp_path / "e")]
    proc = subprocess.Popen([sys.executable, "-m", "sfdrig", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader has gone before anything is written
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(timeout=120) == 141, err
    assert "BrokenPipe" not in err and "Traceback" not in err, err
    assert (tmp_path / "e" / "lub.harmonics.csv").is_file()


# --- docs/run-files.md, read as a newcomer would: its tables and its examples, nothing else ----
DOC = Path(__file__).resolve().parents[2] / "docs" / "run-files.md"
_ROW = re.compile(r"^\| `([^`]+)` \| ([^|]+) \|")


def _doc_tables() -> dict[str, list[tuple[str, str]]]:
    """Heading (e.g. "`/steps` columns") -> the (name, kind) rows of the table under it."""
    tables: dict[str, list[tuple[str, str]]] = {}
    heading = ""
    for line in DOC.read_text().splitlines():
        if line.startswith("#"):
            heading = line.lstrip("#").strip()
        elif heading and (m := _ROW.match(line)):
            tables.setdefault(heading, []).append((m[1], m[2].strip()))
    return tables


def _doc_code(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(), re.S)


def _names(text: str) -> list[str]:
    return re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", text)


def _doc_paragraph(start: str) -> str:
    """The doc's paragraph or list item starting with ``start``."""
    text = DOC.read_text()
    i = text.index(start)
    ends = [j for j in (text.find("\n- ", i), text.find("\n\n", i)) if j > 0]
    return text[i:min(ends)]


def _is_kind(value: object, kind: str) -> bool:
    if kind.startswith("JSON text"):
        return isinstance(value, str) and json.loads(value) is not None
    return {"text": isinstance(value, str), "float": isinstance(value, np.floating),
            "integer": isinstance(value, np.integer),
            "boolean": isinstance(value, np.bool_)}[kind.split(",")[0]]


def _check_attrs(obj: h5py.HLObject, rows: list[tuple[str, str]], where: str,
                 columns: tuple[str, ...] = ()) -> None:
    """Every attribute ``obj`` has is in the doc's table, every one the doc lists (but those
    for some runs only) is there, each of the kind the doc says."""
    documented: dict[str, str] = {}
    for name, kind in rows:
        for col in columns if "<column>" in name else ("",):
            documented[name.replace("<column>", col)] = kind
    have = set(obj.attrs)
    assert have <= set(documented), f"{where}: not in the doc: {sorted(have - set(documented))}"
    needed = {n for n, k in documented.items() if "only" not in k}
    assert needed <= have, f"{where}: the doc lists {sorted(needed - have)}"
    for name in have:
        assert _is_kind(obj.attrs[name], documented[name]), (where, name, obj.attrs[name])


def test_the_run_file_is_as_the_doc_says(runs: dict[str, Path]) -> None:
    """Every object, attribute and column of a run file, with its kind of value, is the doc's
    (so the page cannot drift from the files): text columns are bytes, the JSON texts parse."""
    tables = _doc_tables()
    layout = DOC.read_text().split("## Layout")[1].split("###")[0]
    with h5py.File(runs["lub"], "r") as f:
        for obj in re.findall(r"^\| `(/[^`<]*)", layout, re.M):
            assert (obj.rstrip("/") or "/") in f, obj
        _check_attrs(f, tables["`/` attributes"], "/")
        for group in ("channels", "drive"):
            for ds in f[group].values():
                _check_attrs(ds, tables[f"`/{group}/<name>` attributes"], ds.name)
        for table in ("steps", "events"):
            ds = f[table]
            cols = tables[f"`/{table}` columns"]
            assert [n for n, _ in cols] == list(ds.dtype.names)
            dtype_kind = {"bytes": "S", "integer": "i", "float": "f", "boolean": "b"}
            for name, kind in cols:
                assert ds.dtype[name].kind == dtype_kind[kind], (table, name)
                if kind == "bytes":  # as the doc says: h5py gives bytes
                    assert isinstance(ds[0][name], bytes), (table, name)
            _check_attrs(ds, tables[f"`/{table}` attributes"], table, ds.dtype.names)
        for table in ("step_harmonics", "step_drive_v"):
            _check_attrs(f[table], tables[f"`/{table}` attributes"], table)


def test_the_docs_examples_run_as_written(runs: dict[str, Path], tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """The page's export commands and its Python examples, run word for word in a folder holding
    runs/lub.h5, read what the run file holds (checked here with sfdrig's own reader)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "lub.h5").write_bytes(runs["lub"].read_bytes())
    commands = [ln for block in _doc_code("bash") for ln in block.splitlines()
                if ln.startswith("sfdrig export runs/lub.h5")]  # "Try it": test_readme_e2e
    assert len(commands) == 3
    for line in commands:
        assert main(shlex.split(line)[1:]) == 0, line
    examples: dict[str, dict[str, object]] = {}
    for code in _doc_code("python"):
        ns: dict[str, object] = {}
        exec(compile(code, str(DOC), "exec"), ns)  # noqa: S102 - the doc's own example
        examples[code.splitlines()[0].split(":")[0].lstrip("# ")] = ns
    assert len(examples) == 4 and "out/export/lub.csv" in capsys.readouterr().out
    with open_run(runs["lub"]) as r:
        fs, step = r.sample_rate_hz, r.steps[1]
        z = complex(*step["harmonics"]["x1"][0])
        x1 = r.channel("x1")
        start = datetime.fromisoformat(r.start_time).astimezone(UTC).replace(tzinfo=None)
        events = [(e["sample"], e["kind"], e["message"]) for e in r.events]
        drives = r.drive_names
        seal_n = r.rig_config["seal"]["friction_force_n"]
    h5 = examples["h5py"]
    assert (h5["fs"], h5["motion"], h5["target"]) == (fs, step["motion"],
                                                      f"{step['target_value']:g} m")
    assert h5["amp_stored"] == abs(z) and h5["amp_fitted"] == pytest.approx(abs(z), rel=1e-6)
    assert list(h5["drive_1x"]) == drives and h5["events"] == events
    assert h5["t"][1] == pytest.approx(1 / fs, rel=1e-12)  # type: ignore[index]
    csv_ns = examples["CSV export"]
    assert (csv_ns["fs"], csv_ns["t0"], csv_ns["x1_0"]) == (fs, 0.0, x1[0])
    assert csv_ns["z_1x"] == z and csv_ns["amp_1x"] == abs(z)
    assert csv_ns["seal_n"] == seal_n > 0
    tdms = examples["TDMS export"]
    assert tdms["fs"] == fs and tdms["t"][0] == 0.0  # type: ignore[index]
    assert tdms["wall"][0] == np.datetime64(start, "us")  # type: ignore[index]
    assert np.array_equal(tdms["x1"][:], x1)  # type: ignore[index]
    mat = examples["MAT export"]
    assert mat["fs"] == fs and mat["seal_n"] == seal_n
    assert np.array_equal(mat["x1"], x1) and mat["t"][1] == 1 / fs  # type: ignore[index]


def test_every_export_names_what_the_doc_says(runs: dict[str, Path], tmp_path: Path) -> None:
    """The CSV files' columns, the TDMS groups and properties, the MAT variables and the
    conditions (in all three, the CSV's conditions file too) are those the page lists."""
    for fmt in FORMATS:
        export_run(runs["lub"], fmt, tmp_path)
    tables = _doc_tables()["CSV (`RUN.csv` and its tables beside it)"]
    csv_cols = {file: _names(cols) for file, cols in tables}
    assert len(csv_cols) == 5 and csv_cols["RUN.csv"] == ["time_s", "step", "freq_hz"]
    for file, cols in csv_cols.items():
        header = (tmp_path / file.replace("RUN", "lub")).read_text().splitlines()[0].split(",")
        assert header[:len(cols)] == cols, file
    t = TdmsFile.read(tmp_path / "lub.tdms")
    groups = [name for name, _ in _doc_tables()["TDMS (`RUN.tdms`)"]]
    assert [g.name for g in t.groups()] == groups
    assert [c.name for c in t["per_sample"].channels()] == ["step", "freq_hz"]
    for group, file in (("steps", "RUN.steps.csv"), ("harmonics", "RUN.harmonics.csv"),
                        ("events", "RUN.events.csv"), ("channel_table", "RUN.channels.csv")):
        assert [c.name for c in t[group].channels()] == csv_cols[file], group
    props = set(_names(_doc_paragraph("A waveform's properties")))
    for group in ("channels", "drive"):
        for ch in t[group].channels():
            assert set(ch.properties) <= props, (ch.name, set(ch.properties) - props)
    conditions = _names(_doc_paragraph("- **Conditions**"))
    conditions = [c for c in conditions if c not in ("none", "unknown", "conditions")]
    assert {"lubricated", "seal", "seal_friction_N", "sample_rate_hz", "kind"} <= set(conditions)
    assert set(conditions) <= set(t.properties)
    mat = scipy.io.loadmat(tmp_path / "lub.mat", squeeze_me=True)
    assert set(conditions) == set(mat["conditions"].dtype.names)
    mat_vars = _names(_doc_paragraph("v5 for `scipy.io.loadmat`"))
    assert {"Fs", "time_s", "steps", "harmonics", "conditions", "README"} <= set(mat_vars)
    struct_fields = {"amplitude", "phase_deg", "columns", "units", "convention"}
    assert set(mat_vars) - struct_fields <= set(mat), set(mat_vars) - set(mat)
    toml = tomllib.loads((tmp_path / "lub.csv.conditions.toml").read_text())
    assert set(conditions) == {k for k in toml if k != "run"} | set(toml["run"])
