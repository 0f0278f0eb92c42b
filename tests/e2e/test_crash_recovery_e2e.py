"""Issue 12, items 6 and 9: a daemon killed with SIGKILL mid-run; the next daemon on the same
runs directory closes the run as "interrupted" with its last flushed sample, and plain
``h5py.File(path, "r")`` (no SWMR) opens it with every flushed block intact."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from control.wire.client import CommandClient, Subscriber
from tests.e2e.conftest import start_daemon
from tests.e2e.test_stream_e2e import LONG_X, stacked, until_a_step_is_durable

pytestmark = pytest.mark.e2e


@pytest.mark.paced
def test_a_killed_run_is_closed_interrupted_and_opens_in_plain_h5py(tmp_path):
    runs = tmp_path / "runs"
    d = start_daemon(runs, fast=False)  # paced: the run is still going when it is killed
    try:
        with CommandClient(d.command, timeout_s=10) as c, Subscriber(d.data, rcvhwm=0) as sub:
            sub.wait_connected()
            run_id = c.start_sweep(LONG_X).data["run_id"]
            blocks, step, flushed = until_a_step_is_durable(sub, run_id)
            d.proc.kill()
            d.proc.wait(10)
            while (msg := sub.recv(timeout_s=0.5)) is not None:
                if msg.topic == "block" and msg.header["run_id"] == run_id:
                    blocks.append(msg)
    finally:
        d.terminate()
        d.proc.communicate(timeout=10)
    path = runs / f"{run_id}.h5"
    with pytest.raises(OSError, match="already open for write"):
        h5py.File(path, "r")  # what the killed writer left

    d2 = start_daemon(runs, fast=True)
    try:
        with CommandClient(d2.command, timeout_s=10) as c:
            status = c.status()
            listed = {r["run_id"]: r for r in c.list_runs()}
    finally:
        assert d2.terminate() == 0
        d2.proc.communicate(timeout=10)
    [recovered] = status["recovered_at_start"]
    assert recovered["path"] == str(path) and recovered["status"] == "interrupted"
    assert listed[run_id]["status"] == "interrupted"
    streamed = stacked(blocks)
    with h5py.File(path, "r") as f:  # plain: no SWMR, no h5clear
        assert f.attrs["status"] == "interrupted"
        assert "killed or crashed" in f.attrs["status_reason"]
        n = int(f.attrs["last_sample"])
        assert n == recovered["last_sample"]
        assert step["last_sample"] <= flushed <= n <= streamed.shape[1]
        names = list(f["channels"]) + list(f["drive"])
        order = blocks[0].header["channels"]
        for name in names:
            data = f["channels"][name] if name in f["channels"] else f["drive"][name]
            np.testing.assert_array_equal(data[:], streamed[order.index(name), :n],
                                          err_msg=name)
        assert len(f["steps"]) >= 1
