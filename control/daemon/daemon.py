"""The sfdrig daemon: a state machine, one acquisition loop, a command socket and a publisher.

Threads
    - the command thread (the caller of `Daemon.serve`) owns the ROUTER command socket: the
      daemon parses every request (`control.wire.protocol`), checks it against its state machine
      (`control.daemon.state`), carries it out and answers every one; the thread also sends a
      status heartbeat on the PUB stream every ``heartbeat_s``, and at each aborts a structure
      test whose operator's lease lapsed (`control.daemon.lease`);
    - the acquisition thread (`control.daemon.acquisition.AcquisitionLoop`) runs one run at a
      time (`Engine.run`, which owns the DAQ loop and ends with the drives ramped to zero whatever
      happens); every block goes to a fan-out listener: the run file (`storage.RunWriter`, created
      by `control.run.files`) and the publisher;
    - the publisher thread (`control.wire.publisher.Publisher`) owns the PUB socket.

The daemon is the one owner of its state (the state machine, the job, the fault, the pump's
hold): its commands and the acquisition thread's callbacks change it, under ``sm.lock``.

State machine (`TRANSITIONS`): a request that the table does not allow in the current state is
refused with an error reply and changes nothing. Shutdown (SIGTERM, SIGINT, `Daemon.stop`) aborts
a running sweep the safe way (drives ramped to zero, run file closed valid with status "aborted"
and the reason), then closes the sockets.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import gc
import json
import logging
import math
import os
import secrets
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, cast

import zmq
from pydantic import BaseModel, ValidationError

from control.daemon.acquisition import AcquisitionLoop, RunJob
from control.daemon.lease import OperatorLease
from control.daemon.sockets import bind_sockets
from control.daemon.state import (
    TRANSITIONS,
    StateMachine,
    TransitionError,
    allowed_commands,
    refusal,
)
from control.run.engine import Engine, RunSpec, SpecParser
from control.run.errors import InterlockError
from control.run.files import (
    close_run_file,
    create_run_writer,
    list_runs,
    new_run_id,
    recover_interrupted,
)
from control.run.listener import FanOut
from control.wire.errors import TargetError
from control.wire.heartbeat import AskedQuestion, Heartbeat, LastRun
from control.wire.protocol import (
    AbortRequest,
    AliveRequest,
    AnswerRequest,
    AnyRequest,
    DaemonState,
    ErrorKind,
    ListRunsRequest,
    PauseRequest,
    PumpRequest,
    Reply,
    RequestError,
    ResetRequest,
    ResumeRequest,
    RunListing,
    StartRequest,
    StartTestRequest,
    StatusRequest,
    describe_errors,
    parse_request,
)
from control.wire.publisher import Publisher
from control.wire.security import ServerKeys
from daq.backend import DaqBackend
from daq.channels import ChannelMap
from daq.errors import DaqWatchdogExpiredError

if TYPE_CHECKING:  # imported at first use (the daemon starts without them)
    from control.run.programs.stream import RigHands
    from control.run.pump import PumpRelay
    from control.run.safety import SafetyLimits

__all__ = ["TRANSITIONS", "Daemon", "DaemonConfig", "StateMachine", "TransitionError"]

log = logging.getLogger("sfdrig.daemon")
S = DaemonState


# --- the daemon ---------------------------------------------------------------------------------
@dataclasses.dataclass
class DaemonConfig:
    """Everything the composition root decides. Endpoints ending in ``:0`` bind a random port."""

    runs_dir: Path
    command_endpoint: str = "tcp://127.0.0.1:0"
    data_endpoint: str = "tcp://127.0.0.1:0"
    keys: ServerKeys | None = None
    rig_config: BaseModel | None = None  # RigParams of a simulated rig, or None on hardware
    limits: SafetyLimits | None = None  # None: the defaults
    sndhwm: int = 1000  # PUB send high-water mark [messages]; 0 = unlimited
    # fast sim only: wait for the publisher (instead of dropping) and for the run writer (instead
    # of failing the run when it falls 30 s of data behind a producer no clock paces)
    lossless_publish: bool = False
    heartbeat_s: float = 0.25
    state_file: Path | None = None
    # after the pump goes off, a dry sweep waits this long for the film to drain [s]: its
    # dwells are recorded as dry (the simulated film drains with a 5 s time constant)
    film_drain_s: float = 30.0
    # a structure test is aborted once the client that started it has not renewed its lease
    # (`control.daemon.lease`) for this long [s]; a sweep has no lease
    operator_lease_s: float = 10.0


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
        Build the sweep engine and the pump relay (defaults: `control.run.sweep.engine.SweepEngine`,
        `control.run.pump.PumpRelay`).
    hands : RigHands, optional
        What a person's hands do in the structure tests, done in software (simulated rig only).
    """

    def __init__(self, backend: DaqBackend, channel_map: ChannelMap, config: DaemonConfig,
                 engine_factory: Callable[..., Engine] | None = None,
                 pump_factory: Callable[..., PumpRelay] | None = None,
                 spec_parser: SpecParser | None = None,
                 hands: RigHands | None = None) -> None:
        self.backend = backend
        self.hands = hands  # control.run.programs.stream.RigHands on the simulated rig, else None
        self.channel_map = channel_map
        self.cfg = config
        self.cfg.runs_dir.mkdir(parents=True, exist_ok=True)
        self.recovered = recover_interrupted(self.cfg.runs_dir)  # before any run of ours
        self._engine_factory = engine_factory
        self._spec_parser = spec_parser
        self.backend.configure(channel_map)
        #: the board, as every place names it (status, daemon.json, run files, the page)
        self.board = backend.board
        if pump_factory is None:
            from control.run.pump import PumpRelay

            pump_factory = PumpRelay
        self.pump = pump_factory(backend, drain_s=config.film_drain_s)

        self.sm = StateMachine(self._state_changed)
        self.job: RunJob | None = None
        self._last_run: LastRun = {}
        self.fault_reason = ""
        self._stop_reason = ""
        self._stop = threading.Event()
        self._watchdog_error = ""
        self._estop_released_logged = False  # for the fault latched now
        self._idle_incidents = 0  # written to the incident log since start
        self._pump_hold = ExitStack()  # the pump interlock, held from a run's start to its end

        self._ctx = zmq.Context()
        self._command, self._data, self.endpoints, self._auth = bind_sockets(
            self._ctx, config.command_endpoint, config.data_endpoint, config.keys, config.sndhwm)
        channels = channel_map.ai_names + channel_map.ao_names
        self.publisher = Publisher(self._data, channels, len(channel_map.ai),
                                   channel_map.sample_rate_hz,
                                   block_when_full=config.lossless_publish)
        self.loop = AcquisitionLoop(self._run_started, self._run_done)
        # one compression pool for every run file: threads new each run grew the RSS run
        # after run (each took over another malloc arena; sfdrig.commands._native_memory)
        from storage.runfile import deflate_pool  # h5py: imported when the daemon is built

        self.deflate_pool = deflate_pool("sfdrig-deflate")
        # before anyone is told the endpoints (`sfdrig daemon` prints them next): a client that
        # reads daemon.json then finds these, not a dead predecessor's
        self._write_state_file()

    # --- the command loop -------------------------------------------------------------------
    def serve(self) -> None:
        """Answer commands and send heartbeats until `stop` (or a signal) asks to shut down."""
        next_beat = 0.0
        # what the first run would otherwise load (the sweep engine and what it imports) is
        # loaded now: the first sweep of a day takes as long as the fifteenth (on a loaded PC
        # the first took 1.3x the others). Then start-up's objects (modules, the backend) are
        # frozen: no collection walks them again with the GIL held (the daemon's 130,000
        # objects took about 100 ms a full collection, seconds on a loaded PC)
        self.sweep_factories()
        gc.collect()
        gc.freeze()
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= next_beat:
                    self.publisher.publish_status(self.status())
                    next_beat = now + self.cfg.heartbeat_s
                    self._feed_watchdog_while_idle()
                    self._check_estop_while_idle()
                    self._check_estop_release()
                    self._check_operator_lease()
                if self._command.poll(int(max(0.0, next_beat - now) * 1000) + 1):
                    self._handle(self._command.recv_multipart())
        finally:
            self._shutdown()

    def _check_estop_while_idle(self) -> None:
        """The emergency stop pressed between runs latches a fault and switches the pump off
        (during a run the engine's reads see it and ramp the drives down)."""
        if self.job is not None or self.sm.state is not DaemonState.IDLE:
            return
        try:
            pressed = self.backend.estop_pressed()
        except Exception as err:
            log.error("emergency stop input: %s", err)
            return
        if not pressed:
            return
        with self.sm.lock:
            if self.job is not None or self.sm.state is not DaemonState.IDLE:
                return
            self.fault_reason = "emergency stop pressed"
            self.sm.fire("fault")
        try:
            self.pump.set(False)
        except Exception:
            log.exception("could not switch the pump off after the emergency stop")
        self._log_idle_incident("e-stop", "emergency stop pressed while idle (no run): fault "
                                "latched, pump off")

    def _check_estop_release(self) -> None:
        """Once the emergency stop that latched the fault (between runs or in a run) reads
        released, say so in the incident log: the history shows how long it was held."""
        if self.job is not None or self.sm.state is not DaemonState.FAULT or \
                "emergency stop" not in self.fault_reason or self._estop_released_logged:
            return
        try:
            pressed = self.backend.estop_pressed()
        except Exception:  # reported by `_check_estop_while_idle`'s next read
            return
        if not pressed:
            self._estop_released_logged = True
            self._log_idle_incident("e-stop", "emergency stop released (the fault stays "
                                    "latched until reset)")

    def _check_operator_lease(self) -> None:
        """A test whose operator's lease lapsed is aborted the safe way (drives ramped to
        zero, the run file closed "aborted" with the reason): nobody is left to answer it.
        Requests already queued are handled first: a renewal waiting behind a slow loop is
        not a lost operator."""
        job = self.job
        if job is None or job.lease is None or not job.lease.lapsed():
            return
        for _ in range(100):
            if not self._command.poll(0):
                break
            self._handle(self._command.recv_multipart())
        with self.sm.lock:
            if self.job is not job or not job.lease.lapsed() or not self.sm.allowed("abort"):
                return
            reason = job.lease.reason()
            log.warning("run %s: %s", job.run_id, reason)
            self.sm.fire("abort")
            job.abort_reason = reason
            job.engine.abort(reason)

    def _log_idle_incident(self, incident: str, what: str) -> None:
        """An incident while no run is going is in no run file: the daemon's incident log under
        the runs directory keeps it (`storage.incident_log`, read by the page's history), and
        the data stream says it now."""
        from storage.incident_log import append_incident  # storage (h5py) at first use

        try:  # first: whoever hears the event below finds it in the log
            append_incident(self.cfg.runs_dir, incident, what)
        except OSError as err:
            log.error("incident log %s: %s (the incident: %s)", self.cfg.runs_dir, err, what)
        self._idle_incidents += 1
        self.publisher.on_event("fault" if incident == "e-stop" else "warning", what, 0)

    def _feed_watchdog_between(self) -> None:
        """Feed the board's watchdog from the end of a run (`_run_done`); an expired one is
        left to the command loop to report."""
        with contextlib.suppress(Exception):  # reported by `_feed_watchdog_while_idle`
            self.backend.feed_watchdog()

    def _feed_watchdog_while_idle(self) -> None:
        """Between runs the command loop feeds the board's watchdog (during a run the
        acquisition loop does): if this process hangs or dies, the board turns the pump relay
        off and the drives to 0 V by itself."""
        if self.job is not None:
            return
        try:
            self.backend.feed_watchdog()
        except Exception as err:  # expired or board gone: say so once, keep serving
            if isinstance(err, DaqWatchdogExpiredError):
                self._board_cut("the board's watchdog expired while idle")
            kind = type(err).__name__  # the message counts the seconds since: not per call
            if kind != self._watchdog_error:
                log.error("board watchdog: %s", err)
                if isinstance(err, DaqWatchdogExpiredError):
                    self._log_idle_incident("watchdog", f"the board's watchdog expired while "
                                            f"idle (no run): {err}")
            self._watchdog_error = kind
        else:
            self._watchdog_error = ""

    def _board_cut(self, why: str) -> None:
        """The board set the drives to 0 V and the relays off by itself (its watchdog): the
        pump is off now, whatever was asked of it; say so once on the data stream."""
        if self.pump.is_on:
            self.pump.switched_off_by_board(why)
            self.publisher.on_event("pump", f"pump off: {why} (relays off, drives 0 V; the "
                                    "next start or pump on clears it)", 0)

    def stop(self, reason: str = "shutdown requested") -> None:
        """Ask for a safe shutdown (thread- and signal-safe): abort any run, then exit `serve`."""
        self._stop_reason = reason
        job = self.job
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
            frame = self.handle(body).to_frame()
        except Exception:  # not reachable by construction; the loop must outlive it anyway
            log.exception("could not build a reply")
            frame = Reply(ok=False, state=self.sm.state, error_kind=ErrorKind.FAILED,
                          error="internal error while answering (see the daemon's log)").to_frame()
        try:
            self._command.send_multipart([*envelope, frame], flags=zmq.NOBLOCK)
        except zmq.ZMQError:
            log.warning("could not send a reply (client gone)")

    # --- the commands: one request in, one reply out ----------------------------------------
    def handle(self, body: list[bytes]) -> Reply:
        """The reply to the frames after the routing envelope; never raises."""
        try:
            if len(body) != 1:
                raise RequestError(ErrorKind.MALFORMED,
                                   f"expected one JSON request frame, got {len(body)} frames")
            req = parse_request(body[0])
            return self.execute(req)
        except RequestError as err:
            return self._error(err.kind, str(err), err.cmd, err.request_id)
        except Exception as err:  # the daemon never dies on a request
            log.exception("request failed")
            return self._error(ErrorKind.FAILED, f"{type(err).__name__}: {err}")

    def execute(self, req: AnyRequest) -> Reply:
        """Carry out one validated request; refusals come back as error replies."""
        try:
            with self.sm.lock:
                return self._dispatch(req)
        except TransitionError as err:
            message = f"{req.cmd}: {err}"
            if self.sm.state is S.FAULT and self.fault_reason:
                message += f" (the fault: {self.fault_reason})"
            # the requests allowed now as data too: a client names them in its own words
            return self._error(ErrorKind.FORBIDDEN, message, req.cmd, req.request_id,
                               allowed=allowed_commands(self.sm.state))

    def _error(self, kind: ErrorKind, message: str, cmd: str = "", rid: str = "",
               **data: object) -> Reply:
        return Reply(ok=False, cmd=cmd, request_id=rid, state=self.sm.state, error_kind=kind,
                     error=message, data=data)

    def _ok(self, req: AnyRequest, **data: object) -> Reply:
        return Reply(ok=True, cmd=req.cmd, request_id=req.request_id, state=self.sm.state,
                     data=data)

    def _dispatch(self, req: AnyRequest) -> Reply:
        match req:
            case StatusRequest():
                return self._ok(req, **self.status())
            case ListRunsRequest():
                return self._ok(req, runs=self.list_runs())
            case StartRequest():
                return self._start(req)
            case StartTestRequest():
                return self._start_test(req)
            case AnswerRequest():
                return self._answer(req)
            case AliveRequest():
                return self._alive(req)
            case PauseRequest():
                if self.job is not None and not self.job.engine.can_pause:
                    return self._error(ErrorKind.FORBIDDEN, "pause: a structure test does not "
                                       "pause (answer its question, or abort)", req.cmd,
                                       req.request_id)
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
                if self.sm.state is S.ABORTING:  # pressed again: it is under way, not refused
                    return self._ok(req, already_aborting=True)
                self.sm.fire("abort")
                assert self.job is not None
                self.job.abort_reason = req.reason
                self._engine().abort(req.reason)
                return self._ok(req)
            case PumpRequest():
                return self._pump(req)
            case ResetRequest():
                if self.sm.state is S.IDLE:  # no fault to acknowledge: a no-op, not refused
                    return self._ok(req, nothing_to_reset=True)
                if self.sm.state is S.FAULT and self.backend.estop_pressed():
                    return self._error(ErrorKind.FORBIDDEN, "reset: the emergency stop is "
                                       "still pressed; release it first", req.cmd,
                                       req.request_id)
                self.sm.fire("reset")
                self.fault_reason = ""
                return self._ok(req)
        raise RequestError(ErrorKind.INVALID, f"unhandled request {req!r}")

    def _engine(self) -> Engine:
        assert self.job is not None
        return self.job.engine

    def _operator_event(self, message: str) -> None:
        job = self.job
        if job is not None:
            job.fanout.on_event("operator", message, job.fanout.last_sample)

    def _pump(self, req: PumpRequest) -> Reply:
        """Switch the pump. Whether it may be switched now is `control.run.pump.PumpRelay`'s
        decision alone: from a run's start to its end the daemon holds the relay
        (`Daemon.hold_pump`), so a dry run refuses on and a lubricated run refuses off."""
        try:
            self.pump.set(req.on)
        except (RuntimeError, ValueError) as err:  # InterlockError: a run holds the relay
            return self._error(ErrorKind.FORBIDDEN, f"pump: {err}", req.cmd, req.request_id)
        message = f"pump switched {'on' if req.on else 'off'} by operator"
        job = self.job
        if job is not None:
            job.fanout.on_event("pump", message, job.fanout.last_sample)
        else:
            self.publisher.on_event("pump", message, 0)
        return self._ok(req, pump_on=bool(self.pump.is_on))

    def _start(self, req: StartRequest) -> Reply:
        """Validate the whole start (spec, targets, control and stream settings, the shutdown
        budget, the engine) before the run file exists; only then create it and queue the run."""
        if not self.sm.allowed("start"):
            self.sm.fire("start")  # raises the TransitionError that names the state
        spec_parser, engine_factory = self.sweep_factories()
        try:
            spec = spec_parser(req.spec)
        except ValidationError as err:
            # the parser is a model's `model_validate`: the model answers "did you mean"
            model = getattr(spec_parser, "__self__", None)
            return self._error(ErrorKind.INVALID, describe_errors(
                err, "start.spec", model if isinstance(model, type) else None), req.cmd,
                req.request_id)
        except ValueError as err:
            return self._error(ErrorKind.INVALID, f"start.spec: {err}", req.cmd, req.request_id)
        refusal = self._refusal(spec)
        if refusal is not None:
            return self._error(refusal[0], refusal[1], req.cmd, req.request_id)
        fanout = FanOut([], [self.publisher])  # the run file joins once it exists
        try:
            engine = engine_factory(self.backend, spec, limits=self.cfg.limits, listener=fanout,
                                    pump=self.pump)
        except (TargetError, ValueError) as err:
            return self._error(ErrorKind.INVALID, f"start.spec: {err}", req.cmd, req.request_id)
        except Exception as err:
            log.exception("building the sweep engine failed")
            return self._error(ErrorKind.FAILED, f"start: {type(err).__name__}: {err}",
                               req.cmd, req.request_id)
        try:  # the engine's own check, once: its run does not repeat it
            engine.check()
        except TargetError as err:
            return self._error(ErrorKind.INVALID, f"start.spec: {err}", req.cmd, req.request_id)
        except InterlockError as err:
            return self._error(ErrorKind.FORBIDDEN, f"start: {err}", req.cmd, req.request_id)
        run_id = new_run_id()
        path = self.cfg.runs_dir / f"{run_id}.h5"
        cm = self.channel_map
        try:
            writer = create_run_writer(path, "sweep", cm, run_id=run_id, test_spec=spec,
                                       rig_config=self.cfg.rig_config, operator=req.operator,
                                       notes=req.notes, pool=self.deflate_pool, board=self.board,
                                       paced=not self.cfg.lossless_publish)
        except Exception as err:  # disk full, permissions: nothing has run
            log.exception("creating %s failed", path)
            return self._error(ErrorKind.FAILED, f"start: cannot create the run file: {err}",
                               req.cmd, req.request_id)
        fanout.required.append(writer)
        self.job = RunJob(run_id, path, engine, writer, fanout)
        self.publisher.set_run(run_id)
        lubricated = spec.lubricated
        self.hold_pump(f"the {'lubricated' if lubricated else 'dry'} sweep {run_id}")
        self.sm.fire("start")
        self.loop.submit(self.job)
        return self._ok(req, run_id=run_id, path=str(path), steps_total=engine.steps_total)

    def _start_test(self, req: StartTestRequest) -> Reply:
        """Start a structure or instrument test with the operator in the loop."""
        from control.run.programs.engine import DRY_TESTS, SPECS, ProgramEngine
        from control.run.programs.operator import OperatorDesk

        if not self.sm.allowed("start"):
            raise TransitionError(refusal("start_test", self.sm.state))
        try:
            spec = SPECS[req.test].model_validate(req.spec)
        except ValidationError as err:
            return self._error(ErrorKind.INVALID, describe_errors(err, "start_test.spec"),
                               req.cmd, req.request_id)
        if req.test in DRY_TESTS and self.pump.is_on:
            return self._error(ErrorKind.FORBIDDEN, f"start_test: the {req.test} test is dry "
                               "(no journal, no oil): switch the pump off first", req.cmd,
                               req.request_id)
        fanout = FanOut([], [self.publisher])
        desk = OperatorDesk(lambda kind, message: fanout.on_event(kind, message,
                                                                  fanout.last_sample))
        # the flow test switches the pump itself, and only it may while it runs
        owner = object()
        engine = ProgramEngine(req.test, self.backend, spec, fanout, desk, self.hands,
                               functools.partial(self.pump.set, owner=owner))
        run_id = f"{new_run_id()}-{req.test}"
        path = self.cfg.runs_dir / f"{run_id}.h5"
        try:
            writer = create_run_writer(path, req.test, self.channel_map, run_id=run_id,
                                       test_spec=spec, rig_config=self.cfg.rig_config,
                                       operator=req.operator, notes=req.notes, board=self.board,
                                       lubricated=req.test == "flow", pool=self.deflate_pool,
                                       paced=not self.cfg.lossless_publish)
        except Exception as err:  # disk full, permissions: nothing has run
            log.exception("creating %s failed", path)
            return self._error(ErrorKind.FAILED, f"start_test: cannot create the run file: "
                               f"{err}", req.cmd, req.request_id)
        fanout.required.append(writer)
        # the person at this client answers it: the client renews the lease while it is there
        lease = OperatorLease(self.cfg.operator_lease_s)
        self.job = RunJob(run_id, path, engine, writer, fanout, lease=lease)
        self.publisher.set_run(run_id)
        if req.test in DRY_TESTS:
            self.hold_pump(f"the dry {req.test} test {run_id}")
        else:
            self.hold_pump(f"the {req.test} test {run_id}", owner)
        self.sm.fire("start")
        self.loop.submit(self.job)
        return self._ok(req, run_id=run_id, path=str(path), lease=lease.token,
                        lease_s=lease.seconds)

    def _alive(self, req: AliveRequest) -> Reply:
        """Renew the running test's operator lease (`control.daemon.lease`)."""
        lease = self.job.lease if self.job is not None else None
        if lease is None or not secrets.compare_digest(lease.token, req.lease):
            return self._error(ErrorKind.FORBIDDEN, "alive: no running test holds this lease "
                               "(the test has ended, or another client started it)", req.cmd,
                               req.request_id)
        lease.renew()
        return self._ok(req, lease_s=lease.seconds)

    def _answer(self, req: AnswerRequest) -> Reply:
        from control.run.programs.operator import EntryError

        desk = self.job.engine.desk if self.job is not None else None
        if desk is None:
            return self._error(ErrorKind.FORBIDDEN, "answer: no test is asking anything",
                               req.cmd, req.request_id)
        try:
            answer = desk.submit(req.question_id, req.choice, req.text)
        except EntryError as err:
            return self._error(ErrorKind.INVALID, f"answer: {err}", req.cmd, req.request_id)
        return self._ok(req, answer=answer.model_dump(mode="json"))

    def _refusal(self, spec: RunSpec) -> tuple[ErrorKind, str] | None:
        """Why a valid sweep must not start now (before a run file exists), or None."""
        lubricated = spec.lubricated
        if lubricated and not self.pump.is_on:
            return ErrorKind.FORBIDDEN, "start: a lubricated sweep needs the pump on " \
                "(send pump on first)"
        if not lubricated and self.pump.is_on:
            # the run file would call oil-wet dwells dry, and identify would treat them so
            return ErrorKind.FORBIDDEN, "start: a dry sweep needs the pump off (its dwells " \
                "are recorded as dry; oil in the film would make them wet): send pump off " \
                "first, or set lubricated = true"
        if not lubricated and (wait := self.pump.drains_for_s()) > 0:
            return ErrorKind.FORBIDDEN, f"start: the film is still draining after the pump " \
                f"went off: a dry sweep can start in {math.ceil(wait):.0f} s (its dwells are " \
                f"recorded as dry; the daemon waits {self.pump.drain_s:g} s, --film-drain-s)"
        return None

    def sweep_factories(self) -> tuple[SpecParser, Callable[..., Engine]]:
        """(spec parser, engine factory): the injected ones, else `SweepSpec`, `SweepEngine`."""
        if self._spec_parser is None or self._engine_factory is None:
            from control.run.sweep.engine import SweepEngine, SweepSpec  # resolved at first use
            self._spec_parser = self._spec_parser or SweepSpec.model_validate
            self._engine_factory = self._engine_factory or SweepEngine
        return self._spec_parser, self._engine_factory

    def hold_pump(self, what: str, owner: object | None = None) -> None:
        """Hold the pump relay until the run ends (`control.run.pump.PumpRelay`: the one place
        that refuses a switch while a run holds it): as it is, or switched by ``owner`` alone."""
        self._pump_hold.enter_context(self.pump.shakers_running(what, owner))

    # --- called from the acquisition thread ---------------------------------------------------
    def _run_started(self, job: RunJob) -> None:
        with self.sm.lock:
            if self.sm.state is S.ARMING:
                self.sm.fire("armed")

    def _run_done(self, job: RunJob, status: str, reason: str, fault: bool) -> None:
        """How a run ended: close its file, record it, leave the state. Never raises: a file that
        cannot be written or closed is reported (status "failed", an event, the last run's
        reason), but it does not fault the daemon: the drives are at zero already."""
        if status == "aborted" and not reason:
            reason = job.abort_reason or self._stop_reason or "aborted"
        # the engine fed the board's watchdog while it ran, the command loop feeds it once the
        # job is gone: in between (closing the file, the collection below) this thread does,
        # or a loaded PC lets the watchdog expire (issue 21: 1 s, bench_lab_day at load 12)
        self._feed_watchdog_between()
        problem = close_run_file(job.writer, status, reason)
        if problem:
            status, reason = "failed", f"{reason}; {problem}".lstrip("; ")
        with self.sm.lock:
            self._last_run = {"run_id": job.run_id, "path": str(job.path), "status": status,
                              "reason": reason}
            summary = job.engine.summary
            if summary:
                # the run's peak orbit and load, any contact, where a trip came (issue 21)
                self._last_run["summary"] = json.loads(json.dumps(summary, default=str))
            try:
                self.publisher.on_event("state", f"run {job.run_id} {status}"
                                        + (f": {reason}" if reason else ""),
                                        job.fanout.last_sample)
            except Exception:
                log.exception("publishing the end of run %s failed", job.run_id)
            self.job = None
            self._pump_hold.close()  # the run is over: the pump may be switched again
            if reason.startswith(DaqWatchdogExpiredError.__name__):
                self._board_cut(f"the board's watchdog expired during run {job.run_id}")
            if fault:
                self.fault_reason = reason
                self.sm.fire("fault")
            else:
                self.sm.fire("finished")
            self.publisher.set_run("")
        # a run's arrays caught in reference cycles (listeners, file objects) are freed now, not
        # whenever Python's oldest generation is next collected: the daemon's resident size
        # then follows what it holds, run after run (between runs: nothing is acquiring). It
        # walks only what came after start-up (`serve` froze that). Not frozen here: this run's
        # objects are still referenced (the acquisition thread's frame), and frozen cycles are
        # never collected (the lab-day test's RSS then grew 1.17 MB a run)
        self._feed_watchdog_between()
        gc.collect()

    def _state_changed(self, old: DaemonState, new: DaemonState, event: str) -> None:
        job = self.job
        sample = job.fanout.last_sample if job is not None else 0
        if new is S.FAULT:
            self._estop_released_logged = False  # a new fault: its release still to be seen
        self.publisher.on_event("state", f"{old.value} -> {new.value} ({event})", sample)

    # --- status -----------------------------------------------------------------------------
    def status(self) -> Heartbeat:
        """What a late joiner needs: state, run, progress, pump, sequence numbers, endpoints."""
        job = self.job
        progress = job.engine.progress_fields() if job is not None else {}
        from control.run.safety import SafetyLimits

        limits = self.cfg.limits or SafetyLimits()
        return {
            "state": self.sm.state.value,
            "allowed": allowed_commands(self.sm.state),
            "run_id": job.run_id if job is not None else "",
            "run_path": str(job.path) if job is not None else "",
            "progress": progress,
            "samples": job.fanout.last_sample if job is not None else 0,
            "samples_flushed": job.writer.samples_flushed if job is not None else 0,
            "pump_on": bool(self.pump.is_on),
            "film_drains_for_s": math.ceil(10 * self.pump.drains_for_s()) / 10,
            "safety": {"radial_clearance_m": limits.radial_clearance_m,
                       "displacement_limit_m": limits.displacement_limit_m,
                       "load_limit_n": limits.max_load_n, "drive_limit_v": limits.max_drive_v},
            "tolerance": job.engine.tolerance() if job is not None else None,
            "fault_reason": self.fault_reason,
            "idle_incidents": self._idle_incidents,
            "question": _question(job),
            "operator_lease": ({"lease_s": job.lease.seconds,
                                "silent_s": round(job.lease.silent_s(), 2)}
                               if job is not None and job.lease is not None else None),
            "last_run": self._last_run,
            "recovered_at_start": self.recovered,
            "next_seq": self.publisher.sequence_numbers(),
            "dropped_in_daemon": self.publisher.dropped,
            "sample_rate_hz": self.channel_map.sample_rate_hz,
            "channels": self.channel_map.ai_names,
            "units": {**{c.name: c.units for c in self.channel_map.ai},
                      **{c.name: c.units for c in self.channel_map.ao}},
            "drives": self.channel_map.ao_names,
            "input_ranges": {c.name: sorted((v - c.offset_v) / c.gain_v_per_unit
                                            for v in c.range_v) for c in self.channel_map.ai},
            "endpoints": self.endpoints,
            "board": self.board.as_dict(),
            "pid": os.getpid(),
        }

    def list_runs(self, limit: int = 500) -> list[RunListing]:
        """The run files in the runs directory, newest first, with their status."""
        return list_runs(self.cfg.runs_dir, self.job.path if self.job is not None else None,
                         limit)

    # --- shutdown -------------------------------------------------------------------------
    def _shutdown(self) -> None:
        job = self.job
        if job is not None:
            reason = self._stop_reason or "daemon shutdown"
            job.engine.abort(reason)  # the engine records the abort event at its sample
        self.loop.stop()
        if self.deflate_pool is not None:
            self.deflate_pool.shutdown()
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
        self._remove_state_file()

    def _remove_state_file(self) -> None:
        """Remove ``daemon.json`` only if it is this process's (never another daemon's)."""
        path = self.cfg.state_file
        if path is None:
            return
        try:
            if json.loads(path.read_text()).get("pid") != os.getpid():
                return
        except (OSError, ValueError, AttributeError):
            return
        path.unlink(missing_ok=True)

    def _write_state_file(self) -> None:
        if self.cfg.state_file is None:
            return
        tmp = self.cfg.state_file.with_suffix(".tmp")
        tmp.write_text(json.dumps({**self.endpoints, "pid": os.getpid(),
                                   "curve": self.cfg.keys is not None,
                                   "board": self.board.as_dict()}))
        tmp.replace(self.cfg.state_file)


def _question(job: RunJob | None) -> AskedQuestion | None:
    desk = job.engine.desk if job is not None else None
    q = desk.pending() if desk is not None else None
    # the same fields (tests/control/daemon/test_heartbeat_golden.py holds them together)
    return cast("AskedQuestion", q.model_dump(mode="json")) if q is not None else None
