"""Importers of measured data: CSV quirks, .mat (v5 and v7.3), TDMS, every error path, atomicity,
and the real silverbox file."""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from sfdrig.cli import main
from storage import ImportDataError, open_run
from storage.importers import dwell_steps, import_file, parse_assignments, parse_scale
from storage.runfile import RunWriter
from tests.conftest import REPO_ROOT


def _write(path: Path, text: str, encoding: str = "utf-8") -> Path:
    path.write_bytes(text.encode(encoding))
    return path


def _csv_canonical(path: Path, n: int = 40, fs: float = 100.0) -> tuple[Path, dict]:
    t = np.arange(n) / fs
    cols = {
        "time_s": t,
        "freq_hz": np.where(np.arange(n) < n // 2, 5.0, 7.5),
        "fx_N": np.round(np.sin(t * 3), 6),
        "fy_N": np.round(np.cos(t * 3), 6),
        "x_m": np.round(1e-5 * np.sin(t * 3 + 0.2), 12),
        "oil_temp_C": np.full(n, 41.5),
    }
    lines = [",".join(cols)]
    for i in range(n):
        lines.append(",".join(repr(float(cols[c][i])) for c in cols))
    _write(path, "\n".join(lines) + "\n")
    return path, cols


# --- CSV ---------------------------------------------------------------------------------------
def test_csv_canonical_columns_with_time_and_dwells(tmp_path: Path) -> None:
    src, cols = _csv_canonical(tmp_path / "m.csv")
    out = import_file(src, tmp_path / "m.h5", notes="bench 3")
    with open_run(out) as run:
        assert run.kind == "imported" and run.status == "completed"
        assert run.attrs["notes"] == "bench 3"
        assert run.channel_names == ["fx", "fy", "x", "t_oil"]
        assert run.sample_rate_hz == pytest.approx(100.0, rel=1e-12)
        np.testing.assert_array_equal(run.signal("fx"), cols["fx_N"])
        np.testing.assert_array_equal(run.signal("x"), cols["x_m"])
        np.testing.assert_array_equal(run.signal("t_oil"), cols["oil_temp_C"])
        assert [run.units(c) for c in run.channel_names] == ["N", "N", "m", "degC"]
        steps = run.steps
        assert [(s["freq_hz"], s["first_sample"], s["last_sample"]) for s in steps] == [
            (5.0, 0, 20), (7.5, 20, 40)]
        assert steps[0]["target_kind"] == "" and math.isnan(steps[0]["target_value"])
        spec = run.test_spec
        plain = tmp_path / "plain"
        plain.write_text("")
        assert out.stat().st_mode & 0o777 == plain.stat().st_mode & 0o777  # umask, not 0600
        assert spec["source_format"] == "csv"
        assert spec["source_sha256"] == hashlib.sha256(src.read_bytes()).hexdigest()
        assert spec["signals"]["fx_N"] == "column 'fx_N'"


def test_csv_quirks_bom_quotes_trailing_commas_crlf_blank_tail(tmp_path: Path) -> None:
    text = '\ufeff"F_a","D_b",\r\n1.5,2e-6,\r\n-0.5,3e-6,\r\n2.25,-1e-6,\r\n\r\n\r\n'
    src = _write(tmp_path / "q.csv", text)
    out = import_file(src, tmp_path / "q.h5", mapping={"fx_N": "F_a", "x_m": "D_b"}, fs_hz=50.0,
                      scale={"x_m": 1e3})
    with open_run(out) as run:
        np.testing.assert_array_equal(run.signal("fx"), [1.5, -0.5, 2.25])
        np.testing.assert_allclose(run.signal("x"), [2e-3, 3e-3, -1e-3], rtol=1e-15)
        assert run.sample_rate_hz == 50.0 and run.steps == []


def test_csv_quoted_cells_and_semicolons(tmp_path: Path) -> None:
    src = _write(tmp_path / "s.csv", 'when;fx_N;x_m\n"a;b";"1.0";2e-6\n"c";3;4e-6\n')
    out = import_file(src, tmp_path / "s.h5", fs_hz=10.0)
    with open_run(out) as run:
        np.testing.assert_array_equal(run.signal("fx"), [1.0, 3.0])
        np.testing.assert_array_equal(run.signal("x"), [2e-6, 4e-6])


def test_csv_unused_text_column_is_ignored(tmp_path: Path) -> None:
    src = _write(tmp_path / "u.csv", "label,fx_N,x_m\nstart,1,2e-6\nend,3,4e-6\n")
    with open_run(import_file(src, tmp_path / "u.h5", fs_hz=1.0)) as run:
        assert run.n_samples == 2


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("fx_N,x_m\n1,2\n3,abc\n", r"line 3, column 'x_m': 'abc' is not a number"),
        ("fx_N,x_m\n1,2\n3,\n", r"line 3, column 'x_m': empty cell"),
        ("fx_N,x_m\n1,2\n3\n", r"line 3: 1 cell\(s\), the header has 2 columns"),
        ("fx_N,x_m\n1,2\n3,4,5\n", r"line 3: 3 cells, the header has 2 columns"),
        ("fx_N,x_m\n1,2\n\n3,4\n5,nan\n", r"line 5, column 'x_m': nan is not a finite"),
        ("fx_N,x_m\n", r"header only, no data rows"),
        ("\n\n", r"empty file \(no header row\)"),
        ("fx_N,,x_m\n1,2,3\n", r"line 1: column 2 has no name"),
        ("fx_N,x_m,fx_N\n1,2,3\n", r"line 1: duplicate column names \['fx_N'\]"),
        ("a,b\n1,2\n", r"need at least one force .* among columns \['a', 'b'\]"),
        ("0.5,2e-6,\n1,2,\n", r"line 1: no header row \(the first line holds numbers\)"),
    ],
)
def test_csv_errors_name_the_line_and_column(tmp_path: Path, text: str, message: str) -> None:
    src = _write(tmp_path / "bad.csv", text)
    with pytest.raises(ImportDataError, match=message) as info:
        import_file(src, tmp_path / "bad.h5", fs_hz=10.0)
    assert str(src) in str(info.value)
    assert not (tmp_path / "bad.h5").exists()


