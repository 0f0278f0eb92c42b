"""The sfdrig daemon: a state machine, one acquisition loop, a command socket and a publisher.

Threads
    - the command thread (the caller of `Daemon.serve`) owns the ROUTER command socket: it parses
      requests (`control.wire`), checks them against the state machine, answers every one, and
      sends a status heartbeat on the PUB stream every ``heartbeat_s``;
    - the acquisition thread (`AcquisitionLoop`) runs one sweep at a time (`SweepEngine.run`,
      which owns the DAQ loop and ends with the drives ramped to zero whatever happens); every
      block goes to a fan-out listener: the run file (`storage.RunWriter`) and the publisher;
    - the publisher thread (`control.publisher.Publisher`) owns the PUB socket.

State machine (`TRANSITIONS`): a request that the table does not allow in the current state is
refused with an error reply and changes nothing. Shutdown (SIGTERM, SIGINT, `Daemon.stop`) aborts
a running sweep the safe way (drives ramped to zero, run file closed valid with status "aborted"
and the reason), then closes the sockets.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import queue
import secrets
import threading
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import zmq
from pydantic import ValidationError

from control.errors import InterlockError, TargetError
from control.publisher import Publisher
from control.security import (
    COMMAND_DOMAIN,
    DATA_DOMAIN,
    ServerKeys,
    is_loopback,
    secure_server_socket,
    start_authenticator,
)
from control.wire import (
    AbortRequest,
    DaemonState,
    ErrorKind,
    ListRunsRequest,
    PauseRequest,
    PumpRequest,
    Reply,
    RequestError,
    ResetRequest,
    ResumeRequest,
    StartRequest,
    StatusRequest,
    describe_errors,
    parse_request,
)
from daq.backend import DaqBackend
from daq.channels import ChannelMap

log = logging.getLogger("sfdrig.daemon")
S = DaemonState

#: (state, event) -> next state. Anything absent is refused.
TRANSITIONS: dict[tuple[DaemonState, str], DaemonState] = {
    (S.IDLE, "start"): S.ARMING,
    (S.ARMING, "armed"): S.RUNNING,
    (S.ARMING, "abort"): S.ABORTING,
    (S.RUNNING, "pause"): S.PAUSED,
    (S.RUNNING, "abort"): S.ABORTING,
    (S.PAUSED, "resume"): S.RUNNING,
    (S.PAUSED, "abort"): S.ABORTING,
    (S.ARMING, "finished"): S.IDLE,
    (S.RUNNING, "finished"): S.IDLE,
    (S.PAUSED, "finished"): S.IDLE,
    (S.ABORTING, "finished"): S.IDLE,
    (S.ARMING, "fault"): S.FAULT,
    (S.RUNNING, "fault"): S.FAULT,
    (S.PAUSED, "fault"): S.FAULT,
    (S.ABORTING, "fault"): S.FAULT,
    (S.FAULT, "reset"): S.IDLE,
}


class TransitionError(RuntimeError):
    """An event the transition table does not allow in the current state."""


class StateMachine:
    """The daemon's state, changed only through `TRANSITIONS`; thread-safe.

    ``on_change(old, new, event)`` is called (under the lock) after every transition.
    """

    def __init__(self, on_change: Callable[[DaemonState, DaemonState, str], None] | None = None):
        self.lock = threading.RLock()
        self._state = S.IDLE
        self._on_change = on_change

    @property
    def state(self) -> DaemonState:
        return self._state

    def allowed(self, event: str) -> bool:
        return (self._state, event) in TRANSITIONS

    def fire(self, event: str) -> DaemonState:
        with self.lock:
            new = TRANSITIONS.get((self._state, event))
            if new is None:
                allowed = sorted(e for (s, e) in TRANSITIONS if s is self._state)
                raise TransitionError(
                    f"'{event}' is not allowed while {self._state.value} "
                    f"(allowed: {', '.join(allowed) or 'none'})"
                )
            old, self._state = self._state, new
            if self._on_change is not None:
                self._on_change(old, new, event)
            return new


# --- the sweep stream's consumers ---------------------------------------------------------------
class SweepListener(Protocol):
    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None: ...
    def on_step(self, step: dict[str, Any]) -> None: ...
    def on_event(self, kind: str, message: str, sample: int) -> None: ...


class FanOut:
    """One stream, many consumers: the run file must get every call (its errors stop the run);
    the live consumers are best effort (their errors are counted, never raised)."""

    def __init__(self, required: Sequence[SweepListener], best_effort: Sequence[SweepListener]):
        self.required = list(required)
        self.best_effort = list(best_effort)
        self.errors = 0
        self.last_sample = 0  # one past the last sample seen

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        self.last_sample = first_sample + ai.shape[1]
        for r in self.required:
            r.on_block(first_sample, ai, ao)
        for b in self.best_effort:
            self._try(b.on_block, first_sample, ai, ao)

    def on_step(self, step: dict[str, Any]) -> None:
        for r in self.required:
            r.on_step(step)
        for b in self.best_effort:
            self._try(b.on_step, step)

    def on_event(self, kind: str, message: str, sample: int) -> None:
        for r in self.required:
            r.on_event(kind, message, sample)
        for b in self.best_effort:
            self._try(b.on_event, kind, message, sample)

    def _try(self, fn: Callable[..., None], *args: Any) -> None:
        try:
            fn(*args)
        except Exception:  # a live consumer must never stop acquisition
            self.errors += 1
            log.exception("live consumer failed")


class BackgroundWriter:
    """Runs a run writer's calls on its own thread, in order, so that disk latency (compression,
    flushes at steps and events) stays out of the acquisition loop, whose AO lead is only tens of
    milliseconds.

    A write error, or a backlog beyond ``max_backlog_samples``, makes the next `on_block` raise:
    the engine then stops the run the safe way and records why.
    """

    def __init__(self, writer: Any, max_backlog_samples: int) -> None:
        self.writer = writer
        self.max_backlog = max_backlog_samples
        self._queue: queue.Queue[tuple[str, tuple[Any, ...]] | None] = queue.Queue()
        self._backlog = 0  # samples queued, not yet written
        self._lock = threading.Lock()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name="sfdrig-run-writer",
                                        daemon=True)
        self._thread.start()

    def on_block(self, first_sample: int, ai: np.ndarray, ao: np.ndarray) -> None:
        if self.error is not None:
            raise RuntimeError(f"run file write failed: {self.error}")
        with self._lock:
            if self._backlog > self.max_backlog:
                raise RuntimeError(f"run file writer is {self._backlog} samples behind: the "
                                   "disk cannot keep up")
            self._backlog += ai.shape[1]
        self._queue.put(("on_block", (first_sample, ai, ao)))

    def on_step(self, step: dict[str, Any]) -> None:
        self._queue.put(("on_step", (step,)))

    def on_event(self, kind: str, message: str, sample: int) -> None:
        self._queue.put(("on_event", (kind, message, sample)))

    def drain(self, timeout_s: float = 60.0) -> None:
        """Write everything queued and stop the thread; raise the first write error."""
        self._queue.put(None)
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            raise TimeoutError(f"run writer did not finish within {timeout_s:g} s")
        if self.error is not None:
            raise RuntimeError(f"run file write failed: {self.error}")

    def _loop(self) -> None:
        while (item := self._queue.get()) is not None:
            if self.error is not None:
                continue  # keep draining so the acquisition side never blocks
            name, args = item
            try:
                getattr(self.writer, name)(*args)
            except BaseException as err:
                log.exception("run writer failed")
                self.error = err
            if name == "on_block":
                with self._lock:
                    self._backlog -= args[1].shape[1]


# --- the acquisition loop -----------------------------------------------------------------------
@dataclasses.dataclass
class RunJob:
    """One sweep to run: what the acquisition thread needs, prepared by the command thread."""

    run_id: str
    path: Path
    engine: Any  # control.sweep.SweepEngine
    writer: BackgroundWriter  # around a storage.RunWriter
    fanout: FanOut
    abort_reason: str = ""


class AcquisitionLoop:
    """The one acquisition thread: runs queued sweeps one at a time and reports how each ended
    through ``on_done(job, status, reason, fault)``: status "completed", "aborted" or "failed";
    ``fault`` when the daemon must go to the fault state (a failure, not a refusal)."""

    def __init__(self, on_start: Callable[[RunJob], None],
                 on_done: Callable[[RunJob, str, str, bool], None]) -> None:
        self._jobs: queue.Queue[RunJob | None] = queue.Queue()
        self._on_start = on_start
        self._on_done = on_done
        self._thread = threading.Thread(target=self._loop, name="sfdrig-acquisition", daemon=True)
        self._thread.start()

    def submit(self, job: RunJob) -> None:
        self._jobs.put(job)

    def stop(self, timeout_s: float = 30.0) -> None:
        self._jobs.put(None)
        self._thread.join(timeout_s)

    def _loop(self) -> None:
        while (job := self._jobs.get()) is not None:
            self._on_start(job)
            fault = False
            try:
                outcome = job.engine.run()
                status, reason = outcome_status(outcome)
            except (TargetError, InterlockError) as err:  # refused before any output
                status, reason = "failed", f"refused: {err}"
            except Exception as err:  # the engine ramped down already; record why it stopped
                log.exception("sweep %s failed", job.run_id)
                status, reason, fault = "failed", f"{type(err).__name__}: {err}", True
            self._on_done(job, status, reason, fault or status == "failed"
                          and not reason.startswith("refused"))


def outcome_status(outcome: Any) -> tuple[str, str]:
    """(status, reason) of a `SweepOutcome`, read from its ``status``/``aborted`` fields."""
    status = getattr(outcome, "status", None)
    reason = str(getattr(outcome, "reason", "") or getattr(outcome, "abort_reason", "") or "")
    if status is None:
        status = "aborted" if getattr(outcome, "aborted", False) else "completed"
    status = str(getattr(status, "value", status))
    if status not in ("completed", "aborted", "failed"):
        status = "failed" if status in ("fault", "error", "tripped") else "aborted"
    return status, reason


def as_dict(obj: Any) -> dict[str, Any]:
    """A JSON-safe dict of a progress/outcome object (pydantic model, dataclass, dict)."""
    if obj is None:
        return {}
    if hasattr(obj, "model_dump"):
        d = obj.model_dump(mode="json")
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        d = dataclasses.asdict(obj)
    elif isinstance(obj, dict):
        d = dict(obj)
    else:
        d = {k: v for k, v in vars(obj).items() if not k.startswith("_")}
    return json.loads(json.dumps(d, default=str))


# --- the daemon ---------------------------------------------------------------------------------
@dataclasses.dataclass
class DaemonConfig:
    """Everything the composition root decides. Endpoints ending in ``:0`` bind a random port."""

    runs_dir: Path
    command_endpoint: str = "tcp://127.0.0.1:0"
    data_endpoint: str = "tcp://127.0.0.1:0"
    keys: ServerKeys | None = None
    rig_config: Any = None  # RigParams of a simulated rig, or None on hardware
    limits: Any = None  # control.safety.SafetyLimits, or None for the defaults
    sndhwm: int = 1000  # PUB send high-water mark [messages]; 0 = unlimited
    lossless_publish: bool = False  # wait for the publisher instead of dropping (fast sim only)
    heartbeat_s: float = 0.25
    state_file: Path | None = None


class Daemon:
    """The state machine plus the loop, wired to sockets. Call `serve` from the main thread.

    Parameters
    ----------
    backend : DaqBackend
        The rig (simulated or real), not yet configured.
    channel_map : ChannelMap
        The acquisition configuration.
    config : DaemonConfig
        Endpoints, run directory, keys and limits.
    engine_factory, pump_factory : callable, optional
        Build the sweep engine and the pump relay (defaults: `control.sweep.SweepEngine`,
        `control.pump.PumpRelay`).
    """

    def __init__(self, backend: DaqBackend, channel_map: ChannelMap, config: DaemonConfig,
                 engine_factory: Callable[..., Any] | None = None,
                 pump_factory: Callable[..., Any] | None = None,
                 spec_parser: Callable[[dict[str, Any]], Any] | None = None) -> None:
        self.backend = backend
        self.channel_map = channel_map
        self.cfg = config
        self.cfg.runs_dir.mkdir(parents=True, exist_ok=True)
        self._engine_factory = engine_factory
        self._spec_parser = spec_parser
        self.backend.configure(channel_map)
        if pump_factory is None:
            from control.pump import PumpRelay

            pump_factory = PumpRelay
        self.pump = pump_factory(backend)

        self.sm = StateMachine(self._state_changed)
        self._job: RunJob | None = None
        self._last_run: dict[str, Any] = {}
        self.fault_reason = ""
        self._stop_reason = ""
        self._stop = threading.Event()

        self._ctx = zmq.Context()
        self._auth: Any = None
        self._command, self._data, self.endpoints = self._bind()
        channels = channel_map.ai_names + channel_map.ao_names
        self.publisher = Publisher(self._data, channels, len(channel_map.ai),
                                   channel_map.sample_rate_hz,
                                   block_when_full=config.lossless_publish)
        self.loop = AcquisitionLoop(self._run_started, self._run_done)

    # --- sockets --------------------------------------------------------------------------
    def _bind(self) -> tuple[zmq.Socket, zmq.Socket, dict[str, str]]:
        cfg = self.cfg
        for ep in (cfg.command_endpoint, cfg.data_endpoint):
            if not is_loopback(ep) and cfg.keys is None:
                raise PermissionError(
                    f"binding {ep} exposes the rig beyond this computer: CURVE keys are required "
                    f"(make them with `sfdrig keys DIR`, then pass --keys DIR)"
                )
        if cfg.keys is not None:
            self._auth = start_authenticator(self._ctx, cfg.keys)
        command = self._ctx.socket(zmq.ROUTER)
        data = self._ctx.socket(zmq.PUB)
        for s in (command, data):
            s.linger = 500
        command.router_mandatory = False
        data.sndhwm = cfg.sndhwm
        if cfg.keys is not None:
            secure_server_socket(command, cfg.keys, COMMAND_DOMAIN)
            secure_server_socket(data, cfg.keys, DATA_DOMAIN)
        endpoints = {}
        for name, sock, ep in (("command", command, cfg.command_endpoint),
                               ("data", data, cfg.data_endpoint)):
            sock.bind(_random_port(ep))
            endpoints[name] = str(sock.getsockopt_string(zmq.LAST_ENDPOINT))
        return command, data, endpoints

    # --- the command loop -------------------------------------------------------------------
    def serve(self) -> None:
        """Answer commands and send heartbeats until `stop` (or a signal) asks to shut down."""
        self._write_state_file()
        next_beat = 0.0
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= next_beat:
                    self.publisher.publish_status(self.status())
                    next_beat = now + self.cfg.heartbeat_s
                if self._command.poll(int(max(0.0, next_beat - now) * 1000) + 1):
                    self._handle(self._command.recv_multipart())
        finally:
            self._shutdown()

    def stop(self, reason: str = "shutdown requested") -> None:
        """Ask for a safe shutdown (thread- and signal-safe): abort any run, then exit `serve`."""
        self._stop_reason = reason
        job = self._job
        if job is not None:
            job.abort_reason = job.abort_reason or reason
            job.engine.abort(reason)
        self._stop.set()

    def _handle(self, frames: list[bytes]) -> None:
        identity = frames[0]
        if len(frames) >= 2 and frames[1] == b"":
            envelope, body = [identity, b""], frames[2:]
        else:
            envelope, body = [identity], frames[1:]
        try:
            if len(body) != 1:
                raise RequestError(ErrorKind.MALFORMED,
                                   f"expected one JSON request frame, got {len(body)} frames")
            req = parse_request(body[0])
            reply = self.execute(req)
        except RequestError as err:
            reply = self._error(err.kind, str(err), err.cmd, err.request_id)
        except Exception as err:  # the daemon never dies on a request
            log.exception("request failed")
            reply = self._error(ErrorKind.FAILED, f"{type(err).__name__}: {err}")
        try:
            self._command.send_multipart([*envelope, reply.to_frame()], flags=zmq.NOBLOCK)
        except zmq.ZMQError:
            log.warning("could not send a reply (client gone)")

    def _error(self, kind: ErrorKind, message: str, cmd: str = "", rid: str = "") -> Reply:
        return Reply(ok=False, cmd=cmd, request_id=rid, state=self.sm.state, error_kind=kind,
                     error=message)

    def _ok(self, req: Any, **data: Any) -> Reply:
        return Reply(ok=True, cmd=req.cmd, request_id=req.request_id, state=self.sm.state,
                     data=data)

    def execute(self, req: Any) -> Reply:
        """Carry out one validated request; refusals come back as error replies."""
        try:
            with self.sm.lock:
                return self._dispatch(req)
        except TransitionError as err:
            return self._error(ErrorKind.FORBIDDEN, f"{req.cmd}: {err}", req.cmd, req.request_id)

    def _dispatch(self, req: Any) -> Reply:
        match req:
            case StatusRequest():
                return self._ok(req, **self.status())
            case ListRunsRequest():
                return self._ok(req, runs=self.list_runs())
            case StartRequest():
                return self._start(req)
            case PauseRequest():
                self.sm.fire("pause")
                self._engine().pause()
                self._operator_event("paused by operator")
                return self._ok(req)
            case ResumeRequest():
                self.sm.fire("resume")
                self._engine().resume()
                self._operator_event("resumed by operator")
                return self._ok(req)
            case AbortRequest():
                self.sm.fire("abort")
                assert self._job is not None
                self._job.abort_reason = req.reason
                self._engine().abort(req.reason)
                return self._ok(req)
            case PumpRequest():
                return self._pump(req)
            case ResetRequest():
                self.sm.fire("reset")
                self.fault_reason = ""
                return self._ok(req)
        raise RequestError(ErrorKind.INVALID, f"unhandled request {req!r}")

    def _engine(self) -> Any:
        assert self._job is not None
        return self._job.engine

    def _operator_event(self, message: str) -> None:
        job = self._job
        if job is not None:
            job.fanout.on_event("operator", message, job.fanout.last_sample)

    def _pump(self, req: PumpRequest) -> Reply:
        if self.sm.state in (S.ARMING, S.ABORTING):
            raise TransitionError(f"'pump' is not allowed while {self.sm.state.value}")
        try:
            self.pump.set(req.on)
        except (RuntimeError, ValueError) as err:  # InterlockError: shakers running
            return self._error(ErrorKind.FORBIDDEN, f"pump: {err}", req.cmd, req.request_id)
        message = f"pump switched {'on' if req.on else 'off'} by operator"
        job = self._job
        if job is not None:
            job.fanout.on_event("pump", message, job.fanout.last_sample)
        else:
            self.publisher.on_event("pump", message, 0)
        return self._ok(req, pump_on=bool(self.pump.is_on))

    def _start(self, req: StartRequest) -> Reply:
        if not self.sm.allowed("start"):
            self.sm.fire("start")  # raises the TransitionError that names the state
        if self._spec_parser is None or self._engine_factory is None:
            from control.sweep import SweepEngine, SweepSpec  # resolved at first use
            self._spec_parser = self._spec_parser or SweepSpec.model_validate
            self._engine_factory = self._engine_factory or SweepEngine
        try:
            spec = self._spec_parser(req.spec)
        except ValidationError as err:
            return self._error(ErrorKind.INVALID, describe_errors(err, "start.spec"), req.cmd,
                               req.request_id)
        except ValueError as err:
            return self._error(ErrorKind.INVALID, f"start.spec: {err}", req.cmd, req.request_id)
        refusal = self._refusal(spec)
        if refusal is not None:
            return self._error(refusal[0], refusal[1], req.cmd, req.request_id)
        run_id = new_run_id()
        path = self.cfg.runs_dir / f"{run_id}.h5"
        from storage.runfile import RunWriter

        cm = self.channel_map
        writer = RunWriter.create(
            path, run_id, "sweep",
            channels=cm.to_json_dict()["ai"], ao_names=cm.ao_names,
            sample_rate_hz=cm.sample_rate_hz, operator=req.operator, notes=req.notes,
            channel_map=cm.to_json_dict(), rig_config=self.cfg.rig_config,
            test_spec=spec.model_dump(mode="json") if hasattr(spec, "model_dump") else spec,
            lubricated=bool(getattr(spec, "lubricated", False)),
            chunk_samples=writer_chunk_samples(cm.sample_rate_hz),
        )
        background = BackgroundWriter(writer, int(30 * cm.sample_rate_hz))
        try:
            fanout = FanOut([background], [self.publisher])
            engine = self._engine_factory(self.backend, spec, limits=self.cfg.limits,
                                          listener=fanout, pump=self.pump)
        except Exception as err:
            background.drain()
            writer.close("failed", f"{type(err).__name__}: {err}")
            return self._error(ErrorKind.FAILED, f"start: {err}", req.cmd, req.request_id)
        self._job = RunJob(run_id, path, engine, background, fanout)
        self.publisher.set_run(run_id)
        self.sm.fire("start")
        self.loop.submit(self._job)
        steps_total = len(spec.steps()) if hasattr(spec, "steps") else None
        return self._ok(req, run_id=run_id, path=str(path), steps_total=steps_total)

    def _refusal(self, spec: Any) -> tuple[ErrorKind, str] | None:
        """Why a valid sweep must not start now (before a run file exists), or None."""
        if getattr(spec, "lubricated", False) and not self.pump.is_on:
            return ErrorKind.FORBIDDEN, "start: a lubricated sweep needs the pump on " \
                "(send pump on first)"
        if hasattr(spec, "steps"):
            from control.safety import SafetyLimits, validate_targets

            try:
                validate_targets(spec.steps(), self.cfg.limits or SafetyLimits(),
                                 self.channel_map)
            except TargetError as err:
                return ErrorKind.INVALID, f"start.spec: {err}"
        return None

    # --- called from the acquisition thread ---------------------------------------------------
    def _run_started(self, job: RunJob) -> None:
        with self.sm.lock:
            if self.sm.state is S.ARMING:
                self.sm.fire("armed")

    def _run_done(self, job: RunJob, status: str, reason: str, fault: bool) -> None:
        if status == "aborted" and not reason:
            reason = job.abort_reason or self._stop_reason or "aborted"
        try:
            try:
                job.writer.drain()
            finally:
                job.writer.writer.close(status, reason)
        except Exception as err:
            log.exception("closing %s failed", job.path)
            status, reason = "failed", f"{reason}; run file close failed: {err}".lstrip("; ")
            fault = True
        with self.sm.lock:
            self._last_run = {"run_id": job.run_id, "path": str(job.path), "status": status,
                              "reason": reason}
            self.publisher.on_event("state", f"run {job.run_id} {status}"
                                    + (f": {reason}" if reason else ""), job.fanout.last_sample)
            self._job = None
            if fault:
                self.fault_reason = reason
                self.sm.fire("fault")
            else:
                self.sm.fire("finished")
            self.publisher.set_run("")

    def _state_changed(self, old: DaemonState, new: DaemonState, event: str) -> None:
        job = self._job
        sample = job.fanout.last_sample if job is not None else 0
        self.publisher.on_event("state", f"{old.value} -> {new.value} ({event})", sample)

    # --- status -----------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """What a late joiner needs: state, run, progress, pump, sequence numbers, endpoints."""
        job = self._job
        progress = as_dict(getattr(job.engine, "progress", None)) if job is not None else {}
        max_updates = getattr(getattr(job.engine, "spec", None), "max_updates", None) \
            if job is not None else None
        if max_updates is not None:
            progress["max_updates"] = max_updates
        return {
            "state": self.sm.state.value,
            "run_id": job.run_id if job is not None else "",
            "run_path": str(job.path) if job is not None else "",
            "progress": progress,
            "samples": job.fanout.last_sample if job is not None else 0,
            # durable in the run file (a reader, or a crash, sees at least these)
            "samples_flushed": job.writer.writer.samples_flushed if job is not None else 0,
            "pump_on": bool(self.pump.is_on),
            "fault_reason": self.fault_reason,
            "last_run": self._last_run,
            "next_seq": self.publisher.sequence_numbers(),
            "dropped_in_daemon": self.publisher.dropped,
            "sample_rate_hz": self.channel_map.sample_rate_hz,
            "channels": self.channel_map.ai_names,
            "units": {**{c.name: c.units for c in self.channel_map.ai},
                      **{c.name: c.units for c in self.channel_map.ao}},
            "drives": self.channel_map.ao_names,
            "endpoints": self.endpoints,
            "pid": os.getpid(),
        }

    def list_runs(self, limit: int = 500) -> list[dict[str, Any]]:
        """The run files in the runs directory, newest first, with their status."""
        from storage.reader import open_run

        active = self._job.path if self._job is not None else None
        out: list[dict[str, Any]] = []
        paths = sorted(self.cfg.runs_dir.glob("*.h5"), key=lambda p: p.stat().st_mtime,
                       reverse=True)
        for p in paths[:limit]:
            if p == active:
                out.append({"path": str(p), "run_id": p.stem, "status": "running"})
                continue
            try:
                with open_run(p) as run:
                    a = run.attrs
                    out.append({"path": str(p), "run_id": str(a.get("run_id", p.stem)),
                                "kind": str(a.get("kind", "")), "status": run.status,
                                "status_reason": str(a.get("status_reason", "")),
                                "start_time": run.start_time, "stop_time": run.stop_time,
                                "n_samples": int(run.n_samples), "n_steps": len(run.steps)})
            except Exception as err:  # a broken file is listed with why it is broken
                out.append({"path": str(p), "run_id": p.stem, "status": "unreadable",
                            "status_reason": str(err)})
        return out

    # --- shutdown -------------------------------------------------------------------------
    def _shutdown(self) -> None:
        job = self._job
        if job is not None:
            reason = self._stop_reason or "daemon shutdown"
            job.engine.abort(reason)  # the engine records the abort event at its sample
        self.loop.stop()
        self.publisher.on_event("state", f"daemon stopped: {self._stop_reason}", 0)
        self.publisher.close()
        try:
            if self.pump.is_on:
                self.pump.set(False)
        except Exception:
            log.exception("could not switch the pump off at shutdown")
        try:
            self.backend.close()
        except Exception:
            log.exception("closing the backend failed")
        self._command.close()
        self._data.close()
        if self._auth is not None:
            self._auth.stop()
        self._ctx.term()
        if self.cfg.state_file is not None:
            self.cfg.state_file.unlink(missing_ok=True)

    def _write_state_file(self) -> None:
        if self.cfg.state_file is None:
            return
        tmp = self.cfg.state_file.with_suffix(".tmp")
        tmp.write_text(json.dumps({**self.endpoints, "pid": os.getpid(),
                                   "curve": self.cfg.keys is not None}))
        tmp.replace(self.cfg.state_file)


def _random_port(endpoint: str) -> str:
    """``tcp://host:0`` -> ``tcp://host:*`` (ZeroMQ's any-free-port)."""
    return endpoint[:-2] + ":*" if endpoint.startswith("tcp://") and endpoint.endswith(":0") \
        else endpoint


def writer_chunk_samples(sample_rate_hz: float) -> int:
    """About 1/8 s per HDF5 chunk (a power of two, >= 1024 samples).

    h5py keeps the GIL while it compresses a chunk; with one-second chunks at 62.5 kS/s x 18
    channels that is tens of milliseconds at once, which starves the acquisition thread past its
    AO lead (underflow, seen on a loaded 2-core machine). Eighth-second chunks spread the same
    work into pieces of a few milliseconds.
    """
    return int(max(1024, 2 ** round(math.log2(max(sample_rate_hz, 1.0) / 8))))


def new_run_id() -> str:
    """A unique, sortable run id: UTC time plus a random suffix."""
    return f"{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}"
