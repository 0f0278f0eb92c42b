"""Run-file writer and reader: round trips, SWMR live reading, kill -9 recovery, broken files."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from storage import MissingSignalError, RunFileError, RunWriter, open_run
from storage.reader import _superblock_problem
from storage.records import StepRecord
from storage.runfile import FORMAT_VERSION
from tests.storage import _writer_proc as proc

HELPER = Path(proc.__file__)

CHANNELS = [
    {"name": "fx", "units": "N", "kind": "load_cell", "sensor": "LC-X", "gain_v_per_unit": 0.02,
     "offset_v": 0.0, "physical_channel": "Dev1/ai0"},
    {"name": "x1", "units": "m", "kind": "eddy_current_probe", "gain_v_per_unit": 7952.7,
     "offset_v": 0.1, "physical_channel": "Dev1/ai2"},
    {"name": "x2", "units": "m", "kind": "eddy_current_probe", "gain_v_per_unit": 7677.2,
     "offset_v": -0.1, "physical_channel": "Dev1/ai3"},
    {"name": "t_oil", "units": "degC", "kind": "thermocouple", "gain_v_per_unit": 0.01},
]


def _step(i: int, first: int, last: int, names: list[str], ao: list[str]) -> dict:
    return {
        "index": i, "freq_hz": 10.0 + i, "target_kind": "displacement", "target_value": 2e-5,
        "motion": "circular_forward", "first_sample": first, "last_sample": last, "updates": 3 + i,
        "converged": i % 2 == 0, "reason": "" if i % 2 == 0 else "max updates (8) reached",
        "harmonics": {n: [[0.5 * k + c, -0.25 * k - i] for k in range(5)]
                      for c, n in enumerate(names)},
        "drive_v": {n: [0.1 * (c + 1), -0.2 * i] for c, n in enumerate(ao)},
    }


def _make(path: Path, **kw) -> RunWriter:
    args = dict(operator="A. Tester", notes="baseline", rig_config={"structure": {"mass_kg": 9.7}},
                test_spec={"freqs_hz": [10, 20]}, lubricated=True, flush_interval_s=0)
    args.update(kw)
    return RunWriter.create(path, "run-001", "sweep", CHANNELS, ["shaker_x", "shaker_y"],
                            5000.0, **args)


# --- round trip ------------------------------------------------------------------------------
@pytest.mark.parametrize("flush_interval_s", [0.0, 0.01])  # synchronous; background I/O thread
def test_metadata_blocks_steps_events_round_trip(tmp_path: Path, flush_interval_s: float) -> None:
    path = tmp_path / "run.h5"
    rng = np.random.default_rng(1)
    ai = rng.normal(size=(4, 12_345))
    ao = rng.normal(size=(2, 12_345))
    with _make(path, chunk_samples=1024, flush_interval_s=flush_interval_s) as w:
        w.on_event("state", "running", 0)
        w.on_block(0, ai[:, :5000], ao[:, :5000])
        w.on_step(StepRecord.from_wire(_step(0, 0, 5000, ["fx", "x1"],
                                             ["shaker_x", "shaker_y"])))
        w.on_block(5000, ai[:, 5000:], ao[:, 5000:])
        w.on_event("limit_trip", "force fx 460 N > 448 N", 12_000)
    with open_run(path) as run:
        assert run.kind == "sweep" and run.run_id == "run-001"
        assert run.sample_rate_hz == 5000.0
        assert run.channel_names == ["fx", "x1", "x2", "t_oil"]
        assert run.drive_names == ["shaker_x", "shaker_y"]
        assert run.n_samples == 12_345
        assert run.duration_s == pytest.approx(12_345 / 5000.0)
        for i, name in enumerate(run.channel_names):
            np.testing.assert_array_equal(run.channel(name), ai[i])
        np.testing.assert_array_equal(run.channel("shaker_y"), ao[1])
        np.testing.assert_array_equal(run.signal("x"), (ai[1] + ai[2]) / 2)
        np.testing.assert_array_equal(run.signal("fx"), ai[0])
        np.testing.assert_array_equal(run.channel("fx", 100, 200), ai[0, 100:200])
        a = run.attrs
        # as docs/run-files.md states them (a new format version is a documented change)
        assert a["format"] == "sfdrig-run" and a["format_version"] == 2
        assert a["operator"] == "A. Tester" and a["notes"] == "baseline"
        assert a["status"] == "completed" and a["status_reason"] == ""
        assert a["stop_time"] >= a["start_time"] != ""
        assert a["lubricated"] is True or a["lubricated"] == 1
        assert a["software_version"].startswith("sfdrig")
        assert run.rig_config == {"structure": {"mass_kg": 9.7}}
        assert run.test_spec == {"freqs_hz": [10, 20]}
        assert [c["name"] for c in run.channel_map["ai"]] == ["fx", "x1", "x2", "t_oil"]
        ca = run.channel_attrs("x1")
        assert ca["units"] == "m" and ca["gain_v_per_unit"] == 7952.7 and ca["offset_v"] == 0.1
        assert ca["physical_channel"] == "Dev1/ai2" and ca["kind"] == "eddy_current_probe"
        assert run.units("shaker_x") == "V"
        assert run.steps == [_step(0, 0, 5000, ["fx", "x1"], ["shaker_x", "shaker_y"])]
        ev = run.events
        assert [(e["kind"], e["message"], e["sample"]) for e in ev] == [
            ("state", "running", 0), ("limit_trip", "force fx 460 N > 448 N", 12_000)]
        assert ev[0]["time"].endswith("+00:00")
        # chunked, compressed, as contract B asks
        ds = run.h5["channels/fx"]
        assert ds.chunks == (1024,) and ds.compression == "gzip" and ds.maxshape == (None,)
        assert ds.shuffle and run.h5["drive/shaker_x"].compression == "gzip"


def test_the_io_thread_is_woken_once_a_chunk_not_once_a_block(tmp_path: Path) -> None:
    """A paced run hands over a 10 ms block at a time: the I/O thread has work only when a
    chunk is complete (and at its flushes, which it keeps to on its own), so on_block wakes it
    only then; every sample still reaches the file."""
    wakes = []
    rng = np.random.default_rng(41)
    data = rng.normal(size=(len(CHANNELS) + 2, 2500))
    with _make(tmp_path / "w.h5", chunk_samples=1000, flush_interval_s=60.0) as w:
        real_set = w._wake.set
        w._wake.set = lambda: (wakes.append(w._next_sample), real_set())
        for k in range(0, 2500, 100):  # 25 blocks of 100 samples
            w.on_block(k, data[:len(CHANNELS), k:k + 100], data[len(CHANNELS):, k:k + 100])
        assert wakes == [1000, 2000]  # the blocks that completed the 1st and 2nd chunk
    with open_run(tmp_path / "w.h5") as run:
        for i, c in enumerate(CHANNELS):
            np.testing.assert_array_equal(run.channel(c["name"]), data[i])
        np.testing.assert_array_equal(run.h5["drive/shaker_y"][:], data[-1])


def test_lzf_option(tmp_path: Path) -> None:
    data = np.arange(30.0).reshape(3, 10)
    with RunWriter.create(tmp_path / "l.h5", "l", "sweep", ["a", "b"], ["d"], 10.0,
                          compression="lzf", flush_interval_s=0) as w:
        w.on_block(0, data[:2], data[2:])
    with open_run(tmp_path / "l.h5") as run:
        assert run.h5["channels/a"].compression == "lzf"
        np.testing.assert_array_equal(run.channel("b"), data[1])
        np.testing.assert_array_equal(run.channel("d"), data[2])
    with pytest.raises(ValueError, match="compression 'zstd'"):
        RunWriter.create(tmp_path / "z.h5", "z", "sweep", ["a"], [], 10.0, compression="zstd")


@given(
    n_ai=st.integers(1, 3),
    n_ao=st.integers(0, 2),
    chunk=st.integers(16, 300),
    ops=st.lists(
        st.one_of(
            st.tuples(st.just("block"), st.integers(0, 700)),
            st.tuples(st.just("step"), st.integers(0, 3)),
            st.tuples(st.just("event"), st.text(max_size=40)),
            st.tuples(st.just("flush"), st.just(0)),
        ),
        max_size=25,
    ),
    seed=st.integers(0, 2**32 - 1),
)
def test_round_trip_property(n_ai: int, n_ao: int, chunk: int, ops: list, seed: int) -> None:
    """Any sequence of blocks (any sizes, including empty), steps and events reads back equal."""
    rng = np.random.default_rng(seed)
    names = [f"c{i}" for i in range(n_ai)]
    ao_names = [f"d{i}" for i in range(n_ao)]
    ai_all: list = []
    ao_all: list = []
    steps: list = []
    events: list = []
    first = 0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.h5"
        with RunWriter.create(path, "p", "static", names, ao_names, 100.0,
                              chunk_samples=chunk, flush_interval_s=0) as w:
            for op, arg in ops:
                if op == "block":
                    ai = rng.normal(size=(n_ai, arg))
                    ao = rng.normal(size=(n_ao, arg))
                    w.on_block(first, ai, ao if n_ao else None)
                    first += arg
                    ai_all.append(ai)
                    ao_all.append(ao)
                elif op == "step":
                    s = _step(len(steps), max(0, first - arg), first, names[: arg + 1], ao_names)
                    w.on_step(StepRecord.from_wire(s))
                    steps.append(s)
                elif op == "event":
                    w.on_event("operator", arg, first)
                    # NUL cannot live in an HDF5 string: it is kept visibly as "\0"
                    events.append(("operator", arg.replace("\x00", "\\0"), first))
                else:
                    w.flush()
        with open_run(path) as run:
            assert run.n_samples == first
            ai_ref = np.concatenate(ai_all, 1) if ai_all else np.empty((n_ai, 0))
            ao_ref = np.concatenate(ao_all, 1) if ao_all else np.empty((n_ao, 0))
            for i, n in enumerate(names):
                np.testing.assert_array_equal(run.channel(n), ai_ref[i])
            for i, n in enumerate(ao_names):
                np.testing.assert_array_equal(run.channel(n), ao_ref[i])
            assert run.steps == steps
            assert [(e["kind"], e["message"], e["sample"]) for e in run.events] == events
            assert run.status == "completed"


def test_extra_step_keys_and_unknown_harmonics_are_kept(tmp_path: Path) -> None:
    step = _step(0, 0, 10, ["fx"], ["shaker_x"])
    step["phase_deg"] = 12.5
    step["harmonics"]["hammer"] = [[1.0, 2.0]] * 5
    with _make(tmp_path / "e.h5") as w:
        w.on_block(0, np.zeros((4, 10)), np.zeros((2, 10)))
        w.on_step(StepRecord.from_wire(step))
        w.on_step(StepRecord.from_wire({
            "index": np.int64(1), "freq_hz": np.float64(12.5), "rms_n": np.float64(1.5),
            "phases_deg": np.array([1.0, 2.0]), "converged": np.bool_(True)}))
    with open_run(tmp_path / "e.h5") as run:
        steps = run.steps
        assert steps[0] == step
        assert (steps[1]["index"], steps[1]["freq_hz"], steps[1]["converged"]) == (1, 12.5, True)
        assert (steps[1]["rms_n"], steps[1]["phases_deg"]) == (1.5, [1.0, 2.0])


def test_long_texts_are_truncated_not_lost_silently(tmp_path: Path) -> None:
    with _make(tmp_path / "t.h5") as w:
        w.on_event("warning", "é" * 2000, 0)
    with open_run(tmp_path / "t.h5") as run:
        msg = run.events[0]["message"]
        assert msg.endswith("[truncated]") and msg.startswith("éé")
        assert len(msg.encode()) <= 1024


# --- writer checks ---------------------------------------------------------------------------
def test_writer_rejects_bad_blocks_and_arguments(tmp_path: Path) -> None:
    with _make(tmp_path / "b.h5") as w:
        with pytest.raises(ValueError, match=r"ai block has shape \(3, 5\), expected \(4, n\)"):
            w.on_block(0, np.zeros((3, 5)), np.zeros((2, 5)))
        with pytest.raises(ValueError, match=r"ao block has shape \(2, 4\), expected \(2, 5\)"):
            w.on_block(0, np.zeros((4, 5)), np.zeros((2, 4)))
        w.on_block(0, np.zeros((4, 5)), np.zeros((2, 5)))
        with pytest.raises(ValueError, match="starts at sample 7, expected 5"):
            w.on_block(7, np.zeros((4, 5)), np.zeros((2, 5)))
        with pytest.raises(ValueError, match="close status 'done'"):
            w.close("done")
    with pytest.raises(RuntimeError, match="closed"):
        w.on_block(5, np.zeros((4, 5)), np.zeros((2, 5)))
    with pytest.raises(FileExistsError, match="exists already"):
        _make(tmp_path / "b.h5")
    with pytest.raises(ValueError, match="kind 'sweeep'"):
        RunWriter.create(tmp_path / "k.h5", "r", "sweeep", ["a"], [], 10.0)
    with pytest.raises(ValueError, match=r"duplicate names \['a'\]"):
        RunWriter.create(tmp_path / "k.h5", "r", "sweep", ["a", "a"], [], 10.0)
    with pytest.raises(ValueError, match="sample_rate_hz must be a positive"):
        RunWriter.create(tmp_path / "k.h5", "r", "sweep", ["a"], [], 0.0)
    with pytest.raises(ValueError, match="invalid name 'a/b'"):
        RunWriter.create(tmp_path / "k.h5", "r", "sweep", ["a/b"], [], 10.0)
    assert not (tmp_path / "k.h5").exists()


def test_writer_falling_behind_raises_instead_of_filling_memory(tmp_path: Path) -> None:
    w = _make(tmp_path / "slow.h5", flush_interval_s=0.05, max_backlog_s=1.0)
    try:
        with w._io_lock:  # the I/O thread is stuck (a stalled disk)
            w.on_block(0, np.zeros((4, 4000)), np.zeros((2, 4000)))  # 0.8 s at 5 kS/s: fine
            with pytest.raises(OSError, match=r"1\.2 s behind the acquisition \(limit 1 s\)"):
                w.on_block(4000, np.zeros((4, 2000)), np.zeros((2, 2000)))
        assert w.wait_flushed(4000, timeout_s=10.0)
    finally:
        w.close()
    with open_run(tmp_path / "slow.h5") as run:
        assert run.n_samples == 4000 and run.status == "completed"


def test_writer_behind_an_unpaced_producer_holds_it_back(tmp_path: Path) -> None:
    """The simulated rig's fast mode makes data faster than any disk takes it: with
    ``wait_when_behind`` the block that would go past the backlog waits for the I/O thread
    (here stalled until the producer waits) instead of failing the run (`sfdrig demo` failed a
    flow test that way: "30.0 s behind the acquisition")."""
    w = _make(tmp_path / "fast.h5", flush_interval_s=0.05, max_backlog_s=1.0,
              wait_when_behind=True)
    stalled, waiting = threading.Event(), threading.Event()

    def stalled_disk() -> None:
        with w._io_lock:
            stalled.set()
            # until the producer waits in on_block (its wait is on the condition below)
            while not w._drained._waiters:  # type: ignore[attr-defined]
                waiting.wait(0.001)
    stall = threading.Thread(target=stalled_disk)
    stall.start()
    assert stalled.wait(10.0)
    try:
        w.on_block(0, np.zeros((4, 4000)), np.zeros((2, 4000)))  # 0.8 s at 5 kS/s
        w.on_block(4000, np.ones((4, 2000)), np.ones((2, 2000)))  # 1.2 s behind: waits
        stall.join(10.0)
        assert not stall.is_alive()
        w.on_block(6000, np.ones((4, 6000)), np.ones((2, 6000)))
    finally:
        w.close()
    with open_run(tmp_path / "fast.h5") as run:
        assert run.n_samples == 12000 and run.status == "completed"
        assert run.channel("fx", 3999, 4001).tolist() == [0.0, 1.0]


def test_context_manager_records_failure(tmp_path: Path) -> None:
    with pytest.raises(ZeroDivisionError), _make(tmp_path / "f.h5") as w:
        w.on_block(0, np.ones((4, 3)), np.ones((2, 3)))
        1 / 0  # noqa: B018
    with open_run(tmp_path / "f.h5") as run:
        assert run.status == "failed"
        assert run.attrs["status_reason"] == "ZeroDivisionError: division by zero"
        assert run.n_samples == 3


def test_write_failure_at_close_still_ends_the_run(tmp_path: Path, monkeypatch) -> None:
    """A disk-full error while flushing: the run is closed, marked failed, and the caller told."""
    w = _make(tmp_path / "full.h5", chunk_samples=64)
    w.on_block(0, np.ones((4, 200)), np.zeros((2, 200)))  # 192 samples written, 8 pending
    w.flush()
    w.on_block(200, np.ones((4, 10)), np.zeros((2, 10)))

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(w, "_write_pending", disk_full)
    with pytest.raises(OSError, match="run closed with errors: .*No space left"):
        w.close("completed")
    with open_run(tmp_path / "full.h5") as run:
        assert run.status == "failed"
        assert "samples from 200 on may be lost" in run.attrs["status_reason"]
        assert run.n_samples == 200


def test_aborted_close_keeps_reason(tmp_path: Path) -> None:
    w = _make(tmp_path / "a.h5")
    w.close("aborted", "operator pressed abort")
    w.close("completed")  # second close is a no-op
    with open_run(tmp_path / "a.h5") as run:
        assert (run.status, run.attrs["status_reason"]) == ("aborted", "operator pressed abort")


@given(text=st.text(alphabet=st.characters(codec=None, exclude_categories=()), max_size=3000))
def test_any_text_survives_in_attributes_events_and_the_close_reason(text: str) -> None:
    """NULs, lone surrogates and long texts: written (NUL as the two characters \\0, a lone
    surrogate as its escape), never an error, so closing the run cannot fail on its reason."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "s.h5"
        w = _make(path, operator=text, notes=text)
        w.on_event("operator", text, 0)
        w.close("aborted", text)
        expected = text.replace("\x00", "\\0").encode("utf-8", "backslashreplace").decode()
        with h5py.File(path, "r") as f:
            assert f.attrs["status"] == "aborted"
            assert f.attrs["status_reason"] == expected
            assert f.attrs["operator"] == f.attrs["notes"] == expected
            message = f["events"][0]["message"].decode()
        assert expected.startswith(message.removesuffix(" [truncated]"))