def test_csv_not_utf8_names_line(tmp_path: Path) -> None:
    src = tmp_path / "l1.csv"
    src.write_bytes(b"fx_N,x_m\n1,2\n\xff,3\n")
    with pytest.raises(ImportDataError, match=r"line 3: not UTF-8"):
        import_file(src, tmp_path / "o.h5", fs_hz=1.0)


def test_csv_time_column_gap_names_the_line(tmp_path: Path) -> None:
    t = np.arange(100) / 1000.0
    t = np.delete(t, 57)  # a dropped sample: the row of t = 0.058 s is file line 58
    lines = ["time_s,fx_N,x_m"] + [f"{v:.4f},1,2" for v in t]
    src = _write(tmp_path / "gap.csv", "\n".join(lines))
    with pytest.raises(ImportDataError, match=r"gap\.csv, line 59: time_s is not uniformly"):
        import_file(src, tmp_path / "gap.h5")


def test_csv_time_rounded_in_print_is_uniform(tmp_path: Path) -> None:
    fs = 610.3515625  # dt = 1.6384 ms printed with 5 decimals: 3 % rounding per step
    t = np.arange(500) / fs
    lines = ["time_s,fx_N,x_m"] + [f"{v:.5f},1,2" for v in t]
    src = _write(tmp_path / "round.csv", "\n".join(lines))
    with open_run(import_file(src, tmp_path / "round.h5")) as run:
        assert run.sample_rate_hz == pytest.approx(fs, rel=1e-4)


def test_csv_time_and_fs_must_agree(tmp_path: Path) -> None:
    src, _ = _csv_canonical(tmp_path / "m.csv", fs=100.0)
    with pytest.raises(ImportDataError, match=r"--fs 120 Hz disagrees with the time column"):
        import_file(src, tmp_path / "m.h5", fs_hz=120.0)
    with open_run(import_file(src, tmp_path / "m.h5", fs_hz=100.0)) as run:
        assert run.sample_rate_hz == 100.0


