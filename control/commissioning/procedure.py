"""`sfdrig commission`: the first power-up of a rig, through the `daq.DaqBackend` protocol, the
operator in the loop. Nothing is driven before the sensors are known to tell the truth:

1. **At rest** (nothing driven): the emergency stop must read released, and every input is read
   for ``rest_s``: its offset and noise against its sensor, the probes' gap voltages in range
   (`control.commissioning.checks.judge_rest`). Any failure ends here.
2. **Emergency stop** (with an ``[estop]`` in the map): the operator presses the button; the
   tool must see it pressed within ``estop_timeout_s``, then released.
3. **The pump relay and the watchdog** (``watchdog_s``): the pump relay on, the inlet pressure
   and flow (the map's first pressure and flow inputs) must rise within ``pump_s``: a relay that
   switches nothing names its DO line. Then the tool stops feeding the board's watchdog for
   1.5x its timeout and must find it expired (relays off, drives 0 V, by the board alone), and
   the pressure and flow must fall within ``pump_s``; without those inputs the operator
   confirms the relay dropped. The next run's first write clears the expiry.
4. **A small drive per shaker** (``drive_n`` <= 2 N at ``freq_hz``, away from the ~45 Hz
   resonance; ramped up, held, ramped down; stopped at once if a probe passes a quarter of the
   clearance or a load cell 25x the drive): each input's 1X against physics
   (`control.commissioning.checks.judge_drives`).

Everything recorded (``listener``: a `storage.RunWriter` of kind ``commissioning``; the rest,
each drive and the checks as steps and events) goes in one record with the findings; the
corrections are applied to a proposed map. Ctrl-C during a drive ramps it down first
(`CommissionInterrupted`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from control.commissioning.checks import (
    Finding,
    Plant,
    Response,
    axis_of,
    expected_response,
    judge_drives,
    judge_rest,
    show,
    where,
)
from control.signal.lockin import LockIn, cycles_to_samples
from control.signal.synthesis import SineSynthesizer
from daq.backend import DaqBackend
from daq.channels import ChannelKind, ChannelMap
from daq.device_check import LiveValues
from daq.errors import DaqError, DaqWatchdogExpiredError, EmergencyStopError
from daq.map_edits import Correction, apply_corrections
from storage import RunWriter
from storage.records import StepRecord

MAX_DRIVE_N = 2.0
LEAD_BLOCKS = 6  # AO written this many blocks ahead of the reads (0.3 s: a busy host, gRPC)
#: the least rise of an inlet gauge that counts as the pump running (the report's pump: 15.5 kPa
#: and about 0.5 L/min through the film land, Table 5 and eq. 5)
PUMP_MIN_RISE = {ChannelKind.PRESSURE_4_20MA: 2e3, ChannelKind.FLOW: 0.05}
AWAY_FROM_RESONANCE = 0.3  # the test frequency at least this fraction off the natural one


__all__ = ["CommissionError", "CommissionInterrupted", "CommissionResult", "CommissionSpec",
           "Commissioning", "Operator", "report_markdown"]


class CommissionError(ValueError):
    """A test plan that cannot be run safely (the message says why, in one line)."""


class CommissionInterrupted(KeyboardInterrupt):
    """Ctrl-C: the drive was ramped down to 0 V first."""


@dataclass(frozen=True)
class CommissionSpec:
    drive_n: float = 2.0  # force amplitude per shaker [N]
    freq_hz: float = 20.0
    rest_s: float = 1.0
    ramp_s: float = 0.3
    settle_s: float = 0.5
    record_s: float = 1.0
    block_s: float = 0.05
    clearance_m: float = 127e-6
    estop_timeout_s: float = 30.0
    watchdog_s: float | None = None  # the board's watchdog timeout; None: not tested
    pump_s: float = 2.0  # the pump's pressure and flow must rise (and fall) within this [s]
    plant: Plant = field(default_factory=Plant)

    def check(self, cm: ChannelMap) -> None:
        if not 0 < self.drive_n <= MAX_DRIVE_N:
            raise CommissionError(f"the drive must be in (0, {MAX_DRIVE_N:g}] N, got "
                                  f"{self.drive_n:g} N")
        fn = self.plant.natural_hz()
        if abs(self.freq_hz - fn) < AWAY_FROM_RESONANCE * fn or not 5 <= self.freq_hz <= 200:
            raise CommissionError(
                f"the test frequency {self.freq_hz:g} Hz must be in 5-200 Hz and at least "
                f"{AWAY_FROM_RESONANCE:.0%} away from the rig's resonance ({fn:.0f} Hz): e.g. "
                "20 Hz")
        for ao in cm.ao:
            volts = self.drive_n / ao.nominal_force_n_per_v
            if volts > min(abs(ao.range_v[0]), ao.range_v[1], 9.0):
                raise CommissionError(f"{ao.name}: {self.drive_n:g} N needs {volts:.3g} V at "
                                      f"{ao.nominal_force_n_per_v:g} N/V, outside its range")
        if self.record_s * self.freq_hz < 5 or self.rest_s * cm.sample_rate_hz < 100:
            raise CommissionError("record at least 5 cycles and rest at least 100 samples")


class Operator(Protocol):
    """The person at the rig. ``instruct`` tells them to do something the tool then watches
    for (``action``: press_estop, release_estop, pump_on, watch_relay); ``confirm`` asks yes
    or no (``action``: drive, relay_off)."""

    def instruct(self, action: str, text: str) -> None: ...

    def confirm(self, action: str, question: str) -> bool: ...


@dataclass
class CommissionResult:
    channel_map: ChannelMap
    findings: list[Finding] = field(default_factory=list)
    corrections: list[Correction] = field(default_factory=list)
    proposed: ChannelMap | None = None
    stopped: str = ""  # why it ended early ("" when every stage ran)
    measured: dict[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "fail"]

    @property
    def passed(self) -> bool:
        return not self.failed and not self.stopped


class Commissioning:
    """One commissioning of ``backend`` (configured with the map under test)."""

    def __init__(self, backend: DaqBackend, operator: Operator, spec: CommissionSpec,
                 listener: RunWriter | None = None, log: Callable[[str], None] = print,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.backend = backend
        self.cm = backend.channel_map
        spec.check(self.cm)
        self.operator = operator
        self.spec = spec
        self.listener = listener
        self.log = log
        self._clock = clock
        self._sleep = sleep
        self.sample = 0  # the record's next sample (acquisitions back to back)
        self.fs = self.cm.sample_rate_hz
        self.block = max(int(round(spec.block_s * self.fs)), 16)
        self.result = CommissionResult(self.cm)
        self._pump_level: dict[int, float] = {}  # the gauges with the pump on, over their rest
        self._steps = 0
        self._rest_mean = np.zeros((len(self.cm.ai), 1))

    # --- the whole procedure -------------------------------------------------------------
    def run(self) -> CommissionResult:
        r = self.result
        try:
            if self._rest() and self._estop() and self._watchdog():
                self._drives()
        except EmergencyStopError as err:
            self._stop(f"emergency stop: {err}")
        except DaqError as err:
            self._stop(f"DAQ error: {' '.join(str(err).split())}")
        r.proposed = apply_corrections(self.cm, r.corrections) if r.corrections else None
        return r

    def _say(self, finding: Finding) -> None:
        self.result.findings.append(finding)
        self.log(finding.line())
        if self.listener is not None:
            kind = {"fail": "error", "warn": "warning"}.get(finding.level, "info")
            self.listener.on_event(kind, finding.line(), self.sample)

    def _failed(self, where_: str, text: str, stage: str) -> bool:
        """A failed safety test: its finding, and the end of the commissioning (False)."""
        self._say(Finding("fail", where_, text))
        self._stop(f"{stage} failed")
        return False

    def _stop(self, why: str) -> None:
        self.result.stopped = why
        self.log(f"stopped: {why}")
        if self.listener is not None:
            self.listener.on_event("abort", why, self.sample)

    # --- 1. at rest ----------------------------------------------------------------------
    def _rest(self) -> bool:
        cm, spec = self.cm, self.spec
        self.log(f"at rest: reading {len(cm.ai)} inputs for {spec.rest_s:g} s, nothing driven")
        if cm.estop is not None and self.backend.estop_pressed():
            self._say(Finding("fail", where(cm.estop), (
                f"reads pressed ({'high' if cm.estop.pressed_level else 'low'}) before anyone "
                "pressed it: the loop is open (a cut wire, an unplugged connector, no supply) "
                "or pressed_level is wrong; nothing is driven")))
            self._stop("the emergency stop reads pressed at rest")
            return False
        n = max(int(round(spec.rest_s * self.fs / self.block)), 1)
        first = self.sample
        volts, _ = self._acquire(lambda k: None, n, "rest")
        rest = LiveValues.of(cm, volts)
        self._rest_mean = rest.mean[:, None]  # the watch measures from where each input rests
        self.result.measured["rest"] = {
            ch.name: {"mean": float(rest.mean[i]), "std": float(rest.std[i]),
                      "mean_v": float(rest.mean_v[i])} for i, ch in enumerate(cm.ai)}
        self._step("rest", 0.0, first, self.sample)
        verdict = judge_rest(cm, rest, spec.clearance_m)
        for f in verdict.findings:
            self._say(f)
        self.result.corrections += verdict.corrections
        if verdict.failed:
            self._stop(f"{len(verdict.failed)} input(s) do not read what their sensors should "
                       "at rest: nothing is driven until they do")
            return False
        return True

    # --- 2. the emergency stop -----------------------------------------------------------
    def _estop(self) -> bool:
        estop = self.cm.estop
        if estop is None:
            self._say(Finding("warn", "estop", "the map has no [estop] input: the emergency "
                              "stop is not read by the software (not tested)"))
            return True
        for action, want, text in (
                ("press_estop", True, "press the emergency stop now"),
                ("release_estop", False, "release the emergency stop now")):
            self.log(f"emergency stop: {text} (waiting up to {self.spec.estop_timeout_s:g} s)")
            self._event("operator", f"asked to {text.removesuffix(' now')}")
            self.operator.instruct(action, f"{text[0].upper()}{text[1:]}.")
            t0 = self._clock()
            while self.backend.estop_pressed() != want:
                self.backend.feed_watchdog()
                if self._clock() - t0 > self.spec.estop_timeout_s:
                    return self._failed(where(estop), (
                        f"did not read {'pressed' if want else 'released'} within "
                        f"{self.spec.estop_timeout_s:g} s of being asked: check its wiring "
                        f"and pressed_level ({estop.pressed_level})"), "the emergency-stop test")
                self._sleep(0.05)
        self._say(Finding("ok", where(estop), "read pressed when pressed and released when "
                          "released"))
        return True

    # --- 3. the pump relay and the watchdog ------------------------------------------------
    def _watchdog(self) -> bool:
        timeout = self.spec.watchdog_s
        relay = self.cm.do[0] if self.cm.do else None
        gauges = self._pump_gauges()
        if relay is not None and gauges and not self._pump_on(relay.name, gauges):
            return False
        if timeout is None:
            if relay is not None and gauges:
                self.backend.set_do(relay.name, False)
                if not self._pump_off(relay.name, gauges, "switched off"):
                    return False
            self._say(Finding("warn", "watchdog", "this backend has no watchdog timer: not "
                              "tested"))
            return True
        name = relay.name if relay is not None else None
        self.operator.instruct("watch_relay", (
            (f"Watchdog test: the {name} relay stays on and the tool stops feeding the board's "
             f"watchdog; within {timeout:g} s the board must switch it off by itself (the "
             "pressure and flow must fall)." if gauges else
             f"Watchdog test: the tool switches the {name} relay on (isolate what it powers, or "
             f"watch its indicator) and stops feeding the board's watchdog; within {timeout:g} s "
             "the board must switch it off by itself.")
            if name else "Watchdog test: the tool stops feeding the board's watchdog."))
        self.backend.feed_watchdog()
        if name is not None and not gauges:
            self.backend.set_do(name, True)
            self._event("pump", f"{name} relay on (watchdog test)")
        quiet = 1.5 * timeout
        self.log(f"watchdog: not fed for {quiet:g} s (timeout {timeout:g} s)")
        self._sleep(quiet)
        try:
            self.backend.feed_watchdog()
        except DaqWatchdogExpiredError:
            expired = True
        else:
            expired = False
        if not expired:
            if name is not None:
                self.backend.set_do(name, False)
            return self._failed("watchdog", (
                f"still running after {quiet:g} s without being fed (timeout {timeout:g} s): "
                "the board would keep a hung PC's drives and pump going"), "the watchdog test")
        if name is not None and gauges:
            if not self._pump_off(name, gauges, "the watchdog expired"):
                return False
        elif name is not None and not self.operator.confirm(
                "relay_off", f"Did the {name} relay switch off by itself?"):
            return self._failed("watchdog", (
                f"the board reports its watchdog expired, but the operator saw the {name} "
                "relay stay on: check the relay's wiring and the watchdog's expiration "
                "states"), "the watchdog test")
        self._say(Finding("ok", "watchdog", (
            f"expired after {quiet:g} s unfed (timeout {timeout:g} s): "
            f"{f'the {name} relay off, ' if name else ''}drives at 0 V, by the board")))
        if not gauges:
            self._acquire(lambda k: None, 2, "clear")  # the first write clears the expiry
        return True

    def _pump_gauges(self) -> list[int]:
        """The rows of the inputs that prove the pump runs: the inlet pressure and flow (the
        first pressure and the first flow input of the map)."""
        rows = []
        for kind in (ChannelKind.PRESSURE_4_20MA, ChannelKind.FLOW):
            row = next((i for i, ch in enumerate(self.cm.ai) if ch.kind is kind), None)
            if row is not None:
                rows.append(row)
        return rows

    def _pump_trace(self, what: str) -> np.ndarray:
        """``pump_s`` of every input, nothing driven (the reads feed the watchdog), in
        engineering units less their rest; the pump's step recorded."""
        n = max(int(math.ceil(self.spec.pump_s * self.fs / self.block)), 2)
        first = self.sample
        volts, _ = self._acquire(lambda k: None, n, what)
        self._step(what, 0.0, first, self.sample)
        return np.asarray(self.cm.to_engineering(volts) - self._rest_mean)

    def _rise(self, gauges: list[int]) -> dict[int, float]:
        """What each gauge must rise by to count as the pump running: six times its noise at
        rest, at least `PUMP_MIN_RISE` of its kind (a small pump's few kPa, a trickle of flow)."""
        rest = self.result.measured.get("rest", {})
        out = {}
        for i in gauges:
            ch = self.cm.ai[i]
            std = float(rest.get(ch.name, {}).get("std", 0.0))
            out[i] = max(6 * std, PUMP_MIN_RISE[ch.kind])
        return out

    def _pump_on(self, relay: str, gauges: list[int]) -> bool:
        """The relay on: the pressure and the flow must rise within ``pump_s``."""
        cm, spec = self.cm, self.spec
        do = cm.relay(relay)
        self.operator.instruct("pump_on", (
            f"Pump test: the tool switches the {relay} relay on ({do.physical_channel}) with the "
            f"damper's oil loop closed; the inlet pressure and flow must rise within "
            f"{spec.pump_s:g} s."))
        self.backend.feed_watchdog()
        self.backend.set_do(relay, True)
        self._event("pump", f"{relay} relay on (the pump test)")
        self.log(f"pump: {relay} on ({do.physical_channel}); the pressure and flow must rise "
                 f"within {spec.pump_s:g} s")
        trace = self._pump_trace("pump on")
        tail = trace[:, -max(trace.shape[1] // 10, 1):].mean(axis=1)
        need = self._rise(gauges)
        self._pump_level = {i: float(tail[i]) for i in gauges}
        rose = [i for i in gauges if tail[i] > need[i]]
        said = ", ".join(f"{cm.ai[i].name} {show(cm.ai[i], float(tail[i]))} (at least "
                         f"{show(cm.ai[i], need[i])} expected)" for i in gauges)
        if len(rose) < len(gauges):
            self.backend.set_do(relay, False)
            if not rose:
                return self._failed(f"{do.name} ({do.physical_channel})", (
                    f"switched on, nothing followed within {spec.pump_s:g} s: {said}: the "
                    "pump's relay is not on this line (another DO line, its coil unwired) or "
                    "the pump has no power or no oil"), "the pump test")
            return self._failed(f"{do.name} ({do.physical_channel})", (
                f"switched on, only {', '.join(cm.ai[i].name for i in rose)} rose within "
                f"{spec.pump_s:g} s: {said}: a closed valve, or a gauge not on its line"),
                "the pump test")
        self._say(Finding("ok", f"{do.name} ({do.physical_channel})", (
            f"switched on, the pump ran within {spec.pump_s:g} s: {said.replace(' expected', '')}"
            .replace("(at least", "(over"))))
        return True

    def _pump_off(self, relay: str, gauges: list[int], cause: str) -> bool:
        """After ``cause``: the pressure and the flow must fall below half their pump-on rise
        within ``pump_s``."""
        cm = self.cm
        do = cm.relay(relay)
        trace = self._pump_trace("pump off")
        tail = trace[:, -max(trace.shape[1] // 10, 1):].mean(axis=1)
        stayed = [i for i in gauges if tail[i] > 0.5 * self._pump_level[i]]
        said = ", ".join(f"{cm.ai[i].name} {show(cm.ai[i], float(tail[i]))} (was "
                         f"{show(cm.ai[i], self._pump_level[i])})" for i in gauges)
        if stayed:
            self.backend.set_do(relay, False)
            return self._failed(f"{do.name} ({do.physical_channel})", (
                f"{cause}, but the pump ran on for {self.spec.pump_s:g} s: {said}: the relay "
                "did not drop (a welded contact, the pump on another switch, the watchdog's "
                "expiration states)"), "the pump test")
        self._say(Finding("ok", f"{do.name} ({do.physical_channel})", (
            f"{cause}: the pump stopped within {self.spec.pump_s:g} s: {said}")))
        return True

    # --- 4. the drives -------------------------------------------------------------------
    def _drives(self) -> None:
        spec, cm = self.spec, self.cm
        axes = [ao.axis for ao in cm.ao]
        if not axes:
            self._stop("the map has no shaker drive")
            return
        if not self.operator.confirm("drive", (
                f"Journal out, amplifiers on with their gain low, nobody touching the rig: "
                f"drive {spec.drive_n:g} N at {spec.freq_hz:g} Hz on {' then '.join(axes)}?")):
            self._stop("the operator did not allow the drive")
            return
        responses: dict[str, dict[str, Response]] = {}
        forces: dict[str, complex] = {}
        for axis in axes:
            got = self._drive(axis)
            if got is None:
                return
            responses[axis], forces[axis] = got
        verdict = judge_drives(cm, responses, forces, spec.freq_hz)
        for f in verdict.findings:
            self._say(f)
        self.result.corrections += verdict.corrections

    def _drive(self, axis: str) -> tuple[dict[str, Response], complex] | None:
        spec, cm = self.spec, self.cm
        row = cm.ao_for_axis(axis)
        ao = cm.ao[row]
        volts = spec.drive_n / ao.nominal_force_n_per_v
        synth = SineSynthesizer(len(cm.ao), self.fs)
        synth.ramp_to(np.zeros(len(cm.ao), complex), spec.freq_hz, 0.0)
        target = np.zeros(len(cm.ao), complex)
        target[row] = volts
        ramp_blocks = int(math.ceil(spec.ramp_s * self.fs / self.block))
        settle_blocks = int(math.ceil(spec.settle_s * self.fs / self.block))
        record = cycles_to_samples(spec.freq_hz, self.fs, round(spec.record_s * spec.freq_hz))
        record_blocks = int(math.ceil(record / self.block))
        down_at = ramp_blocks + settle_blocks + record_blocks
        total = down_at + ramp_blocks + 2

        def program(k: int) -> np.ndarray | None:
            if k == 0:
                synth.ramp_to(target, None, spec.ramp_s)
            elif k == ramp_blocks:  # written a lead ahead of playing
                self.log(f"drive {axis}: at {spec.drive_n:g} N, settling {spec.settle_s:g} s, "
                         f"recording {record / self.fs:.3g} s")
            elif k == down_at:
                synth.fade_out(spec.ramp_s)
            return synth.next_block(self.block)

        self.log(f"drive {axis}: {spec.drive_n:g} N ({volts:.3g} V on {ao.name}) at "
                 f"{spec.freq_hz:g} Hz, ramped over {spec.ramp_s:g} s")
        first = self.sample
        ai_v, ao_v = self._acquire(program, total, f"drive {axis}", synth=synth,
                                   watch=(volts, spec.drive_n))
        if ai_v is None:
            return None
        start = (ramp_blocks + settle_blocks) * self.block
        window = slice(start, start + record)
        eng = cm.to_engineering(ai_v[:, window])
        lock = LockIn(self.fs, n_harmonics=2)
        z, sigma = lock.fundamental_with_error(eng, first + start, spec.freq_hz)
        d = complex(lock.fundamental_with_error(ao_v[row:row + 1, window], first + start,
                                                spec.freq_hz)[0][0])
        force = d * ao.nominal_force_n_per_v
        unit = d / abs(d)  # phases referred to the drive's
        resp = {ch.name: Response(complex(z[i] / unit), float(sigma[i]), complex(
            expected_response(ch, axis, abs(force), spec.freq_hz, spec.plant)))
            for i, ch in enumerate(cm.ai) if axis_of(ch) is not None}
        self.result.measured[f"drive_{axis}"] = {
            "force_n": abs(force), "drive_v": abs(d),
            "channels": {n: {"re": r.z.real, "im": r.z.imag, "sigma": r.sigma,
                             "expected_re": r.expected.real, "expected_im": r.expected.imag}
                         for n, r in resp.items()}}
        self._step(f"drive {axis}", spec.freq_hz, first + start, first + start + record,
                   "load", spec.drive_n, axis, converged=True,
                   harmonics={ch.name: (complex(z[i]),) for i, ch in enumerate(cm.ai)},
                   drive_v={ao.name: complex(d)})
        return resp, abs(force)

    # --- acquisition ----------------------------------------------------------------------
    def _acquire(self, program: Callable[[int], np.ndarray | None], n_blocks: int, what: str,
                 synth: SineSynthesizer | None = None,
                 watch: tuple[float, float] | None = None) -> tuple[Any, Any]:
        """``n_blocks`` blocks with AO ``program(k)`` (None: 0 V), AO written ``LEAD_BLOCKS``
        ahead; the AI volts and AO volts of the whole acquisition, or (None, None) when the
        watch stopped it. Ctrl-C ramps a running drive down, then raises."""
        be, cm = self.backend, self.cm
        zero = np.zeros((len(cm.ao), self.block))
        written: list[np.ndarray] = []

        def block(k: int) -> np.ndarray:
            out = program(k) if k < n_blocks else None
            b = zero if out is None else out
            written.append(b)
            return b

        reads: list[np.ndarray] = []
        stopped = ""
        started = False
        try:
            try:
                be.write_ao(np.hstack([block(k) for k in range(LEAD_BLOCKS)]))
                be.start()
                started = True
                for k in range(n_blocks):
                    ai = be.read_ai(self.block)
                    reads.append(ai)
                    if self.listener is not None:
                        self.listener.on_block(self.sample, cm.to_engineering(ai),
                                               written[k])
                    self.sample += self.block
                    if watch is not None and not stopped:
                        stopped = self._over(cm.to_engineering(ai), watch)
                        if stopped:
                            be.cut_ao()
                            break
                    be.write_ao(block(k + LEAD_BLOCKS))
            except EmergencyStopError:
                be.cut_ao()  # pressed during a drive: its queued AO does not play
                raise
            except KeyboardInterrupt:
                if synth is None or not started:
                    raise CommissionInterrupted(f"{what}: interrupted; nothing was driven") \
                        from None
                self._ramp_down(synth, written, len(reads))
                raise CommissionInterrupted(f"{what}: interrupted; the drive ramped down to "
                                            "0 V") from None
        finally:
            be.stop()
        if stopped:
            self._say(Finding("fail", what, stopped))
            self._stop(f"{what}: the safety watch stopped the drive")
            return None, None
        return np.hstack(reads), np.hstack(written[:n_blocks])

    def _ramp_down(self, synth: SineSynthesizer, written: list[np.ndarray], read: int) -> None:
        """Fade the drive from where the synthesiser is (the blocks already queued play
        first), a block written for each read, until the fade and a block of 0 V have been
        read (and recorded); a second Ctrl-C or an error cuts the drive instead."""
        be, cm = self.backend, self.cm
        fade = int(math.ceil(synth.fade_out(min(self.spec.ramp_s, 0.2)) / self.block)) + 1
        try:
            for _ in range(fade):
                written.append(synth.next_block(self.block))
                be.write_ao(written[-1])
            while read < len(written):
                ai = be.read_ai(self.block)
                if self.listener is not None:
                    self.listener.on_block(self.sample, cm.to_engineering(ai), written[read])
                self.sample += self.block
                read += 1
        except (KeyboardInterrupt, DaqError):
            be.cut_ao()

    def _over(self, eng: np.ndarray, watch: tuple[float, float]) -> str:
        """Why a block must stop the drive ("" when it need not): a probe a quarter of the
        clearance from where it rested, a load cell over 25x the drive."""
        _, force = watch
        eng = eng - self._rest_mean
        limit_x = 0.25 * self.spec.clearance_m
        for i, ch in enumerate(self.cm.ai):
            peak = float(np.max(np.abs(eng[i])))
            if ch.kind is ChannelKind.EDDY_CURRENT_PROBE and peak > limit_x:
                return (f"stopped at once: {ch.name} read {peak * 1e6:.0f} um under a "
                        f"{force:g} N drive (limit {limit_x * 1e6:.0f} um)")
            if ch.kind is ChannelKind.LOAD_CELL and ch.name != "hammer" and \
                    peak > 25 * force + 5:
                return (f"stopped at once: {ch.name} read {peak:.0f} N under a {force:g} N "
                        "drive")
        return ""

    # --- the record ----------------------------------------------------------------------
    def _step(self, stage: str, freq_hz: float, first: int, last: int, target_kind: str = "",
              target_value: float = 0.0, motion: str = "", converged: bool = False,
              harmonics: Mapping[str, tuple[complex, ...]] | None = None,
              drive_v: Mapping[str, complex] | None = None) -> None:
        step = StepRecord(index=self._steps, freq_hz=freq_hz, target_kind=target_kind,
                          target_value=target_value, motion=motion, first_sample=first,
                          last_sample=last, converged=converged, harmonics=dict(harmonics or {}),
                          drive_v=dict(drive_v or {}), extra={"stage": stage})
        self._steps += 1
        if self.listener is not None:
            self.listener.on_step(step)

    def _event(self, kind: str, message: str) -> None:
        if self.listener is not None:
            self.listener.on_event(kind, message, self.sample)


def report_markdown(result: CommissionResult, map_name: str, record: str, diff: str,
                    spec: CommissionSpec, board: str) -> str:
    """The commissioning's short report: verdict and the board it was reached on (a rehearsal's
    says "simulated"), every finding, the proposed corrections."""
    verdict = "PASSED" if result.passed else "FAILED"
    lines = [f"# Commissioning of {map_name} on the {board}: {verdict}", "",
             f"- verdict: {verdict} on the {board}",
             f"- record: `{record}`",
             f"- drive: {spec.drive_n:g} N per shaker at {spec.freq_hz:g} Hz; rest "
             f"{spec.rest_s:g} s; watchdog "
             f"{'not tested' if spec.watchdog_s is None else f'{spec.watchdog_s:g} s'}; the "
             f"pump's pressure and flow within {spec.pump_s:g} s"]
    if result.stopped:
        lines.append(f"- stopped early: {result.stopped}")
    lines += ["", "## Findings", "", "| | where | what |", "|---|---|---|"]
    lines += [f"| {f.level} | {f.where} | {f.text} |" for f in result.findings]
    lines += ["", "## Proposed corrections", ""]
    if result.corrections:
        lines += [f"- {c.line()}" for c in result.corrections]
        lines += ["", "```diff", diff.rstrip("\n"), "```"]
    else:
        lines.append("none")
    return "\n".join(lines) + "\n"