def test_background_flush_makes_a_lone_block_visible(tmp_path: Path) -> None:
    """A block that fills no chunk and is followed by nothing is flushed within the interval."""
    path = tmp_path / "bg.h5"
    w = _make(path, flush_interval_s=0.05, chunk_samples=4096)
    try:
        w.on_block(0, np.full((4, 100), 3.0), np.zeros((2, 100)))
        assert w.wait_flushed(100, timeout_s=10.0)
        with open_run(path) as run:
            assert run.status == "running" and run.stop_time == ""
            np.testing.assert_array_equal(run.channel("fx"), np.full(100, 3.0))
    finally:
        w.close()


def test_a_step_and_an_event_are_in_the_file_when_their_calls_return(tmp_path: Path) -> None:
    """The publisher announces a step after `on_step` returns: a client that saw it must find it
    in the file even if the daemon is killed the next moment, whatever the flush interval."""
    path = tmp_path / "durable.h5"
    w = _make(path, flush_interval_s=3600.0, chunk_samples=4096)
    try:
        w.on_block(0, np.ones((4, 300)), np.zeros((2, 300)))
        w.on_step(StepRecord.from_wire(_step(0, 0, 300, ["fx"], [])))
        with open_run(path) as run:  # at once: no wait, no flush asked for
            assert len(run.steps) == 1 and run.n_samples == 300
        w.on_event("note", "a note", 300)
        with open_run(path) as run:
            assert [e["message"] for e in run.events] == ["a note"]
    finally:
        w.close()


