"""LiveView from synthetic blocks made here (plain numpy sines, no simulator): triggering,
decimation, orbit, live harmonics, the step table and the time left, with numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from control.wire.client import Message
from storage.records import StepRecord
from tests.fake_daemon import heartbeat
from web.view import LiveView, step_point, upward_crossings

FS = 10_000.0
NAMES = ["fx", "fy", "x1", "x2", "y1", "y2", "shaker_x", "shaker_y"]
N_AI = 6


def blocks(freq_hz: float, n_blocks: int, n: int = 250, amp_m: float = 20e-6,
           h3: float = 0.05, phase0: float = 0.7, seed: int = 1):
    """Blocks of a forward circular orbit: x = A cos, y = A sin (+3X on x), drives at phase0."""
    rng = np.random.default_rng(seed)
    for b in range(n_blocks):
        k = np.arange(b * n, (b + 1) * n)
        w = 2 * np.pi * freq_hz * k / FS
        x = amp_m * (np.cos(w) + h3 * np.cos(3 * w)) + 5e-6  # probe offset
        y = amp_m * np.sin(w)
        rows = np.stack([
            40 * np.cos(w + 0.3), 40 * np.sin(w + 0.3),
            x + rng.normal(0, 1e-9, n), x, y, y,
            0.8 * np.sin(w + phase0), -0.8 * np.cos(w + phase0),
        ])
        header = {"first_sample": int(k[0]), "n_samples": n, "shape": list(rows.shape),
                  "n_ai": N_AI, "channels": NAMES, "sample_rate_hz": FS,
                  "t_acquired": 1000.0 + b, "seq": b, "run_id": "R1", "topic": "block"}
        yield Message("block", header, rows, 1000.0 + b)


def test_traces_are_triggered_whole_cycles_decimated_with_orbit_and_harmonics():
    view = LiveView(buffer_s=0.5, cycles=3, points=200)
    view.set_status(heartbeat(run_id="R1", progress={"freq_hz": 20.0}))
    for m in blocks(20.0, 40):  # 1 s of data through a 0.5 s ring: it wraps
        view.on_message(m)
    tr = view.frame(now=2000.0)["traces"]
    assert tr["triggered"]
    # 3 cycles at 20 Hz = 1500 samples, decimated to at most 200 points
    assert tr["decimation"] == 8 and len(tr["t_ms"]) == 188
    assert tr["freq_hz"] == pytest.approx(20.0, rel=1e-3)
    # the window starts at an upward crossing of the X drive: sin(w + 0.7) = 0
    sx = np.asarray(tr["channels"]["shaker_x"])
    assert abs(sx[0]) < 0.8 * 2 * np.pi * 20 / FS * 1.01 and sx[1] > 0
    # orbit: radius 20 um about the centre (5 um offset on x), 3X adds 5 % on x
    ox, oy = np.asarray(tr["orbit_x_um"]), np.asarray(tr["orbit_y_um"])
    assert oy.max() == pytest.approx(20.0, rel=0.01) and oy.min() == pytest.approx(-20.0, rel=0.01)
    assert (ox.max() + ox.min()) / 2 == pytest.approx(5.0, abs=0.6)
    h = np.asarray(tr["harmonics"]["x1"])
    assert h[0] == pytest.approx(20e-6, rel=1e-3)
    assert h[2] / h[0] == pytest.approx(0.05, rel=0.01)
    assert h[1] / h[0] < 1e-3 and h[3] / h[0] < 1e-3
    assert np.asarray(tr["harmonics"]["fy"])[0] == pytest.approx(40.0, rel=1e-3)


def test_the_same_phase_of_the_drive_starts_every_frame():
    view = LiveView(buffer_s=0.5, cycles=2, points=10_000)
    firsts = []
    for i, m in enumerate(blocks(33.0, 30)):
        view.on_message(m)
        if i >= 10:
            firsts.append(view.frame()["traces"]["channels"]["shaker_x"][0])
    # every frame starts within one sample's rise of the drive's zero crossing
    assert max(abs(v) for v in firsts) < 0.8 * 2 * np.pi * 33 / FS


def test_no_drive_shows_the_last_100_ms_untriggered():
    view = LiveView(buffer_s=0.5)
    for m in blocks(20.0, 8):
        m.array[N_AI:] = 0.0
        view.on_message(m)
    tr = view.frame()["traces"]
    assert not tr["triggered"] and tr["harmonics"] == {}
    assert tr["t_ms"][-1] == pytest.approx(100.0 - 1e3 / FS * tr["decimation"], abs=0.2)


def test_a_lost_block_restarts_the_traces():
    view = LiveView(buffer_s=0.5)
    msgs = list(blocks(20.0, 10))
    for m in msgs[:5] + msgs[6:]:  # block 5 lost
        view.on_message(m)
    tr = view.frame()["traces"]
    assert tr["last_sample"] == 10 * 250 - 1
    assert len(tr["t_ms"]) * tr["decimation"] <= 4 * 250  # only what came after the gap


def circular_step(index: int, freq: float, ax: float, phase_deg: float) -> dict:
    zx = ax
    zy = ax * 1.02 * complex(math.cos(math.radians(phase_deg)), math.sin(math.radians(phase_deg)))
    harm = {"fx": [[40.2, 0.0]] + [[0, 0]] * 4, "fy": [[0.0, -40.2]] + [[0, 0]] * 4,
            "x1": [[zx, 0]] + [[0, 0]] * 4, "x2": [[zx, 0]] + [[0, 0]] * 4,
            "y1": [[zy.real, zy.imag]] + [[0, 0]] * 4, "y2": [[zy.real, zy.imag]] + [[0, 0]] * 4}
    return {"index": index, "freq_hz": freq, "target_kind": "load", "target_value": 40.0,
            "motion": "circular_forward", "updates": 2, "converged": True, "reason": "",
            "harmonics": harm}


def test_step_point_of_a_load_held_circular_step():
    p = step_point(StepRecord.from_wire(circular_step(0, 50.0, 10e-6, -88.5)), 1.0, 1.0)
    assert p["unit"] == "N" and p["target"] == 40.0
    assert p["achieved"] == pytest.approx(40.2) and p["error_pct"] == pytest.approx(0.5)
    assert p["phase_deg"] == pytest.approx(-90.0)  # fy relative to fx for a load target
    assert p["phase_target_deg"] == -90.0 and p["phase_band_deg"] == 1.0
    assert p["x_um"] == pytest.approx(10.0) and p["y_um"] == pytest.approx(10.2)


def test_step_point_of_a_displacement_x_step_has_the_frf_phase_and_no_phase_target():
    h = {"fx": [[0.0, 30.0]] + [[0, 0]] * 4, "x1": [[25e-6, 0]] + [[0, 0]] * 4,
         "x2": [[25.5e-6, 0]] + [[0, 0]] * 4}
    p = step_point(StepRecord.from_wire({"index": 3, "freq_hz": 40.0, "target_kind": "displacement",
                    "target_value": 25e-6, "motion": "x", "harmonics": h}), 2.0, 1.0)
    assert p["unit"] == "um" and p["achieved"] == pytest.approx(25.25)
    assert p["error_pct"] == pytest.approx(1.0) and p["band_pct"] == 2.0
    assert p["phase_deg"] == pytest.approx(-90.0)  # x lags fx by 90 deg
    assert p["phase_target_deg"] is None and p["phase_label"] == "x rel. fx"
    # F/X = 30j N / 25.25 um: 1.188 MN/m in quadrature (the motion lags by 90 deg)
    assert p["kx_re_mn_per_m"] == pytest.approx(0.0, abs=1e-12)
    assert p["kx_im_mn_per_m"] == pytest.approx(30.0 / 25.25e-6 / 1e6)
    assert math.isnan(p["ky_re_mn_per_m"]) and math.isnan(p["drive_v"])


def test_step_point_drive_level_and_stiffness_of_a_circular_step():
    step = {**circular_step(0, 50.0, 10e-6, -90.0),
            "drive_v": {"shaker_x": [3.0, 4.0], "shaker_y": [0.0, -2.0]}}
    p = step_point(StepRecord.from_wire(step), 1.0, 1.0)
    assert p["drive_v"] == pytest.approx(5.0)  # |3 + 4j| V, the larger drive
    assert p["kx_re_mn_per_m"] == pytest.approx(40.2 / 10e-6 / 1e6)  # 4.02 MN/m
    # fy = -40.2j over y = -10.2j um: 3.94 MN/m in phase
    assert p["ky_re_mn_per_m"] == pytest.approx(40.2 / 10.2e-6 / 1e6, rel=1e-9)
    assert p["ky_im_mn_per_m"] == pytest.approx(0.0, abs=1e-9)


def test_steps_and_time_left_from_the_finished_steps():
    view = LiveView()
    view.set_status(heartbeat(run_id="R1", progress={"steps_total": 5},
                              tolerance={"amplitude_pct": 2.0, "phase_deg": 3.0}), now=100.0)
    for i in range(2):
        view.on_message(Message("step", {"run_id": "R1", "seq": i,
                                         "step": circular_step(i, 20.0 + i, 1e-5, -90)},
                                None, 110.0 + 10 * i))
    fr = view.frame(now=124.0)
    assert [s["index"] for s in fr["steps"]] == [0, 1]
    assert fr["steps"][0]["band_pct"] == 2.0 and fr["steps"][0]["phase_band_deg"] == 3.0
    # before the link says the daemon is there, no time left is promised
    assert fr["time_left_s"] is None and fr["link"]["state"] == "connecting"
    view.set_link({"state": "live", "message": ""})
    fr = view.frame(now=124.0)
    # 2 steps in 20 s: 3 left take 30 s, 4 s of the next one have passed
    assert fr["time_left_s"] == pytest.approx(26.0)
    view.set_link({"state": "lost", "message": "no heartbeat for 1.2 s"})
    assert view.frame(now=125.0)["time_left_s"] is None  # a dead daemon's run counts nothing
    # a new run clears the table
    view.on_message(Message("event", {"run_id": "R2", "seq": 0, "kind": "info",
                                      "message": "x", "time": 1.0}, None, 130.0))
    assert view.frame()["steps"] == []


def test_upward_crossings():
    assert upward_crossings(np.array([-1.0, 0.0, 1.0, -2.0, -1.0, 3.0])).tolist() == [1, 5]


def test_memory_held_for_the_harmonics_stays_bounded_over_a_sweep():
    """Frames over a sweep 20 -> 60 Hz, each window a new n: the lock-in keeps the matrices of a
    few windows (it kept 32: tens of MB at 62.5 kS/s, the web process's slow growth)."""
    view = LiveView(buffer_s=0.5, cycles=3, points=200)
    held = []
    for i, f in enumerate(np.linspace(20.0, 60.0, 41)):
        view.set_status(heartbeat(run_id="R1", progress={"freq_hz": float(f)}))
        for m in blocks(float(f), 12, seed=i):
            view.on_message(m)
        assert view.frame(now=2000.0)["traces"]["triggered"]
        assert view._lockin is not None
        held.append(sum(b.nbytes + g.nbytes for b, g in view._lockin._cache.values()))
    window_20hz = 3 * FS / 20.0 * 11 * 8  # bytes of the basis of 3 cycles at 20 Hz
    assert max(held) <= 4 * window_20hz * 1.01
    assert len(view._lockin._cache) == 4


def test_the_runs_peak_orbit_load_and_contact_live_then_the_daemons_summary():
    """Issue 21: the page shows the run's peak orbit (radius about the probes' zero, as the limit
    sees it) and load while it runs, any journal-housing contact, and the daemon's summary (every
    block counted) once it has ended."""
    view = LiveView(buffer_s=0.5)
    view.set_status(heartbeat(run_id="R1", safety={**heartbeat()["safety"],
                                                   "displacement_limit_m": 63.5e-6}))
    assert view.frame()["peaks"] is None  # nothing measured yet
    for m in blocks(20.0, 8):  # radius: 20 um (+5 um offset on x, +5 % 3X) -> 26 um at most
        view.on_message(m)
    pk = view.frame()["peaks"]
    assert pk["final"] is False and pk["run_id"] == "R1"
    assert pk["peak_displacement_m"] == pytest.approx(26e-6, rel=0.01)
    assert pk["peak_load_n"] == pytest.approx(40.0, rel=1e-3)
    assert pk["contact"] == "" and "no journal-housing contact" in pk["text"]
    assert "peak orbit 26.0 um of the 63.5 um limit, peak load 40.0 N" in pk["text"]
    contact = "journal-housing contact: orbit radius 124.5 um at the 127 um clearance"
    view.on_message(Message("event", {"run_id": "R1", "seq": 1, "kind": "fault",
                                      "message": contact, "time": 1.0}, None, 1010.0))
    assert view.frame()["peaks"]["contact"] == contact
    assert view.frame()["peaks"]["text"].endswith(contact)
    # the run ended: the daemon's summary (it saw every block) replaces what the view saw
    summary = {"peak_displacement_m": 125.0e-6, "displacement_limit_m": 63.5e-6,
               "peak_displacement_at": {"step_index": 0, "steps_total": 1, "freq_hz": 150.0},
               "peak_load_n": 119.8, "max_load_n": 448.0, "peak_load_at": {},
               "contact": contact, "tripped_at": {"message": "displacement 64.7 um ..."}}
    view.set_status(heartbeat(run_id="", last_run={"run_id": "R1", "status": "aborted",
                                                   "summary": summary}))
    pk = view.frame()["peaks"]
    assert pk["final"] and pk["tripped"]
    assert pk["text"] == ("peak orbit 125.0 um of the 63.5 um limit (step 1/1, 150.0 Hz), "
                          f"peak load 119.8 N of 448 N; {contact}")


def test_per_input_rms_peak_and_range_used():
    """fx = 40 cos: RMS 40/sqrt(2) N, peak 40 N; of a +/-100 N range it uses 40 %, of a
    -20..180 N range (middle 80 N) it reaches 120 N below the middle: 120 %, past the end."""
    view = LiveView(buffer_s=0.5, cycles=3, points=200)
    view.set_status(heartbeat(run_id="R1", progress={"freq_hz": 20.0},
                              input_ranges={"fx": [-100.0, 100.0], "fy": [-20.0, 180.0]}))
    for m in blocks(20.0, 40):
        view.on_message(m)
    levels = view.frame(now=2000.0)["traces"]["levels"]
    assert levels["fx"]["rms"] == pytest.approx(40 / math.sqrt(2), rel=1e-3)
    assert levels["fx"]["peak"] == pytest.approx(40.0, rel=1e-3)
    assert levels["fx"]["range_pct"] == pytest.approx(40.0, rel=1e-3)
    assert levels["fy"]["range_pct"] == pytest.approx(120.0, rel=1e-3)
    assert levels["x1"]["range_pct"] is None  # no range given: not guessed
    assert levels["y1"]["rms"] == pytest.approx(20e-6 / math.sqrt(2), rel=1e-3)
