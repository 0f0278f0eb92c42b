"""The daemon's command handling: one request frame in, one reply out, whatever the frame holds.

`CommandHandler` parses a request (`control.wire.protocol`), checks it against the daemon's state
machine,
carries it out on the daemon and answers; a request the state does not allow is refused with an
error reply and changes nothing.
"""

from __future__ import annotations

import functools
import logging
import math
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from control.daemon.acquisition import RunJob
from control.daemon.state import TransitionError, refusal
from control.run.engine import Engine
from control.run.errors import InterlockError, TargetError
from control.run.files import create_run_writer, new_run_id
from control.run.listener import FanOut
from control.wire.protocol import (
    AbortRequest,
    AnswerRequest,
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
    StartTestRequest,
    StatusRequest,
    describe_errors,
    parse_request,
)

if TYPE_CHECKING:
    from control.daemon.daemon import Daemon

log = logging.getLogger("sfdrig.daemon")
S = DaemonState


class CommandHandler:
    """Answers the requests of the command socket by acting on ``daemon``."""

    def __init__(self, daemon: Daemon) -> None:
        self.d = daemon

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

    def execute(self, req: Any) -> Reply:
        """Carry out one validated request; refusals come back as error replies."""
        try:
            with self.d.sm.lock:
                return self._dispatch(req)
        except TransitionError as err:
            message = f"{req.cmd}: {err}"
            if self.d.sm.state is S.FAULT and self.d.fault_reason:
                message += f" (the fault: {self.d.fault_reason})"
            return self._error(ErrorKind.FORBIDDEN, message, req.cmd, req.request_id)

    def _error(self, kind: ErrorKind, message: str, cmd: str = "", rid: str = "") -> Reply:
        return Reply(ok=False, cmd=cmd, request_id=rid, state=self.d.sm.state, error_kind=kind,
                     error=message)

    def _ok(self, req: Any, **data: Any) -> Reply:
        return Reply(ok=True, cmd=req.cmd, request_id=req.request_id, state=self.d.sm.state,
                     data=data)

    def _dispatch(self, req: Any) -> Reply:
        d = self.d
        match req:
            case StatusRequest():
                return self._ok(req, **d.status())
            case ListRunsRequest():
                return self._ok(req, runs=d.list_runs())
            case StartRequest():
                return self._start(req)
            case StartTestRequest():
                return self._start_test(req)
            case AnswerRequest():
                return self._answer(req)
            case PauseRequest():
                if d.job is not None and not d.job.engine.can_pause:
                    return self._error(ErrorKind.FORBIDDEN, "pause: a structure test does not "
                                       "pause (answer its question, or abort)", req.cmd,
                                       req.request_id)
                d.sm.fire("pause")
                self._engine().pause()
                self._operator_event("paused by operator")
                return self._ok(req)
            case ResumeRequest():
                d.sm.fire("resume")
                self._engine().resume()
                self._operator_event("resumed by operator")
                return self._ok(req)
            case AbortRequest():
                if d.sm.state is S.ABORTING:  # pressed again: it is under way, not refused
                    return self._ok(req, already_aborting=True)
                d.sm.fire("abort")
                assert d.job is not None
                d.job.abort_reason = req.reason
                self._engine().abort(req.reason)
                return self._ok(req)
            case PumpRequest():
                return self._pump(req)
            case ResetRequest():
                if d.sm.state is S.FAULT and d.backend.estop_pressed():
                    return self._error(ErrorKind.FORBIDDEN, "reset: the emergency stop is "
                                       "still pressed; release it first", req.cmd,
                                       req.request_id)
                d.sm.fire("reset")
                d.fault_reason = ""
                return self._ok(req)
        raise RequestError(ErrorKind.INVALID, f"unhandled request {req!r}")

    def _engine(self) -> Engine:
        assert self.d.job is not None
        return self.d.job.engine

    def _operator_event(self, message: str) -> None:
        job = self.d.job
        if job is not None:
            job.fanout.on_event("operator", message, job.fanout.last_sample)

    def _pump(self, req: PumpRequest) -> Reply:
        """Switch the pump. Whether it may be switched now is `control.run.pump.PumpRelay`'s
        decision alone: from a run's start to its end the daemon holds the relay
        (`Daemon.hold_pump`), so a dry run refuses on and a lubricated run refuses off."""
        d = self.d
        try:
            d.pump.set(req.on)
        except (RuntimeError, ValueError) as err:  # InterlockError: a run holds the relay
            return self._error(ErrorKind.FORBIDDEN, f"pump: {err}", req.cmd, req.request_id)
        message = f"pump switched {'on' if req.on else 'off'} by operator"
        job = d.job
        if job is not None:
            job.fanout.on_event("pump", message, job.fanout.last_sample)
        else:
            d.publisher.on_event("pump", message, 0)
        return self._ok(req, pump_on=bool(d.pump.is_on))

    def _start(self, req: StartRequest) -> Reply:
        """Validate the whole start (spec, targets, control and stream settings, the shutdown
        budget, the engine) before the run file exists; only then create it and queue the run."""
        d = self.d
        if not d.sm.allowed("start"):
            d.sm.fire("start")  # raises the TransitionError that names the state
        spec_parser, engine_factory = d.sweep_factories()
        try:
            spec = spec_parser(req.spec)
        except ValidationError as err:
            return self._error(ErrorKind.INVALID, describe_errors(err, "start.spec"), req.cmd,
                               req.request_id)
        except ValueError as err:
            return self._error(ErrorKind.INVALID, f"start.spec: {err}", req.cmd, req.request_id)
        refusal = self._refusal(spec)
        if refusal is not None:
            return self._error(refusal[0], refusal[1], req.cmd, req.request_id)
        fanout = FanOut([], [d.publisher])  # the run file joins once it exists
        try:
            engine = engine_factory(d.backend, spec, limits=d.cfg.limits, listener=fanout,
                                    pump=d.pump)
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
        path = d.cfg.runs_dir / f"{run_id}.h5"
        cm = d.channel_map
        try:
            writer = create_run_writer(path, "sweep", cm, run_id=run_id, test_spec=spec,
                                       rig_config=d.cfg.rig_config, operator=req.operator,
                                       notes=req.notes, pool=d.deflate_pool)
        except Exception as err:  # disk full, permissions: nothing has run
            log.exception("creating %s failed", path)
            return self._error(ErrorKind.FAILED, f"start: cannot create the run file: {err}",
                               req.cmd, req.request_id)
        fanout.required.append(writer)
        d.job = RunJob(run_id, path, engine, writer, fanout)
        d.publisher.set_run(run_id)
        lubricated = bool(getattr(spec, "lubricated", False))
        d.hold_pump(f"the {'lubricated' if lubricated else 'dry'} sweep {run_id}")
        d.sm.fire("start")
        d.loop.submit(d.job)
        return self._ok(req, run_id=run_id, path=str(path), steps_total=engine.steps_total)

    def _start_test(self, req: StartTestRequest) -> Reply:
        """Start a structure or instrument test with the operator in the loop."""
        from control.run.programs.engine import DRY_TESTS, SPECS, ProgramEngine
        from control.run.programs.operator import OperatorDesk

        d = self.d
        if not d.sm.allowed("start"):
            raise TransitionError(refusal("start_test", d.sm.state))
        try:
            spec = SPECS[req.test].model_validate(req.spec)
        except ValidationError as err:
            return self._error(ErrorKind.INVALID, describe_errors(err, "start_test.spec"),
                               req.cmd, req.request_id)
        if req.test in DRY_TESTS and d.pump.is_on:
            return self._error(ErrorKind.FORBIDDEN, f"start_test: the {req.test} test is dry "
                               "(no journal, no oil): switch the pump off first", req.cmd,
                               req.request_id)
        fanout = FanOut([], [d.publisher])
        desk = OperatorDesk(lambda kind, message: fanout.on_event(kind, message,
                                                                  fanout.last_sample))
        # the flow test switches the pump itself, and only it may while it runs
        owner = object()
        engine = ProgramEngine(req.test, d.backend, spec, fanout, desk, d.hands,
                               functools.partial(d.pump.set, owner=owner))
        run_id = f"{new_run_id()}-{req.test}"
        path = d.cfg.runs_dir / f"{run_id}.h5"
        try:
            writer = create_run_writer(path, req.test, d.channel_map, run_id=run_id,
                                       test_spec=spec, rig_config=d.cfg.rig_config,
                                       operator=req.operator, notes=req.notes,
                                       lubricated=req.test == "flow", pool=d.deflate_pool)
        except Exception as err:  # disk full, permissions: nothing has run
            log.exception("creating %s failed", path)
            return self._error(ErrorKind.FAILED, f"start_test: cannot create the run file: "
                               f"{err}", req.cmd, req.request_id)
        fanout.required.append(writer)
        d.job = RunJob(run_id, path, engine, writer, fanout)
        d.publisher.set_run(run_id)
        if req.test in DRY_TESTS:
            d.hold_pump(f"the dry {req.test} test {run_id}")
        else:
            d.hold_pump(f"the {req.test} test {run_id}", owner)
        d.sm.fire("start")
        d.loop.submit(d.job)
        return self._ok(req, run_id=run_id, path=str(path))

    def _answer(self, req: AnswerRequest) -> Reply:
        from control.run.programs.operator import EntryError

        desk = self.d.job.engine.desk if self.d.job is not None else None
        if desk is None:
            return self._error(ErrorKind.FORBIDDEN, "answer: no test is asking anything",
                               req.cmd, req.request_id)
        try:
            answer = desk.submit(req.question_id, req.choice, req.text)
        except EntryError as err:
            return self._error(ErrorKind.INVALID, f"answer: {err}", req.cmd, req.request_id)
        return self._ok(req, answer=answer.model_dump(mode="json"))

    def _refusal(self, spec: Any) -> tuple[ErrorKind, str] | None:
        """Why a valid sweep must not start now (before a run file exists), or None."""
        d = self.d
        lubricated = bool(getattr(spec, "lubricated", False))
        if lubricated and not d.pump.is_on:
            return ErrorKind.FORBIDDEN, "start: a lubricated sweep needs the pump on " \
                "(send pump on first)"
        if not lubricated and d.pump.is_on:
            # the run file would call oil-wet dwells dry, and identify would treat them so
            return ErrorKind.FORBIDDEN, "start: a dry sweep needs the pump off (its dwells " \
                "are recorded as dry; oil in the film would make them wet): send pump off " \
                "first, or set lubricated = true"
        if not lubricated and (wait := d.pump.drains_for_s()) > 0:
            return ErrorKind.FORBIDDEN, f"start: the film is still draining after the pump " \
                f"went off: a dry sweep can start in {math.ceil(wait):.0f} s (its dwells are " \
                f"recorded as dry; the daemon waits {d.pump.drain_s:g} s, --film-drain-s)"
        return None