# --- SWMR: live reading ----------------------------------------------------------------------
def test_swmr_reader_in_same_process_sees_growth(tmp_path: Path) -> None:
    path = tmp_path / "live.h5"
    w = _make(path, chunk_samples=256)
    try:
        w.on_block(0, np.ones((4, 300)), np.zeros((2, 300)))
        w.flush()
        with open_run(path) as run:
            assert run.n_samples == 300 and run.status == "running"
            w.on_block(300, np.full((4, 200), 2.0), np.zeros((2, 200)))
            w.on_step(StepRecord.from_wire(_step(0, 0, 500, ["fx"], [])))
            run.refresh()
            assert run.n_samples == 500 and len(run.steps) == 1
            assert run.channel("x2")[-1] == 2.0
    finally:
        w.close()


def test_swmr_reader_in_another_process_while_writing(tmp_path: Path) -> None:
    path = tmp_path / "live2.h5"
    w = RunWriter.create(path, "live", "sweep", [f"c{i}" for i in range(proc.N_AI)],
                         [f"d{i}" for i in range(proc.N_AO)], proc.FS_HZ, flush_interval_s=0,
                         chunk_samples=1500)
    reader = None
    try:
        w.on_block(0, *proc.expected_block(0, 1000))
        w.flush()
        reader = subprocess.Popen([sys.executable, str(HELPER), "reader", str(path)],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert reader.stdin is not None and reader.stdout is not None
        to_reader, from_reader = reader.stdin, reader.stdout
        first = 1000
        for round_ in range(3):
            to_reader.write("read\n")
            to_reader.flush()
            n, n_steps, n_events, total = from_reader.readline().split()
            assert (int(n), int(n_steps), int(n_events)) == (first, round_, round_)
            assert float(total) == pytest.approx(proc.expected_block(0, first)[0][0].sum(),
                                                 rel=1e-12)
            w.on_block(first, *proc.expected_block(first, 2500))
            first += 2500
            w.on_event("info", f"round {round_}", first)
            w.on_step(StepRecord.from_wire({"index": round_, "freq_hz": 5.0}))
        w.close()
        to_reader.write("read\nquit\n")
        to_reader.flush()
        n, n_steps, n_events, _ = from_reader.readline().split()
        assert (int(n), int(n_steps), int(n_events)) == (first, 3, 3)
        assert reader.wait(timeout=30) == 0
    finally:
        if not w.closed:
            w.close()
        if reader is not None and reader.poll() is None:
            reader.kill()
            reader.wait()
        for stream in (reader.stdin, reader.stdout) if reader is not None else ():
            if stream is not None:
                stream.close()


# --- kill -9 ---------------------------------------------------------------------------------
def test_writer_killed_mid_run_leaves_every_flushed_block(tmp_path: Path) -> None:
    path = tmp_path / "killed.h5"
    child = subprocess.Popen([sys.executable, str(HELPER), "writer", str(path)],
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    out = child.stdout
    last = 0
    try:
        # Kill while it is writing, once at least 100 000 samples (5 steps) are known flushed.
        for line in out:
            last = int(line.split()[1])
            if last >= 100_000:
                break
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.wait()
        out.close()
    assert child.returncode == -signal.SIGKILL
    assert last >= 100_000
    with open_run(path) as run:
        assert run.status == "running" and run.stop_time == ""
        n = run.n_samples
        assert n >= last
        ai, ao = proc.expected_block(0, n)
        for i in range(proc.N_AI):
            np.testing.assert_array_equal(run.channel(f"c{i}"), ai[i])
        for i in range(proc.N_AO):
            np.testing.assert_array_equal(run.channel(f"d{i}"), ao[i])
        steps = run.steps
        assert len(steps) >= last // 20_000
        assert [s["last_sample"] for s in steps] == [20_000 * (k + 1) for k in range(len(steps))]


# --- broken files ----------------------------------------------------------------------------
@pytest.fixture
def good_run(tmp_path: Path) -> Path:
    path = tmp_path / "good.h5"
    with _make(path, chunk_samples=512) as w:
        w.on_block(0, np.ones((4, 20_000)), np.zeros((2, 20_000)))
        w.on_step(StepRecord.from_wire(_step(0, 0, 100, ["fx"], ["shaker_x"])))
    return path


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(RunFileError, match=r"nope\.h5: no such file"):
        open_run(tmp_path / "nope.h5")
    with pytest.raises(RunFileError, match="is a directory"):
        open_run(tmp_path)


def test_not_hdf5(tmp_path: Path) -> None:
    p = tmp_path / "notes.h5"
    p.write_text("time_s,fx_N\n0,1\n")
    with pytest.raises(RunFileError, match=r"notes\.h5: not an HDF5 file"):
        open_run(p)


def test_truncated_file(good_run: Path) -> None:
    size = good_run.stat().st_size
    with open(good_run, "r+b") as f:
        f.truncate(size // 3)
    with (pytest.raises(RunFileError, match=r"good\.h5: .*(truncated|damaged)"),
          open_run(good_run) as run):
        run.channel("fx")


@pytest.mark.parametrize("fraction", [0.002, 0.05, 0.3, 0.6, 0.9, 0.99])
def test_truncated_anywhere_is_refused_as_truncated(good_run: Path, fraction: float) -> None:
    """Whatever part of a closed file is cut, opening it says the file and that it is cut short
    (the superblock records the whole file's length): no partial data read as if whole."""
    data = good_run.read_bytes()
    good_run.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(RunFileError, match=re.escape(str(good_run)) + ": .*truncated"):
        open_run(good_run)


def test_truncated_file_of_a_live_or_dead_writer_fails_fast(tmp_path: Path) -> None:
    """The copy of a file still marked open for writing, cut short: RunFileError, no hang
    (HDF5's SWMR reader would retry the missing metadata for hours)."""
    w = _make(tmp_path / "live.h5")
    try:
        w.on_block(0, np.ones((4, 5000)), np.zeros((2, 5000)))
        w.on_step(StepRecord.from_wire(_step(0, 0, 5000, ["fx"], [])))
        data = (tmp_path / "live.h5").read_bytes()
    finally:
        w.close()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(RunFileError, match=rf"cut\.h5: .*truncated.*{len(data) // 2}"):
        open_run(cut)
    assert _superblock_problem(cut) == (
        f"truncated: {len(data) // 2} bytes where the HDF5 superblock records {len(data)} "
        "(or the file is still being created)")
    whole = tmp_path / "whole.h5"  # the same bytes uncut open as a SWMR file
    whole.write_bytes(data)
    with open_run(whole) as run:
        assert run.h5.swmr_mode and run.n_samples == 5000 and len(run.steps) == 1


def test_wrong_format_attr(good_run: Path) -> None:
    with h5py.File(good_run, "r+") as f:
        f.attrs["format"] = "other-format"
    with pytest.raises(RunFileError, match="format attribute is 'other-format', expected"):
        open_run(good_run)


def test_hdf5_without_format(tmp_path: Path) -> None:
    p = tmp_path / "plain.h5"
    with h5py.File(p, "w") as f:
        f["x"] = [1.0]
    with pytest.raises(RunFileError, match=r"plain\.h5: not an sfdrig run file"):
        open_run(p)


def test_newer_format_version(good_run: Path) -> None:
    with h5py.File(good_run, "r+") as f:
        f.attrs["format_version"] = FORMAT_VERSION + 1
    with pytest.raises(RunFileError, match=f"format_version {FORMAT_VERSION + 1} is newer"):
        open_run(good_run)


@pytest.mark.parametrize("obj", ["steps", "events", "channels", "step_harmonics"])
def test_missing_dataset(good_run: Path, obj: str) -> None:
    with h5py.File(good_run, "r+") as f:
        del f[obj]
    with pytest.raises(RunFileError, match=rf"good\.h5: missing /{obj}"):
        open_run(good_run)


def test_missing_channel_dataset(good_run: Path) -> None:
    with h5py.File(good_run, "r+") as f:
        del f["channels/x2"]
    with pytest.raises(RunFileError, match=r"/channels holds \['fx', 't_oil', 'x1'\]"):
        open_run(good_run)


def test_missing_attribute_and_bad_json(good_run: Path) -> None:
    with h5py.File(good_run, "r+") as f:
        f.attrs["channel_map"] = "{not json"
    with pytest.raises(RunFileError, match="'channel_map' is not valid JSON"):
        open_run(good_run)
    with h5py.File(good_run, "r+") as f:
        del f.attrs["sample_rate_hz"]
    with pytest.raises(RunFileError, match=r"missing root attribute\(s\) \['sample_rate_hz'\]"):
        open_run(good_run)


def test_missing_signal_names_what_exists(good_run: Path) -> None:
    with open_run(good_run) as run:
        with pytest.raises(MissingSignalError, match=r"no signal 'y': neither a channel 'y' nor"):
            run.signal("y")
        with pytest.raises(KeyError):
            run.channel("p_in")
        with pytest.raises(RunFileError, match="'z' is not a canonical signal"):
            run.signal("z")
        assert run.has_signal("x") and not run.has_signal("y")


def test_channel_map_json_is_stored_verbatim(tmp_path: Path) -> None:
    cmap = {"sample_rate_hz": 10.0, "ai": [{"name": "a"}], "ao": [], "device": {"name": "Dev1"}}
    with RunWriter.create(tmp_path / "c.h5", "c", "flow", ["a"], [], 10.0,
                          channel_map=json.dumps(cmap), flush_interval_s=0):
        pass
    with open_run(tmp_path / "c.h5") as run:
        assert run.channel_map == cmap and run.rig_config is None and run.test_spec is None
        assert run.drive_names == [] and run.steps == []


def test_the_event_kinds_of_the_listener_and_the_run_file_agree() -> None:
    """Two copies (control must not import h5py to name an event): kept equal here."""
    from control.run.listener import EVENT_KINDS as sent
    from storage.layout import EVENT_KINDS as stored

    assert sent == stored and "fault" in stored
