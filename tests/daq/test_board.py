"""The board named one way everywhere (`daq.board.Board`, each backend's ``board``), the
gRPC target checked in one place, and the board's lock: a second holder is refused with the
first one's pid and command line; the simulated rig in process has no lock."""

from __future__ import annotations

import os

import pytest

from daq.board import NIDAQMX, SIM, Board, board_lock, grpc_target_problem
from daq.channels import ChannelMap, channel_map_from_dict, default_channel_map
from daq.errors import ChannelConfigError, DaqError
from daq.locks import AlreadyRunning, command_line
from daq.nidaqmx_backend import NidaqmxBackend
from simulated_hw.backend import SimulatedBackend
from tests.daq.conftest import on_server


@pytest.mark.parametrize("target", ["127.0.0.1:31763", "localhost:1", "rig-pc.lab.example:65535",
                                    "[::1]:50051", "10.0.0.7:80"])
def test_a_host_and_a_port_are_a_target(target):
    assert grpc_target_problem(target) == ""


@pytest.mark.parametrize("target,problem", [
    ("localhost", "no port"),
    ("", "no port"),
    (":80", "no host before the port"),
    ("host:notaport", "the port 'notaport' is not a TCP port 1-65535"),
    ("host:70000", "the port '70000' is not a TCP port 1-65535"),
    ("host:0", "the port '0' is not a TCP port 1-65535"),
    ("host:", "the port '' is not a TCP port 1-65535"),
    ("a b:80", "'a b' is not a host name or address"),
    ("http://host:80", "'http://host' is not a host name or address"),
    ("-host:80", "'-host' is not a host name or address"),
])
def test_what_is_not_host_port_is_named(target, problem):
    assert grpc_target_problem(target) == f"not HOST:PORT: {problem} (e.g. 127.0.0.1:31763)"


def test_a_map_with_a_bad_grpc_target_is_refused_naming_the_field():
    data = default_channel_map().to_json_dict()
    data["grpc_target"] = "localhost"
    with pytest.raises(ChannelConfigError) as err:
        channel_map_from_dict(data, "rig.toml")
    assert err.value.lines() == [
        "rig.toml: grpc_target = 'localhost': not HOST:PORT: no port (e.g. 127.0.0.1:31763); "
        "leave grpc_target out for the local driver"]


def test_each_board_is_described_once():
    assert Board(SIM, "Dev1").describe() == "simulated rig (in process)"
    assert Board(NIDAQMX, "Dev1").describe() == "nidaqmx device Dev1 (local driver)"
    remote = Board(NIDAQMX, "Dev2", "127.0.0.1:5000")
    assert remote.describe() == "nidaqmx device Dev2 via gRPC 127.0.0.1:5000"
    assert remote.as_dict() == {"backend": "nidaqmx", "device": "Dev2",
                                "grpc_target": "127.0.0.1:5000",
                                "description": "nidaqmx device Dev2 via gRPC 127.0.0.1:5000"}
    assert Board(NIDAQMX, "Dev1").as_dict()["grpc_target"] == ""


def test_the_backends_name_their_boards(fast_server):
    sim = SimulatedBackend(seed=1)
    sim.configure(default_channel_map())
    assert sim.board == Board(SIM, "Dev1")
    backend = NidaqmxBackend(watchdog_timeout_s=None)
    with pytest.raises(DaqError, match="not configured"):
        _ = backend.board
    cm: ChannelMap = on_server(fast_server)
    backend.configure(cm)
    try:
        # the sim-server's device says it is simulated (DevIsSimulated), as an NI simulated
        # device does: the daemon, its run files and the page name a rehearsal as one
        assert backend.board.describe() == (f"simulated nidaqmx device Dev1 via gRPC "
                                            f"{fast_server.address}")
        assert backend.board.simulated
    finally:
        backend.close()
    # --grpc-target overrides the map's
    assert NidaqmxBackend(grpc_target="rig:7").grpc_target == "rig:7"


def test_one_board_one_lock_however_its_server_is_named(tmp_path):
    port = "31763"
    names = {board_lock(Board(NIDAQMX, "Dev1", f"{host}:{port}"), tmp_path).path.name  # type: ignore[union-attr]
             for host in ("127.0.0.1", "localhost", "LOCALHOST")}
    assert names == {"device-grpc-localhost-31763-Dev1.lock"}
    others = {board_lock(b, tmp_path).path.name for b in (  # type: ignore[union-attr]
        Board(NIDAQMX, "Dev1"), Board(NIDAQMX, "Dev2", f"127.0.0.1:{port}"),
        Board(NIDAQMX, "Dev1", "127.0.0.1:31764"), Board(NIDAQMX, "Dev1", f"rig-pc:{port}"))}
    assert len(others) == 4 and not others & names
    # each process has its own simulated rig: nothing to share, nothing to lock
    assert board_lock(Board(SIM, "Dev1"), tmp_path) is None


def test_a_second_holder_is_refused_with_the_first_ones_pid_and_command(tmp_path):
    board = Board(NIDAQMX, "Dev1", "127.0.0.1:31763")
    first = board_lock(board, tmp_path)
    second = board_lock(Board(NIDAQMX, "Dev1", "localhost:31763"), tmp_path)
    assert first is not None and second is not None
    first.acquire(runs_dir="runs")
    try:
        with pytest.raises(AlreadyRunning) as err:
            second.acquire()
        assert str(err.value) == (f"nidaqmx device Dev1 via gRPC localhost:31763 is in use by "
                                  f"pid {os.getpid()} ({command_line()}), runs dir runs")
        assert err.value.holder["pid"] == os.getpid()
    finally:
        first.release()
    second.acquire()  # free once the first let go (or died: the kernel drops a flock)
    second.release()


def test_a_run_file_names_the_board_that_recorded_it(tmp_path):
    from control.run.files import create_run_writer
    from storage.reader import open_run

    board = Board(NIDAQMX, "Dev1", "127.0.0.1:31763")
    writer = create_run_writer(tmp_path / "r.h5", "static", default_channel_map(), run_id="r",
                               board=board)
    writer.close("completed", "")
    with open_run(tmp_path / "r.h5") as run:
        assert {k: run.attrs[k] for k in ("board", "backend", "device", "grpc_target")} == {
            "board": "nidaqmx device Dev1 via gRPC 127.0.0.1:31763", "backend": "nidaqmx",
            "device": "Dev1", "grpc_target": "127.0.0.1:31763"}
    # without a board (imported data): the attributes are there, empty
    create_run_writer(tmp_path / "i.h5", "static", default_channel_map(), run_id="i").close(
        "completed", "")
    with open_run(tmp_path / "i.h5") as run:
        assert run.attrs["board"] == run.attrs["backend"] == ""