def test_csv_needs_a_rate(tmp_path: Path) -> None:
    src = _write(tmp_path / "r.csv", "fx_N,x_m\n1,2\n")
    with pytest.raises(ImportDataError, match=r"no time_s column and no sample rate: give --fs"):
        import_file(src, tmp_path / "r.h5")
    with pytest.raises(ImportDataError, match=r"--fs -5.0: must be a positive"):
        import_file(src, tmp_path / "r.h5", fs_hz=-5.0)


def test_csv_map_to_missing_column(tmp_path: Path) -> None:
    src = _write(tmp_path / "m.csv", "V1,V2\n1,2\n")
    with pytest.raises(ImportDataError, match=r"--map x_m=V3: no column 'V3' \(columns: "):
        import_file(src, tmp_path / "m.h5", mapping={"fx_N": "V1", "x_m": "V3"}, fs_hz=1.0)


def test_scale_of_a_signal_not_imported(tmp_path: Path) -> None:
    src = _write(tmp_path / "m.csv", "fx_N,x_m\n1,2\n")
    with pytest.raises(ImportDataError, match=r"--scale y_m: no such signal"):
        import_file(src, tmp_path / "m.h5", fs_hz=1.0, scale={"y_m": 2.0})


def test_option_parsing_errors() -> None:
    assert parse_assignments(["fx_N=V1", "x_m = V2"], "--map") == {"fx_N": "V1", "x_m": "V2"}
    with pytest.raises(ImportDataError, match=r"--map 'fx_N': expected CANONICAL=VALUE"):
        parse_assignments(["fx_N"], "--map")
    with pytest.raises(ImportDataError, match=r"'force' is not a canonical name"):
        parse_assignments(["force=V1"], "--map")
    with pytest.raises(ImportDataError, match=r"'fx_N' given twice"):
        parse_assignments(["fx_N=a", "fx_N=b"], "--map")
    assert parse_scale(["x_m=1e-6"]) == {"x_m": 1e-6}
    with pytest.raises(ImportDataError, match=r"--scale x_m=big: factor must be a finite"):
        parse_scale(["x_m=big"])
    with pytest.raises(ImportDataError, match=r"--scale time_s: only signal columns"):
        parse_scale(["time_s=2"])


def test_unknown_extension(tmp_path: Path) -> None:
    src = _write(tmp_path / "data.xlsx", "x")
    with pytest.raises(ImportDataError, match=r"unknown file type '\.xlsx'"):
        import_file(src, tmp_path / "o.h5")


# --- all or nothing ----------------------------------------------------------------------------
def test_bad_input_leaves_existing_output_untouched(tmp_path: Path) -> None:
    good, _ = _csv_canonical(tmp_path / "good.csv")
    out = import_file(good, tmp_path / "run.h5")
    before = out.read_bytes()
    bad = _write(tmp_path / "bad.csv", "fx_N,x_m\n1,2\n3,x\n")
    with pytest.raises(ImportDataError, match="line 3"):
        import_file(bad, out, fs_hz=1.0, overwrite=True)
    assert out.read_bytes() == before
    with pytest.raises(ImportDataError, match=r"run\.h5: exists already"):
        import_file(good, out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "good.csv", "run.h5"]


def test_failure_while_writing_leaves_no_file(tmp_path: Path, monkeypatch) -> None:
    src, _ = _csv_canonical(tmp_path / "m.csv")

    def boom(self, *args, **kwargs):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(RunWriter, "on_step", boom)
    with pytest.raises(OSError, match="disk full"):
        import_file(src, tmp_path / "m.h5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.csv"]


def test_dwell_steps_skip_rests_and_transitions() -> None:
    f = np.array([0, 0, 5, 5, 5, np.nan, 10, 10, 5, 5.0])
    got = [(s["index"], s["freq_hz"], s["first_sample"], s["last_sample"])
           for s in dwell_steps(f)]
    assert got == [(0, 5.0, 2, 5), (1, 10.0, 6, 8), (2, 5.0, 8, 10)]


