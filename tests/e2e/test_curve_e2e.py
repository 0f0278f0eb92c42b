"""CURVE on: an unauthorised client's commands are refused, an authorised one's accepted, and a
read-only key may subscribe to live data but not command."""

from __future__ import annotations

import subprocess
import sys

import pytest

from control.wire.client import CommandClient, DaemonUnavailable, Subscriber
from control.wire.security import load_client_keys, make_keys

pytestmark = pytest.mark.e2e


def test_curve_refuses_unknown_keys_and_accepts_known_ones(daemon_factory, tmp_path):
    keys = tmp_path / "keys"
    make_keys(keys, commanders=["operator"], readers=["viewer"])
    # a stranger: a well-formed key pair the daemon has never seen
    stranger_dir = tmp_path / "stranger"
    make_keys(stranger_dir, commanders=["mallory"], readers=[])
    stranger = load_client_keys(stranger_dir, "mallory")
    server_public = load_client_keys(keys, "operator").server_public
    stranger = type(stranger)(stranger.public, stranger.secret, server_public)

    d = daemon_factory("--keys", str(keys))
    refused = pytest.raises(DaemonUnavailable, match="refused this client's CURVE key")
    with CommandClient(d.command, timeout_s=20, keys=stranger) as c, refused:
        c.status()
    with CommandClient(d.command, timeout_s=3) as c, pytest.raises(DaemonUnavailable):
        c.status()  # no CURVE at all
    viewer = load_client_keys(keys, "viewer")
    refused = pytest.raises(DaemonUnavailable, match="refused this client's CURVE key")
    with CommandClient(d.command, timeout_s=20, keys=viewer) as c, refused:
        c.pump(True)
    with CommandClient(d.command, timeout_s=10, keys=load_client_keys(keys, "operator")) as c:
        assert c.status()["state"] == "idle"
        assert c.pump(True).data["pump_on"] is True
        replied = c.status()
        assert replied["pump_on"] is True
    # read-only status for viewers: the heartbeat carries what the status reply does
    with Subscriber(d.data, keys=load_client_keys(keys, "viewer")) as sub:
        beat = sub.wait_connected(timeout_s=10)
        assert beat["pump_on"] is True and beat["state"] == "idle"
        assert set(beat) == set(replied)
    assert d.terminate() == 0


def test_binding_beyond_loopback_without_keys_is_refused(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "sfdrig", "daemon", "--fast", "--runs-dir", str(tmp_path),
         "--command-endpoint", "tcp://0.0.0.0:0"],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 2
    assert "CURVE keys are required" in out.stderr
