"""End to end: `sfdrig sim-server` as a real process on a free loopback port, driven by
`NidaqmxBackend` through the real nidaqmx client; stops cleanly on SIGTERM."""

from __future__ import annotations

import math
import signal
import subprocess
import sys

import numpy as np
import pytest

from daq.channels import default_channel_map
from daq.nidaqmx_backend import NidaqmxBackend

pytestmark = pytest.mark.e2e


def test_sim_server_process_serves_the_rig_and_stops_on_sigterm() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--fast", "--seed", "4"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        first = proc.stdout.readline().strip()  # blocks until the server is listening
        assert first.startswith("listening on 127.0.0.1:"), (first, proc.stderr.read())
        address = first.removeprefix("listening on ")
        cm = default_channel_map().model_copy(update={"grpc_target": address})
        fs, f_hz, n = cm.sample_rate_hz, 40.0, 2_000
        t = np.arange(4 * n) / fs
        drive = np.vstack([np.zeros_like(t), 1.5 * np.cos(2 * math.pi * f_hz * t)])  # shaker_y
        backend = NidaqmxBackend()
        try:
            backend.configure(cm)
            backend.write_ao(drive[:, :n])
            backend.start()
            blocks = []
            for k in range(1, 4):
                blocks.append(backend.read_ai(n))
                backend.write_ao(drive[:, k * n:(k + 1) * n])
            backend.stop()
        finally:
            backend.close()
        ai = cm.to_engineering(np.hstack(blocks))
        fy = ai[cm.ai_index("fy")][n:]  # whole cycles (50 per second) after the first block
        tt = t[n:3 * n]
        amp = abs(2 * np.mean(fy * np.exp(-2j * math.pi * f_hz * tt)))
        assert amp == pytest.approx(75.0, rel=0.01)  # 1.5 V x 50 N/V through the 1 kHz shaker
        assert np.abs(ai[cm.ai_index("fx")]).max() < 0.5  # x not driven: noise only
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            out, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise
    assert proc.returncode == 0, err
    assert "sim-server stopped" in out


def test_sim_server_refuses_a_missing_rig_file(tmp_path) -> None:
    missing = tmp_path / "no-such-rig.toml"
    proc = subprocess.run(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--rig", str(missing)],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 2
    assert str(missing) in proc.stderr and proc.stdout == ""


@pytest.mark.parametrize("rig", [None, "report"])
def test_sim_server_stops_cleanly_on_sigint(rig: str | None) -> None:
    """Also with a named rig (``--rig report``, as the daemon and the demo take it)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0",
         *(["--rig", rig] if rig else [])],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout.readline().startswith("listening on 127.0.0.1:")
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "sim-server stopped" in out
