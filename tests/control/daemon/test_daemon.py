"""The daemon in process, with a scripted sweep engine: state machine, replies, fan-out, files.

The real engine is exercised end to end in tests/e2e; here a small engine that reads the
simulated rig block by block makes every transition reachable and deterministic (it can hold a
run at a gate until the test releases it, so nothing waits on wall-clock time)."""

from __future__ import annotations

import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from pydantic import BaseModel, ConfigDict

from control.daemon.daemon import TRANSITIONS, Daemon, DaemonConfig, StateMachine, TransitionError
from control.run.pump import PumpRelay
from control.wire.client import CommandClient, CommandRefused, Subscriber
from control.wire.protocol import DaemonState
from daq.channels import default_channel_map
from simulated_hw.backend import SimulatedBackend
from storage.reader import open_run
from storage.records import StepRecord
from tests.e2e.raw_dealer import RawDealer


class ScriptSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    blocks: int
    block_size: int = 500
    hold_after: int | None = None  # wait at this block until aborted
    lubricated: bool = False
    fail_at: int | None = None  # the DAQ fails at this block (a fault)
    slow_abort: bool = False  # an abort takes until the test releases it (state aborting)


class ScriptEngine:
    """A run the test scripts block by block, behind `control.run.engine.Engine`."""

    gates: dict[str, threading.Event] = {}
    abort_done = threading.Event()
    can_pause = True
    steps_total = None
    desk = None
    summary: dict = {}

    def __init__(self, backend, spec, limits=None, listener=None, pump=None):
        self.backend, self.spec, self.listener, self.pump = backend, spec, listener, pump
        self._aborted = threading.Event()
        self._running = threading.Event()
        self._running.set()
        self.reason = ""
        self.held = threading.Event()
        self.aborting = threading.Event()
        ScriptEngine.last = self
        self.progress = {"block": 0, "blocks": spec.blocks}

    def run(self):
        b, n = self.backend, self.spec.block_size
        cm = b.channel_map
        b.write_ao(np.zeros((2, n)))
        b.start()
        try:
            for i in range(self.spec.blocks):
                if self.spec.hold_after == i:
                    self.held.set()
                    self._aborted.wait()
                self._running.wait()
                if self.spec.fail_at == i:
                    raise RuntimeError("the board stopped answering")
                if self._aborted.is_set():
                    if self.spec.slow_abort:
                        self.aborting.set()
                        assert ScriptEngine.abort_done.wait(10)
                    return SimpleNamespace(status="aborted", reason=self.reason)
                ao = np.full((2, n), 0.01 * (i % 7))
                b.write_ao(ao)
                ai = cm.to_engineering(b.read_ai(n))
                self.listener.on_block(i * n, ai, ao)
                self.progress = {"block": i + 1, "blocks": self.spec.blocks}
                if i % 4 == 3:
                    self.listener.on_step(StepRecord.from_wire({"index": i // 4, "freq_hz": 20.0}))
            return SimpleNamespace(status="completed", reason="")
        finally:
            b.stop()

    def pause(self):
        self._running.clear()

    def resume(self):
        self._running.set()

    def abort(self, reason):
        self.reason = reason
        self._aborted.set()
        self._running.set()

    def check(self):
        return None

    def progress_fields(self):
        return dict(self.progress)

    def tolerance(self):
        return None


@pytest.fixture
def daemon(tmp_path: Path):
    backend = SimulatedBackend(seed=3)
    cfg = DaemonConfig(runs_dir=tmp_path / "runs", sndhwm=0, lossless_publish=True,
                       heartbeat_s=0.05)
    d = Daemon(backend, default_channel_map(), cfg, engine_factory=ScriptEngine,
               spec_parser=ScriptSpec.model_validate)  # the real PumpRelay on the sim rig
    t = threading.Thread(target=d.serve, name="test-daemon-serve")
    t.start()
    yield d
    d.stop("test over")
    t.join(30)


def wait_state(client: CommandClient, sub: Subscriber, state: str) -> None:
    """Wait on the PUB stream (no sleeps) until a status heartbeat shows ``state`` and the
    daemon, asked, is in it: a heartbeat queued before the request that left ``state`` shows
    it still (an idle one from before a start, when the test took more than a heartbeat's
    0.25 s to start: on a loaded PC)."""
    while True:
        msg = sub.recv(timeout_s=10)
        assert msg is not None, f"no message while waiting for state {state}"
        if msg.topic == "status" and msg.header["status"]["state"] == state \
                and client.status()["state"] == state:
            return


def test_transition_table_refuses_what_it_does_not_list():
    sm = StateMachine()
    with pytest.raises(TransitionError, match="'pause' is not allowed while idle"):
        sm.fire("pause")
    assert sm.state is DaemonState.IDLE
    assert sm.fire("start") is DaemonState.ARMING
    assert sm.fire("armed") is DaemonState.RUNNING
    assert sm.fire("pause") is DaemonState.PAUSED
    assert sm.fire("abort") is DaemonState.ABORTING
    assert sm.fire("finished") is DaemonState.IDLE
    # every state can be left: no trap states
    for state in DaemonState:
        assert any(s is state for (s, _e) in TRANSITIONS), state


def test_sweep_streams_every_block_and_the_file_matches(daemon: Daemon):
    ep = daemon.endpoints
    with CommandClient(ep["command"]) as c, Subscriber(ep["data"], rcvhwm=0) as sub:
        sub.wait_connected()
        assert c.status()["board"] == {"backend": "sim", "device": "Dev1", "grpc_target": "",
                                       "description": "simulated rig (in process)"}
        reply = c.start_sweep({"blocks": 24, "block_size": 400}, operator="t")
        run_id = reply.data["run_id"]
        blocks, steps = [], []
        while True:
            msg = sub.recv(timeout_s=10)
            assert msg is not None
            if msg.topic == "block":
                assert msg.header["run_id"] == run_id
                blocks.append(msg)
            elif msg.topic == "step":
                steps.append(msg.header["step"])
            elif msg.topic == "event" and msg.header["message"].startswith(f"run {run_id}"):
                break
        assert sub.lost == {}
        assert [m.header["first_sample"] for m in blocks] == [400 * i for i in range(24)]
        assert [s["index"] for s in steps] == list(range(6))
        assert c.status()["state"] == "idle"
        runs = c.list_runs()
    assert runs[0]["run_id"] == run_id and runs[0]["status"] == "completed"
    streamed = np.concatenate([m.array for m in blocks], axis=1)
    with open_run(reply.data["path"]) as run:
        assert run.n_samples == 24 * 400
        # the board that recorded it (daq.board.Board), as status names it
        assert {k: run.attrs[k] for k in ("board", "backend", "device", "grpc_target")} == {
            "board": "simulated rig (in process)", "backend": "sim", "device": "Dev1",
            "grpc_target": ""}
        names = run.channel_names
        for i, name in enumerate(names):
            np.testing.assert_array_equal(run.channel(name), streamed[i])
        np.testing.assert_array_equal(run.h5["drive/shaker_x"][:], streamed[len(names)])


def test_list_runs_answers_from_the_run_index(daemon: Daemon, monkeypatch):
    """``list_runs`` reads a run file's header only when the file is new or changed since the
    last look (the run index): a client asking at every refresh costs the daemon no header
    reads of a year of runs, mid-sweep. What it answers is what the files say."""
    import storage.run_index

    read: list[str] = []
    real = storage.run_index.read_row
    monkeypatch.setattr(storage.run_index, "read_row",
                        lambda path, now=None: read.append(path.name) or real(path, now))
    ep = daemon.endpoints
    with CommandClient(ep["command"]) as c, Subscriber(ep["data"], rcvhwm=0) as sub:
        sub.wait_connected()
        assert c.list_runs() == []
        ids = []
        for spec in ({"blocks": 8, "block_size": 400}, {"blocks": 10, "hold_after": 3}):
            run_id = c.start_sweep(spec).data["run_id"]
            ids.append(run_id)
            if "hold_after" in spec:
                assert ScriptEngine.last.held.wait(10)
                c.abort("the operator stopped it")
            while True:  # the run's end, on the stream
                msg = sub.recv(timeout_s=10)
                assert msg is not None
                if msg.topic == "event" and msg.header["message"].startswith(f"run {run_id}"):
                    break
            wait_state(c, sub, "idle")
        runs = c.list_runs()
        # a file from elsewhere (copied in): read once, at the next look only
        copied = daemon.cfg.runs_dir / "copied.h5"
        copied.write_bytes(Path(runs[1]["path"]).read_bytes())
        again = c.list_runs()
        assert [r["run_id"] for r in again] == [ids[1], ids[0], ids[0]]
        assert {r["path"] for r in again[1:]} == {runs[1]["path"], str(copied)}
        assert c.list_runs() == again
    # the writer recorded both runs in the index as they ended: no header read for them; the
    # copied file is read at each look until its change is 2 s old (`RACY_NS`: coarse clocks)
    assert read and set(read) == {"copied.h5"}
    assert [r["run_id"] for r in runs] == ids[::-1]  # newest first
    for listed in runs:
        with open_run(listed["path"]) as run:
            assert listed == {"path": str(run.path), "run_id": run.run_id, "kind": run.kind,
                              "status": run.status,
                              "status_reason": str(run.attrs.get("status_reason", "")),
                              "start_time": run.start_time, "stop_time": run.stop_time,
                              "n_samples": run.n_samples, "n_steps": len(run.steps)}
    assert (runs[1]["status"], runs[1]["n_samples"], runs[1]["n_steps"]) == ("completed", 3200, 2)
    assert runs[0]["status"] == "aborted" and "the operator stopped it" in runs[0]["status_reason"]


def test_forbidden_requests_leave_the_state_unchanged(daemon: Daemon):
    ep = daemon.endpoints
    with CommandClient(ep["command"]) as c, Subscriber(ep["data"], rcvhwm=0) as sub:
        sub.wait_connected()
        for cmd in ("pause", "resume", "abort"):
            with pytest.raises(CommandRefused, match=f"'{cmd}' is not allowed while idle"):
                c.request(cmd)
        assert c.reset().data == {"nothing_to_reset": True}  # a no-op, not a refusal
        with pytest.raises(CommandRefused, match=r"start\.spec\.blocks: Field required$"):
            c.start_sweep({"block_size": 10})
        assert c.status()["state"] == "idle"
        c.start_sweep({"blocks": 10, "hold_after": 3})
        assert ScriptEngine.last.held.wait(10)
        with pytest.raises(CommandRefused, match="'start' is not allowed while running"):
            c.start_sweep({"blocks": 1})
        assert c.pause().state is DaemonState.PAUSED
        with pytest.raises(CommandRefused, match="'pause' is not allowed while paused"):
            c.pause()
        assert c.resume().state is DaemonState.RUNNING
        assert c.abort("test abort").state is DaemonState.ABORTING
        wait_state(c, sub, "idle")
        last = c.status()["last_run"]
        assert (last["status"], last["reason"]) == ("aborted", "test abort")
        with open_run(last["path"]) as run:
            assert run.status == "aborted"
            assert run.attrs["status_reason"] == "test abort"
            assert run.n_samples == 3 * 500


def test_malformed_frames_get_error_replies(daemon: Daemon):
    with CommandClient(daemon.endpoints["command"]) as c:
        cases = {
            b"not json": "malformed",
            b"[1, 2]": "malformed",
            b'{"cmd": "fly"}': "invalid",
            b'{"cmd": "pump"}': "invalid",
            b'{"cmd": "pump", "on": "maybe"}': "invalid",
            b'{"cmd": "status", "extra": 1}': "invalid",
        }
        for frame, kind in cases.items():
            import json
            reply = json.loads(c.send_raw([b"", frame]))
            assert reply["ok"] is False and reply["error_kind"] == kind, (frame, reply)
            assert reply["error"]
        reply = json.loads(c.send_raw([b"", b"{}", b"{}"]))
        assert reply["error"] == "expected one JSON request frame, got 2 frames"
        assert c.status()["state"] == "idle"


def test_a_start_with_a_typo_says_what_it_probably_means(daemon: Daemon):
    """Issue 39: `--set recrod_cycles=40` was "Extra inputs are not permitted", nothing more;
    the daemon's refusal (what the CLI and the page show) names the field it probably means."""
    with CommandClient(daemon.endpoints["command"]) as c, \
            pytest.raises(CommandRefused) as refused:
        c.start_sweep({"blocks": 4, "blok_size": 400})
    assert refused.value.reply.error == ("start.spec.blok_size: Extra inputs are not permitted "
                                         "(got 400); did you mean 'block_size'?")


@pytest.mark.parametrize("rid", ["\x00nul", "\n\r\t", "a\tb\r\nc\x00"])
def test_a_request_id_comes_back_exactly_as_sent(daemon: Daemon, rid: str):
    """Issue 39: "\u0000nul" came back as "\ufffdnul" and "\n\r\t" as "" (from an abort;
    other requests refused a NUL): a client could not match its reply. A raw DEALER, so that
    no client library smooths the frame."""
    import json

    with RawDealer(daemon.endpoints["command"]) as raw:
        for request in ({"cmd": "status"}, {"cmd": "abort"}, {"cmd": "pause"},
                        {"cmd": "pump", "on": "maybe"}, {"cmd": "fly"}):
            reply = raw.request(json.dumps({**request, "request_id": rid}))
            assert reply["request_id"] == rid, (request, reply)
        assert raw.request(json.dumps({"cmd": "status", "request_id": rid}))["ok"] is True


def test_the_pump_stays_as_the_run_started_it_while_running_and_paused(daemon: Daemon):
    """Issue 21: pump on was accepted during a dry sweep (and while it was paused), so a run
    recorded dry had oil-wet dwells; pump off during a lubricated run must be refused too."""
    ep = daemon.endpoints
    with CommandClient(ep["command"]) as c, Subscriber(ep["data"], rcvhwm=0) as sub:
        sub.wait_connected()
        assert c.pump(False).data["pump_on"] is False
        run_id = c.start_sweep({"blocks": 10, "hold_after": 3}).data["run_id"]
        assert ScriptEngine.last.held.wait(10)
        for state in ("running", "paused"):
            with pytest.raises(CommandRefused) as refused:
                c.pump(True)
            assert f"cannot be switched on during the dry sweep {run_id}" in str(refused.value)
            assert "recorded as dry" in str(refused.value)
            assert c.status()["pump_on"] is False and c.status()["state"] == state
            assert not daemon.backend.rig.pump_on
            if state == "running":
                assert c.pause().state is DaemonState.PAUSED
        assert c.pump(False).data["pump_on"] is False  # no change: allowed
        c.abort("test over")
        wait_state(c, sub, "idle")
        assert c.pump(True).data["pump_on"] is True  # the run is over

        run_id = c.start_sweep({"blocks": 10, "hold_after": 3, "lubricated": True}
                               ).data["run_id"]
        assert ScriptEngine.last.held.wait(10)
        for state in ("running", "paused"):
            with pytest.raises(CommandRefused) as refused:
                c.pump(False)
            message = str(refused.value)
            assert "cannot be switched off while the shakers run" in message
            assert f"the lubricated sweep {run_id}" in message and "drained" in message
            assert c.status()["pump_on"] is True and daemon.backend.rig.pump_on
            if state == "running":
                assert c.pause().state is DaemonState.PAUSED
        c.abort("test over")
        wait_state(c, sub, "idle")
        assert c.pump(False).data["pump_on"] is False


def test_a_dry_sweep_waits_for_the_film_to_drain_after_the_pump_goes_off(tmp_path: Path):
    """Issue 21: a dry sweep started as the pump went off ran on a film still full of oil (the
    Y displacement step of the lab-day session then failed to converge while the film drained)
    and was recorded dry. It is refused, saying how long is left, until ``film_drain_s``."""
    now = [100.0]
    cfg = DaemonConfig(runs_dir=tmp_path / "runs", sndhwm=0, lossless_publish=True,
                       heartbeat_s=0.05, film_drain_s=30.0)
    d = Daemon(SimulatedBackend(seed=3), default_channel_map(), cfg,
               engine_factory=ScriptEngine, spec_parser=ScriptSpec.model_validate,
               pump_factory=lambda be, drain_s: PumpRelay(be, drain_s=drain_s,
                                                          clock=lambda: now[0]))
    t = threading.Thread(target=d.serve, name="test-daemon-serve")
    t.start()
    try:
        with CommandClient(d.endpoints["command"]) as c, \
                Subscriber(d.endpoints["data"], rcvhwm=0) as sub:
            sub.wait_connected()
            assert c.status()["film_drains_for_s"] == 0.0  # never on: nothing to drain
            c.pump(True)
            assert c.status()["film_drains_for_s"] == 0.0  # on: full, not draining
            c.pump(False)
            now[0] += 12.5
            assert c.status()["film_drains_for_s"] == 17.5
            with pytest.raises(CommandRefused) as refused:
                c.start_sweep({"blocks": 4})
            assert refused.value.reply.error == (
                "start: the film is still draining after the pump went off: a dry sweep can "
                "start in 18 s (its dwells are recorded as dry; the daemon waits 30 s, "
                "--film-drain-s)")
            assert refused.value.reply.error_kind == "forbidden"
            assert c.status()["state"] == "idle" and not list((tmp_path / "runs").glob("*.h5"))
            # a lubricated sweep needs the pump, not a dry film: it is not held back
            c.pump(True)
            c.start_sweep({"blocks": 4, "lubricated": True})
            wait_state(c, sub, "idle")
            c.pump(False)
            now[0] += 29.75
            with pytest.raises(CommandRefused, match="can start in 1 s"):
                c.start_sweep({"blocks": 4})
            assert c.status()["film_drains_for_s"] == 0.3  # 0.25 s, rounded up
            now[0] += 0.21875
            # 31 ms left: never "0" while a dry start is still refused (the lab-day bench waited
            # for a rounded 0.0 and was refused)
            assert c.status()["film_drains_for_s"] == 0.1
            now[0] += 0.03125
            assert c.status()["film_drains_for_s"] == 0.0
            assert c.start_sweep({"blocks": 4}).ok
            wait_state(c, sub, "idle")
    finally:
        d.stop("test over")
        t.join(30)


def test_refusals_name_the_requests_allowed_now_and_how_to_reset_a_fault(daemon: Daemon):
    """Issue 21: refusals listed the machine's events ("allowed: fault, finished"), never the
    requests, and never said how a fault is reset; reset must lead to a sweep that runs."""
    ep = daemon.endpoints
    with CommandClient(ep["command"]) as c, Subscriber(ep["data"], rcvhwm=0) as sub:
        sub.wait_connected()
        with pytest.raises(CommandRefused) as refused:
            c.pause()
        assert refused.value.reply.error == ("pause: 'pause' is not allowed while idle (allowed "
                                             "now: start, start_test, pump, status, list_runs)")
        c.start_sweep({"blocks": 10, "hold_after": 3})
        assert ScriptEngine.last.held.wait(10)
        with pytest.raises(CommandRefused) as refused:
            c.start_sweep({"blocks": 1})
        assert refused.value.reply.error == ("start: 'start' is not allowed while running "
                                             "(allowed now: pause, abort, pump, status, "
                                             "list_runs)")
        c.abort("next")
        wait_state(c, sub, "idle")

        run_id = c.start_sweep({"blocks": 10, "fail_at": 2}).data["run_id"]
        wait_state(c, sub, "fault")
        status = c.status()
        assert status["fault_reason"] == "RuntimeError: the board stopped answering"
        assert status["last_run"]["run_id"] == run_id
        for start in (lambda: c.start_sweep({"blocks": 4}),
                      lambda: c.request("start_test", test="impact")):
            with pytest.raises(CommandRefused) as refused:
                start()
            cmd = refused.value.reply.cmd
            assert refused.value.reply.error == (
                f"{cmd}: '{cmd}' is not allowed while fault (allowed now: reset, pump, status, "
                "list_runs); reset the fault with `sfdrig status --reset` (or Reset fault on "
                "the web page) once its cause is cleared (the fault: RuntimeError: the board "
                "stopped answering)")
        assert c.reset().state is DaemonState.IDLE
        assert c.status()["fault_reason"] == ""
        reply = c.start_sweep({"blocks": 8, "block_size": 400})
        while (msg := sub.recv(timeout_s=10)) is not None:  # not a heartbeat from before it
            if msg.topic == "event" and msg.header["message"].startswith(
                    f"run {reply.data['run_id']} "):
                break
        assert msg is not None, "the run after the reset did not end"
        last = c.status()["last_run"]
        assert (last["run_id"], last["status"]) == (reply.data["run_id"], "completed")
    with open_run(last["path"]) as run:
        assert run.status == "completed" and run.n_samples == 8 * 400


def test_an_abort_while_aborting_is_not_refused(daemon: Daemon):
    """Pressed twice: the second abort is answered ok (it is under way), not "not allowed"."""
    ScriptEngine.abort_done.clear()
    ep = daemon.endpoints
    with CommandClient(ep["command"]) as c, Subscriber(ep["data"], rcvhwm=0) as sub:
        sub.wait_connected()
        run_id = c.start_sweep({"blocks": 10, "hold_after": 3, "slow_abort": True}
                               ).data["run_id"]
        assert ScriptEngine.last.held.wait(10)
        assert c.abort("first").state is DaemonState.ABORTING
        assert ScriptEngine.last.aborting.wait(10)
        again = c.abort("second")
        assert (again.ok, again.state, again.data) == (True, DaemonState.ABORTING,
                                                       {"already_aborting": True})
        ScriptEngine.abort_done.set()
        while (msg := sub.recv(timeout_s=10)) is not None:
            if msg.topic == "event" and msg.header["message"].startswith(f"run {run_id} "):
                break
        assert msg is not None and msg.header["message"] == f"run {run_id} aborted: first"