# --- MATLAB ------------------------------------------------------------------------------------
def test_mat_v5_variables_struct_fields_and_matrix_columns(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    m = rng.normal(size=(64, 3))
    path = tmp_path / "d.mat"
    scipy.io.savemat(path, {
        "fy_N": m[:, 0:1],  # a column vector, canonical name
        "meas": m,
        "rig": {"probe_x": m[:, 2] * 1e-6, "note": "bench"},
        "label": "text",
    })
    out = import_file(path, tmp_path / "d.h5",
                      mapping={"fx_N": "meas(:,2)", "x_m": "rig.probe_x"}, fs_hz=2000.0)
    with open_run(out) as run:
        np.testing.assert_array_equal(run.signal("fy"), m[:, 0])
        np.testing.assert_array_equal(run.signal("fx"), m[:, 1])
        np.testing.assert_array_equal(run.signal("x"), m[:, 2] * 1e-6)
        assert run.test_spec["source_format"] == "mat"
        assert run.test_spec["signals"]["fx_N"] == "variable 'meas(:,2)'"


@pytest.mark.parametrize(
    ("mapping", "message"),
    [
        ({"fx_N": "nope", "x_m": "b"}, r"no variable 'nope' \(variables: \["),
        ({"fx_N": "meas", "x_m": "b"}, r"'meas' has shape \(8, 3\), not a vector"),
        ({"fx_N": "meas(:,4)", "x_m": "b"}, r"'meas\(:,4\)': index 4 exceeds"),
        ({"fx_N": "meas(:,0)", "x_m": "b"}, r"MATLAB indices start at 1"),
        ({"fx_N": "label", "x_m": "b"}, r"variable 'label' is not numeric"),
        ({"fx_N": "a", "x_m": "short"}, r"signals differ in length: variable 'a' has 8, "
                                        r"variable 'short' has 5"),
        ({"fx_N": "s.f", "x_m": "b"}, r"no field 'f' in 's.f'"),
        ({"fx_N": "s", "x_m": "b"}, r"'s' is a struct"),
        ({"fx_N": "a", "x_m": "withnan"}, r"sample 2, variable 'withnan': nan is not a finite"),
        ({"fx_N": "a b", "x_m": "b"}, r"'a b' is not a variable reference"),
    ],
)
def test_mat_errors_name_the_variable(tmp_path: Path, mapping: dict, message: str) -> None:
    path = tmp_path / "e.mat"
    scipy.io.savemat(path, {"a": np.arange(8.0), "b": np.ones(8), "meas": np.ones((8, 3)),
                            "label": "text", "short": np.ones(5), "s": {"g": np.ones(8)},
                            "withnan": np.array([1, 2, np.nan, 4, 5, 6, 7, 8.0])})
    with pytest.raises(ImportDataError, match=message):
        import_file(path, tmp_path / "e.h5", mapping=mapping, fs_hz=10.0)
    assert not (tmp_path / "e.h5").exists()


def _write_mat73(path: Path, variables: dict) -> None:
    """A v7.3 .mat as MATLAB writes it: HDF5 with a 512-byte user block, column-major arrays."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            if isinstance(value, dict):
                g = f.create_group(name)
                g.attrs["MATLAB_class"] = np.bytes_("struct")
                for k, v in value.items():
                    d = g.create_dataset(k, data=np.atleast_2d(np.asarray(v, float)).T.T)
                    d.attrs["MATLAB_class"] = np.bytes_("double")
                continue
            arr = np.asarray(value)
            if arr.dtype.kind == "U":
                d = f.create_dataset(name, data=np.frombuffer(arr.item().encode("utf-16-le"),
                                                              dtype="<u2")[:, None])
                d.attrs["MATLAB_class"] = np.bytes_("char")
                continue
            arr = arr.reshape(-1, 1) if arr.ndim == 1 else arr  # MATLAB column vector
            d = f.create_dataset(name, data=arr.T)  # column-major on disk
            d.attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as fh:  # MATLAB's text header in the user block
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: test HDF5 schema 1.00 .")


def test_mat_v73_read_with_h5py(tmp_path: Path) -> None:
    t = np.arange(50) / 250.0
    data = np.stack([np.sin(t), np.cos(t) * 1e-5, t * 0 + 20.0], axis=1)
    path = tmp_path / "v73.mat"
    _write_mat73(path, {"time_s": t, "data": data, "info": "x", "grp": {"fy": np.sin(2 * t)}})
    out = import_file(path, tmp_path / "v73.h5",
                      mapping={"fx_N": "data(:,1)", "x_m": "data(:,2)", "oil_temp_C": "data(:,3)",
                               "fy_N": "grp.fy"})
    with open_run(out) as run:
        assert run.sample_rate_hz == pytest.approx(250.0, rel=1e-9)
        np.testing.assert_array_equal(run.signal("fx"), data[:, 0])
        np.testing.assert_array_equal(run.signal("x"), data[:, 1])
        np.testing.assert_array_equal(run.signal("t_oil"), data[:, 2])
        np.testing.assert_allclose(run.signal("fy"), np.sin(2 * t), rtol=0, atol=0)
        assert run.test_spec["source_format"] == "mat-v7.3"
    with pytest.raises(ImportDataError, match=r"variable 'info' is MATLAB char, not numeric"):
        import_file(path, tmp_path / "o.h5", mapping={"fx_N": "info", "x_m": "data(:,2)"})
    with pytest.raises(ImportDataError, match=r"no variable 'gone'"):
        import_file(path, tmp_path / "o.h5", mapping={"fx_N": "gone", "x_m": "data(:,2)"})


def test_mat_garbage(tmp_path: Path) -> None:
    path = _write(tmp_path / "g.mat", "not a mat file at all")
    with pytest.raises(ImportDataError, match=r"g\.mat: not a readable \.mat file"):
        import_file(path, tmp_path / "g.h5", fs_hz=1.0)


# --- TDMS --------------------------------------------------------------------------------------
def _write_tdms(path: Path, channels: list[tuple[str, str, np.ndarray, dict]]) -> None:
    groups = {g for g, _, _, _ in channels}
    with TdmsWriter(path) as w:
        w.write_segment([RootObject({"name": "sfd test"})]
                        + [GroupObject(g) for g in sorted(groups)]
                        + [ChannelObject(g, c, data, properties=props)
                           for g, c, data, props in channels])


@pytest.mark.parametrize("offset_s, first_sample_at", [(0.0, "2019-05-03T10:20:30.250"),
                                                       (1.5, "2019-05-03T10:20:31.750")])
def test_tdms_labview_layout(tmp_path: Path, offset_s: float, first_sample_at: str) -> None:
    """The run starts at its first sample: wf_start_time + wf_start_offset (npTDMS's time
    track)."""
    n = 300
    rng = np.random.default_rng(5)
    fx, x1 = rng.normal(size=n), rng.normal(size=n) * 1e-5
    props = {"wf_increment": 1 / 5000.0, "wf_start_offset": offset_s,
             "wf_start_time": np.datetime64("2019-05-03T10:20:30.250")}
    path = tmp_path / "lv.tdms"
    _write_tdms(path, [("Forces", "Load X", fx, props), ("Probes", "X1", x1, props),
                       ("Probes", "fy_N", fx * 2, props)])
    out = import_file(path, tmp_path / "lv.h5", mapping={"fx_N": "Forces/Load X", "x_m": "X1"})
    with open_run(out) as run:
        assert run.sample_rate_hz == pytest.approx(5000.0, rel=1e-12)
        np.testing.assert_array_equal(run.signal("fx"), fx)
        np.testing.assert_array_equal(run.signal("fy"), fx * 2)
        np.testing.assert_array_equal(run.signal("x"), x1)
        assert run.start_time.startswith(first_sample_at)
        assert run.test_spec["signals"]["x_m"] == "channel 'Probes/X1'"


def test_tdms_errors(tmp_path: Path) -> None:
    n = 20
    p1 = {"wf_increment": 0.001}
    p2 = {"wf_increment": 0.002}
    path = tmp_path / "bad.tdms"
    _write_tdms(path, [("A", "F", np.ones(n), p1), ("A", "D", np.ones(n), p2),
                       ("B", "D", np.ones(n), p1), ("B", "E", np.ones(n), p1)])
    with pytest.raises(ImportDataError, match=r"channel name 'D' is in several groups"):
        import_file(path, tmp_path / "o.h5", mapping={"fx_N": "F", "x_m": "D"})
    with pytest.raises(ImportDataError, match=r"different wf_increment \(channel 'A/F': 0.001 s,"
                                              r" channel 'A/D': 0.002 s\)"):
        import_file(path, tmp_path / "o.h5", mapping={"fx_N": "F", "x_m": "A/D"})
    with pytest.raises(ImportDataError, match=r"--fs 900 Hz disagrees with wf_increment of "
                                              r"channel 'A/F' \(1000 Hz\)"):
        import_file(path, tmp_path / "o.h5", mapping={"fx_N": "F", "x_m": "E"}, fs_hz=900.0)
    with pytest.raises(ImportDataError, match=r"no channel 'Z' \(channels: \['A/F', "):
        import_file(path, tmp_path / "o.h5", mapping={"fx_N": "F", "x_m": "Z"})
    garbage = _write(tmp_path / "g.tdms", "TDSm garbage")
    with pytest.raises(ImportDataError, match=r"g\.tdms: (not a readable TDMS|no channels)"):
        import_file(garbage, tmp_path / "o.h5", mapping={"fx_N": "F", "x_m": "Z"})
    other = _write(tmp_path / "h.tdms", "time,fx\n")
    with pytest.raises(ImportDataError, match=r"h\.tdms: not a TDMS file \(no 'TDSm' lead-in\)"):
        import_file(other, tmp_path / "o.h5", mapping={"fx_N": "F", "x_m": "Z"})
    truncated = tmp_path / "t.tdms"
    truncated.write_bytes(path.read_bytes()[:100])
    with pytest.raises(ImportDataError, match=r"t\.tdms: (not a readable TDMS|no channels)"):
        import_file(truncated, tmp_path / "o.h5", mapping={"fx_N": "F", "x_m": "E"})
    assert not (tmp_path / "o.h5").exists()


# --- the real silverbox file -------------------------------------------------------------------
@pytest.mark.needs_shared
def test_silverbox_import_via_cli(shared_dir: Path, tmp_path: Path, monkeypatch,
                                  capsys) -> None:
    src = shared_dir / "data" / "silverbox" / "SNLS80mV.csv"
    assert src.is_file(), f"{src} is missing from ../shared (present: a broken copy)"
    monkeypatch.chdir(REPO_ROOT)
    out = tmp_path / "sb.h5"
    rc = main(["import", "../shared/data/silverbox/SNLS80mV.csv", "--map", "fx_N=V1",
               "--map", "x_m=V2", "--fs", "610.3515625", "--no-steps", "--out", str(out)])
    assert rc == 0
    assert "131072 samples at 610.352 Hz" in capsys.readouterr().out
    # independent parse of the file: two numeric columns, header and trailing commas skipped
    ref = np.loadtxt(src, delimiter=",", skiprows=1, usecols=(0, 1))
    with open_run(out) as run:
        assert run.n_samples == 131072 == len(ref)
        assert run.sample_rate_hz == 610.3515625
        np.testing.assert_array_equal(run.signal("fx"), ref[:, 0])
        np.testing.assert_array_equal(run.signal("x"), ref[:, 1])
        assert run.test_spec["source_sha256"] == (
            "ae62d5a91230c10f76e6dd02c8a4fac3c9d4d8a95fbf50e87cb0c4885003e0f1")
    assert os.path.samefile(REPO_ROOT.parent / "shared", shared_dir)
