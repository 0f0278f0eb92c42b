"""CURVE key directories and the loopback rule of the daemon's endpoints."""

from __future__ import annotations

import pytest

from control.wire.security import (
    KeyFileError,
    is_loopback,
    load_client_keys,
    load_server_keys,
    make_keys,
)


@pytest.mark.parametrize(("endpoint", "local"), [
    ("tcp://127.0.0.1:0", True), ("tcp://127.0.0.1:*", True), ("tcp://127.4.5.6:5555", True),
    ("tcp://localhost:5555", True), ("tcp://[::1]:5555", True), ("ipc:///tmp/sfdrig", True),
    ("inproc://x", True), ("tcp://0.0.0.0:5555", False), ("tcp://*:5555", False),
    ("tcp://10.0.0.5:5555", False), ("tcp://eth0:5555", False), ("udp://127.0.0.1:1", False),
])
def test_loopback_rule(endpoint, local):
    assert is_loopback(endpoint) is local


def test_key_directory_layout_and_reload(tmp_path):
    d = tmp_path / "keys"
    written = make_keys(d, ["operator"], ["viewer"])
    assert {p.relative_to(d).as_posix() for p in written} == {
        "server.key_secret", "server.key", "clients/operator.key_secret",
        "commanders/operator.key", "clients/viewer.key_secret", "readers/viewer.key"}
    assert (d / "server.key_secret").stat().st_mode & 0o777 == 0o600
    server = load_server_keys(d)
    op = load_client_keys(d, "operator")
    assert op.server_public == server.public and len(op.public) == 40
    # adding a client keeps the server key
    make_keys(d, ["carol"], [])
    assert load_server_keys(d).public == server.public
    with pytest.raises(KeyFileError, match="carol.key_secret exists"):
        make_keys(d, ["carol"], [])
    with pytest.raises(KeyFileError, match="client name '../x'"):
        make_keys(d, ["../x"], [])
    with pytest.raises(KeyFileError, match="both commander and reader"):
        make_keys(d, ["z"], ["z"])
    with pytest.raises(KeyFileError, match="nobody.key_secret not found"):
        load_client_keys(d, "nobody")
