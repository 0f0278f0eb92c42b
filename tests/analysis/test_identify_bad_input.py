"""Bad input: missing channels, too few cycles, NaN and saturated samples, wrong kind of run.

Each case gives a message naming the run, the step and the channel; the rest of the analysis
still runs, and the report lists what was skipped and why. The runs are copies of a small real
sweep (SweepEngine on the simulated rig), edited on the way through `RunWriter`.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from analysis.identify import identify
from analysis.report import build_report
from control.run.sweep.engine import SweepSpec
from storage import RunWriter, open_run
from storage.records import StepRecord
from tests.analysis.test_identify_acceptance import DRY_LIMITS, run_sweep


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("bad_input")
    lub = SweepSpec(motion="x", lubricated=True, amplitude_m=[30e-6], freq_hz=[30.0, 45.0, 60.0],
                    settle_cycles=6, record_cycles=8)
    dry = SweepSpec(motion="circular_forward", load_n=[35.0], freq_hz=[25.0, 70.0, 120.0],
                    settle_cycles=6, record_cycles=8)
    return {"lub": run_sweep(d / "lub.h5", lub, seed=21),
            "dry": run_sweep(d / "dry.h5", dry, seed=22, limits=DRY_LIMITS)}


def rewrite(src: Path, dst: Path, drop: tuple[str, ...] = (),
            edit: Callable[[str, np.ndarray, list[dict]], None] | None = None,
            edit_steps: Callable[[list[dict]], None] | None = None, kind: str | None = None
            ) -> Path:
    """Copy a run through RunWriter, leaving out channels and editing data or steps."""
    with open_run(src) as r:
        cmap = r.channel_map
        chans = [c for c in cmap["ai"] if c["name"] not in drop]
        cmap = dict(cmap, ai=chans)
        data = {c["name"]: r.channel(c["name"]) for c in chans}
        drives = {n: r.channel(n) for n in r.drive_names}
        steps = r.steps
        w = RunWriter.create(dst, r.run_id + "-edited", kind or r.kind, chans, r.drive_names,
                             r.sample_rate_hz, channel_map=cmap, rig_config=r.rig_config,
                             test_spec=r.test_spec, lubricated=bool(r.attrs["lubricated"]))
    if edit is not None:
        for name, arr in data.items():
            edit(name, arr, steps)
    if edit_steps is not None:
        edit_steps(steps)
    ai = np.vstack([data[c["name"]] for c in chans])
    ao = np.vstack([drives[n] for n in w.ao_names])
    w.on_block(0, ai, ao)
    for st in steps:
        w.on_step(StepRecord.from_wire(st))
    w.close()
    return dst


def messages(ident) -> list[str]:
    return [s.message for s in ident.skipped]


def test_clean_runs_skip_nothing(source: dict[str, Path]) -> None:
    ident = identify([source["lub"], source["dry"]])
    assert messages(ident) == []
    assert len(ident.lubricated.points) == 3
    assert ident.dry is not None


def test_missing_channel_names_run_step_and_channel(source: dict[str, Path],
                                                    tmp_path: Path) -> None:
    bad = rewrite(source["lub"], tmp_path / "nofx.h5", drop=("fx",))
    ident = identify([bad, source["dry"]])
    msgs = messages(ident)
    assert any("lub-edited" in m and "step 1, channel fx" in m  # the file's step 0
               and "not in the run" in m for m in msgs), msgs
    assert ident.lubricated is None  # nothing left to identify the film with
    assert any("no usable unidirectional dwell" in m for m in msgs)
    assert ident.dry is not None  # the rest still runs
    page = build_report(ident, tmp_path / "report")
    assert "channel fx" in page.read_text()


def test_one_probe_missing_falls_back_to_the_other(source: dict[str, Path],
                                                   tmp_path: Path) -> None:
    bad = rewrite(source["lub"], tmp_path / "nox1.h5", drop=("x1",))
    ident = identify([bad])
    assert messages(ident) == []  # "x" is the mean of the probes present: x2 alone
    assert len(ident.lubricated.points) == 3


def test_too_few_cycles(source: dict[str, Path], tmp_path: Path) -> None:
    def shorten(steps: list[dict]) -> None:
        st = steps[1]
        st["last_sample"] = st["first_sample"] + int(2.5 * 10_000 / st["freq_hz"])

    bad = rewrite(source["lub"], tmp_path / "short.h5", edit_steps=shorten)
    ident = identify([bad])
    msgs = messages(ident)
    assert any("lub-edited" in m and "step 2 [" in m and "only 2 whole cycle(s) at 45 Hz" in m
               for m in msgs), msgs  # the file's step 1, counted from 1
    assert sorted(p.step for p in ident.lubricated.points) == [0, 2]
    doc = build_report(ident, tmp_path / "r").parent.joinpath("report.json").read_text()
    assert "only 2 whole cycle(s)" in json.loads(doc)["skipped"][0]["message"]


def test_nan_samples(source: dict[str, Path], tmp_path: Path) -> None:
    def nan_in_fx(name: str, arr: np.ndarray, steps: list[dict]) -> None:
        if name == "fx":
            st = steps[2]
            arr[st["first_sample"] + 100: st["first_sample"] + 103] = np.nan

    bad = rewrite(source["lub"], tmp_path / "nan.h5", edit=nan_in_fx)
    ident = identify([bad])
    msgs = messages(ident)
    assert any("step 3, channel fx" in m and "3 NaN/inf sample(s)" in m
               for m in msgs), msgs  # the file's step 2, counted from 1
    assert sorted(p.step for p in ident.lubricated.points) == [0, 1]


def test_saturated_probe(source: dict[str, Path], tmp_path: Path) -> None:
    with open_run(source["lub"]) as r:
        attrs = r.channel_attrs("x2")
    full_scale_m = (10.0 - attrs["offset_v"]) / attrs["gain_v_per_unit"]

    def clip_x2(name: str, arr: np.ndarray, steps: list[dict]) -> None:
        if name == "x2":
            st = steps[0]
            arr[st["first_sample"]: st["first_sample"] + 50] = full_scale_m

    bad = rewrite(source["lub"], tmp_path / "sat.h5", edit=clip_x2)
    ident = identify([bad])
    msgs = messages(ident)
    assert any("step 1, channel x2" in m and "saturated: 50 sample(s)" in m
               for m in msgs), msgs  # the file's step 0, counted from 1
    # x1 still measures the motion: the dwell is kept
    assert sorted(p.step for p in ident.lubricated.points) == [0, 1, 2]


def test_wrong_kind_for_the_analysis_asked(source: dict[str, Path], tmp_path: Path) -> None:
    ident = identify([source["lub"], source["dry"]], analyses=["dry"])
    msgs = messages(ident)
    assert any("run lub" in m and "kind 'sweep'" in m and "lubricated=True" in m
               and "'lubricated' analysis, which was not asked for" in m for m in msgs), msgs
    assert ident.lubricated is None
    assert ident.dry is not None
    # a static-kind file handed to the sweep analyses is not mistaken for a sweep
    wrong = rewrite(source["dry"], tmp_path / "as_static.h5", kind="static")
    ident = identify([wrong], analyses=["dry", "lubricated"])
    assert any("kind 'static'" in m and "'static' analysis" in m for m in messages(ident))
    assert ident.dry is None and not ident.static


def test_unknown_analysis_and_unreadable_file(source: dict[str, Path], tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown analyses"):
        identify([source["lub"]], analyses=["modal"])
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    ident = identify([junk, source["lub"]])
    assert any(str(junk) in m and "[open]" in m for m in messages(ident))
    assert ident.lubricated is not None
