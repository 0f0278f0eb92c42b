"""A day in the lab on one daemon (issue 21, deliverable 1): sweep after sweep on one paced
daemon process, each completing in the same wall time with the same result, and the daemon's
memory, file descriptors and threads flat.

Paced to the wall clock on purpose: the promise is that the fifteenth sweep of a day behaves as
the first, also on a machine busy with other work (this suite runs in parallel processes).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from control.client import CommandClient, Subscriber
from storage.reader import open_run

pytestmark = pytest.mark.e2e

SWEEPS = 15
RECORD_S = 4.0  # 15 x 4 s = 60 s of recording in all
FREQ_HZ = 80.0
# The one-step sweep, recorded for RECORD_S: 40 N circular above the dry resonance.
ONE_STEP = {"motion": "circular_forward", "load_n": [40.0], "freq_hz": [FREQ_HZ],
            "record_cycles": int(RECORD_S * FREQ_HZ)}
# What one run's recording would leave behind if it were kept: 14 channels x 10 kS/s x 4 s,
# float64 (4.5 MB). Thirteen runs after the first may not add one run's worth.
ONE_RUN_BYTES = 14 * 10_000 * RECORD_S * 8


def _proc(pid: int) -> tuple[int, int, int]:
    """(resident bytes, open file descriptors, threads) of a live process, from /proc."""
    rss = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) * 1024
    fds = len(list(Path(f"/proc/{pid}/fd").iterdir()))
    threads = len(list(Path(f"/proc/{pid}/task").iterdir()))
    return rss, fds, threads


def _run_end(sub: Subscriber, run_id: str, timeout_s: float) -> str:
    while True:
        msg = sub.recv(timeout_s=timeout_s)
        assert msg is not None, f"run {run_id}: the stream went silent for {timeout_s} s"
        if msg.topic == "event" and msg.header["message"].startswith(f"run {run_id} "):
            return str(msg.header["message"])


def test_fifteen_sweeps_back_to_back_on_one_paced_daemon(daemon_factory):
    d = daemon_factory(fast=False)
    walls: list[float] = []
    achieved: list[float] = []
    files: list[Path] = []
    after_first: tuple[int, int, int] | None = None
    with CommandClient(d.command, timeout_s=10) as c, Subscriber(d.data, topics=["event"]) as sub:
        sub.wait_connected()
        for i in range(SWEEPS):
            t0 = time.monotonic()
            run_id = c.start_sweep(ONE_STEP, operator="lab day").data["run_id"]
            end = _run_end(sub, run_id, timeout_s=60)
            walls.append(time.monotonic() - t0)
            assert end == f"run {run_id} completed", f"sweep {i + 1}: {end}"
            files.append(d.runs_dir / f"{run_id}.h5")
            if i == 0:
                after_first = _proc(d.proc.pid)
        last = _proc(d.proc.pid)
        assert c.status()["state"] == "idle"
    assert after_first is not None
    for i, path in enumerate(files):
        with open_run(path) as run:
            assert run.status == "completed"
            step = run.steps[0]
            n = int(step["last_sample"]) - int(step["first_sample"])
            assert n >= RECORD_S * run.sample_rate_hz * 0.99, f"sweep {i + 1}: {n} samples"
            achieved.append(abs(complex(*step["harmonics"]["x1"][0])))
    # the same sweep, the same wall time: no run waits for anything of an earlier one
    assert max(walls) <= 1.2 * min(walls), f"wall times {np.round(walls, 2)} s"
    # ... and the same result
    assert np.ptp(achieved) <= 0.02 * np.mean(achieved), \
        f"x amplitude {np.round(np.array(achieved) * 1e6, 3)} um"
    rss0, fds0, thr0 = after_first
    rss1, fds1, thr1 = last
    assert fds1 == fds0, f"file descriptors {fds0} -> {fds1}"
    assert thr1 == thr0, f"threads {thr0} -> {thr1}"
    assert rss1 - rss0 < ONE_RUN_BYTES, f"resident memory {rss0 / 1e6:.1f} -> {rss1 / 1e6:.1f} MB"
