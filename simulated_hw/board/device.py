"""`SimDevice`: one simulated board, its clock, and the rig wired to it."""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections.abc import Callable

import numpy as np
from nidaqmx.utils import unflatten_channel_string

from daq.channels import AnalogInput, ChannelMap, DeviceSpec
from daq.errors import (
    DEVICE_NOT_FOUND,
    INPUT_BUFFER_OVERWRITTEN,
    INVALID_ATTRIBUTE_VALUE,
    READ_TIMEOUT,
    RESOURCE_RESERVED,
    SAMPLE_RATE_TOO_HIGH,
    WRITE_FAILED_WATCHDOG_EXPIRED,
)
from rig_model.params import RigParams
from rig_model.rig import RigModel, warm_up
from simulated_hw.board import ao_stream, counters, thermocouple, triggers
from simulated_hw.board import digital as digital_io
from simulated_hw.board.codes import (
    INVALID_AO_DATA_WRITE,
    MAX_CHUNK,
    NO_CHANS_IN_TASK,
    OUTPUT_BUFFER_EMPTY,
    PHYSICAL_CHAN_DOES_NOT_EXIST,
    SAMPLE_RATE_TOO_LOW,
    SAMPLES_CAN_NOT_YET_BE_WRITTEN,
    SAMPLES_WILL_NEVER_BE_AVAILABLE,
    TASK_NOT_RUNNING,
    WAIT_UNTIL_DONE_NOT_DONE,
    daq_error,
)
from simulated_hw.board.on_demand import OnDemandAi
from simulated_hw.board.safe_states import EmergencyStop, SafeStates
from simulated_hw.board.sensor_wiring import floating, sensors_on
from simulated_hw.board.tasks import AiRing, SimTask
from simulated_hw.board.watchdog import Watchdog

_log = logging.getLogger(__name__)

#: how much of the time between acquisitions the rig's motion is simulated [s] (a held drive
#: settles well within it; the oil and film follow the whole gap, `RigModel.rest`)
GAP_DYNAMIC_S = 1.0

#: the internal channel through which AI reads AO terminal N back (X-series ``_aoN_vs_aognd``)
INTERNAL_AO = re.compile(r"_ao(\d+)_vs_aognd", re.IGNORECASE)


def rows_index(rows: list[int]) -> slice | list[int]:
    """``rows`` as an index: a slice (a view, no copy) when they are consecutive ascending."""
    if rows and rows == list(range(rows[0], rows[0] + len(rows))):
        return slice(rows[0], rows[0] + len(rows))
    return rows


def _same_rig(a: ChannelMap, b: ChannelMap) -> bool:
    """Whether a rig built for ``a`` converts exactly as one built for ``b``."""
    return (a.sample_rate_hz, a.ai, a.ao, a.do) == (b.sample_rate_hz, b.ai, b.ao, b.do)


# --- the device -----------------------------------------------------------------------------
class SimDevice:
    """One simulated board and the rig wired to it. All methods hold the device lock briefly;
    waits for the clock happen outside it, so a relay can switch during a blocking read.

    Hardware-timed AI runs the rig; AO generates on the AI sample clock (sample-aligned with
    AI) or on its own clock (sampled at the AI sample instants while AI runs, advanced with
    the device clock otherwise); on-demand AI runs a rig of its own (`on_demand`). Every
    new rig continues the one simulated last (`carried`): the rig keeps moving between tasks."""

    def __init__(
        self,
        wiring: ChannelMap,
        params: RigParams,
        seed: int = 0,
        fast: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] | None = None,
        live_watchdog: bool = True,
        rest_on_clock: bool = False,
    ) -> None:
        self.spec: DeviceSpec = wiring.device
        self.wiring = wiring
        self.params = params
        self.seed = seed
        self.fast = fast
        self._clock = clock
        self._stopping = threading.Event()
        self._sleep = sleep if sleep is not None else self._stopping.wait
        self.lock = threading.RLock()
        self.lines: dict[str, bool] = {}  # DO line states, by canonical physical name
        self.inputs: dict[str, bool] = {}  # levels applied to input lines from outside
        self.ao_hold: dict[str, float] = {}  # AO terminal values when no generation drives them
        # watchdogs, what they hold; ``live_watchdog``: a thread expires them on time (a
        # server, whose client may die), else the next look at the board does (in process)
        self.safe = SafeStates(clock, self.lock, self._expire, live=live_watchdog)
        self.locked_ao = self.safe.locked_ao  # AO terminals an expired watchdog holds [V]
        self.locked_do = self.safe.locked_do  # lines an expired watchdog holds
        self.estop = EmergencyStop(wiring.estop)
        self.ao_tasks: list[SimTask] = []  # running hardware-timed AO tasks
        #: told every AO terminal's voltage at the AI samples it is taking, (first, (ao, n))
        self.on_terminals: Callable[[int, np.ndarray], None] | None = None
        self._vtime = 0.0  # fast mode: the device clock while no AI runs [s]
        #: fast mode: between acquisitions the device clock also follows ``clock``, in whole
        #: seconds (the in-process rig: the oil fills or drains over a pause, while a
        #: program's milliseconds of set-up leave the rig as it was); ``_idle_since``: the
        #: ``clock`` time the idle stretch began
        self.rest_on_clock = rest_on_clock
        self._idle_since = clock()
        self.on_demand = OnDemandAi(self)  # software-timed AI reads, with their own rig
        self.watchdog_timer = self.safe.timer
        self._physical = self._physical_names()
        self._ao_all = self.spec.ao_channels()  # the AO terminals, in the device's order
        #: the AO terminal each of the rig's drives is wired to
        self._wired_ao = [self._ao_all.index(c.physical_channel) for c in wiring.ao]
        self._wired_index = rows_index(self._wired_ao)  # a slice when they are in order
        #: the rig as last simulated, and the device time up to which it was: the next
        #: acquisition's rig continues from it (the rig keeps moving between tasks)
        self.carried: tuple[RigModel, float] | None = None
        self._reset_acquisition()
        self.press_estop(False)  # the emergency-stop loop is closed: released
        # load the compiled physics now, not during the first paced read (~0.5 s; more to compile);
        # the rig from the board's start on (see `carried`) has not moved yet
        warm_up(params, wiring.sample_rate_hz)
        self.carried = (RigModel(params, wiring, seed), self.now())

    def _physical_names(self) -> dict[str, tuple[str, str]]:
        """lower-case physical name -> (canonical name, kind)."""
        names: dict[str, tuple[str, str]] = {}
        for kind, chans in (("ai", self.spec.ai_channels()), ("ao", self.spec.ao_channels()),
                            ("do", self.spec.do_lines())):
            for c in chans:
                names[c.lower()] = (c, kind)
        for port in range(self.spec.do_ports):  # a port: all its lines
            c = f"{self.spec.name}/port{port}"
            names[c.lower()] = (c, "port")
        for i in range(self.spec.ao_count):  # internal channels: AI reads an AO terminal back
            c = f"{self.spec.name}/_ao{i}_vs_aognd"
            names[c.lower()] = (c, "ai")
        return names

    def _reset_acquisition(self) -> None:
        rig: RigModel | None = getattr(self, "rig", None)
        if rig is not None and getattr(self, "ai_task", None) is not None:
            self.carried = (rig, self.now())  # the rig goes on moving after the task
        if self.fast and getattr(self, "ai_task", None) is not None:
            self._vtime = self.now()  # fast mode: the clock stays where the AI left it
            self._idle_since = self._clock()
        self.rig: RigModel | None = None
        self.ai_task: SimTask | None = None
        self.t0 = 0.0
        self.generated = 0  # samples taken since the AI start trigger
        self.read_pos = 0
        self.ring: AiRing | None = None
        self._rows: list[tuple[str, int] | None] = []  # per AI channel: ("rig"|"ao", row)
        self._in_order: list[tuple[str, int] | None] = []  # `_rig_rows_in_order`
        self.floating_rng = np.random.default_rng(self.seed + 1)

    def shutdown(self) -> None:
        self._stopping.set()
        self.safe.close()

    # --- safe states ----------------------------------------------------------------------
    def feed_watchdog(self, task: SimTask) -> None:
        """Reset a watchdog task's timer; -200644 once it has expired."""
        self.safe.feed(task.watchdog, task.name)

    def clear_expiration(self, task: SimTask) -> None:
        """Unlock the lines and outputs an expired watchdog holds (they keep their values)."""
        with self.lock:
            self.ao_hold.update(self.safe.clear_expiration(task.watchdog))

    def _expire(self, w: Watchdog) -> None:
        """The board's own action on expiry: outputs and lines to their expiration states,
        the generations on them stopped, both held there until the expiration is cleared."""
        deadline = w.deadline()
        if self.ai_task is not None and not self.fast:
            due = self._due()  # everything before the expiry happened first, nothing after
            if deadline is not None:
                due = min(due, self._sample_at(deadline))
            self._advance(due)
        self.safe.hold(w)
        _log.warning("watchdog on %s expired: AO %s, lines %s", w.device_name, w.ao_states,
                     w.do_states)
        for task in list(self.ao_tasks):
            if any(ch.physical[0] in w.ao_states for ch in task.channels):
                task.error = task.error or daq_error(
                    WRITE_FAILED_WATCHDOG_EXPIRED,
                    f"task {task.name!r}: the watchdog timer expired (not reset for "
                    f"{w.timeout_s:g} s); its outputs are held in the expiration states",
                )
        self._set_lines(w.do_states)
        w.expired_event.set()

    def watchdogs(self) -> list[Watchdog]:
        return self.safe.watchdogs()

    def add_watchdog(self, w: Watchdog) -> None:
        self.safe.add(w)

    def remove_watchdog(self, w: Watchdog) -> None:
        self.safe.remove(w)

    def press_estop(self, pressed: bool) -> None:
        """Press or release the emergency-stop button the wiring map puts on an input line
        (no-op without one): the line then reads its ``pressed_level``."""
        with self.lock:
            applied = self.estop.press(pressed)
            if applied is not None:
                line, level = applied
                self.inputs[line] = level
                _log.warning("emergency stop %s (%s reads %s)", "pressed" if pressed else
                             "released", line, "high" if level else "low")

    def line_level(self, line: str) -> bool:
        """What a digital line reads: an input's external level, else what the port drives."""
        with self.lock:
            return self.inputs.get(line, self.lines.get(line, False))

    # --- the device clock -----------------------------------------------------------------
    def move_idle_clock(self, seconds: float) -> None:
        """Fast mode, no AI running: move the device clock on (an on-demand read's time)."""
        self._vtime += seconds

    def now(self) -> float:
        """Device time [s]: the wall clock when paced; in fast mode the time of the last AI
        sample taken (it moves only when someone reads, waits or reads on demand)."""
        if not self.fast:
            return self._clock()
        if self.ai_task is not None:
            return self.t0 + self.generated / self.ai_rate
        if self.rest_on_clock:
            return self._vtime + math.floor(self._clock() - self._idle_since)
        return self._vtime

    # --- lookups --------------------------------------------------------------------------
    def physical(self, name: str, kind: str, where: str) -> list[str]:
        """Canonical physical names for a (possibly list or range) channel string."""
        try:
            parts = unflatten_channel_string(name)
        except Exception as err:  # nidaqmx raises DaqError for bad range syntax
            raise daq_error(PHYSICAL_CHAN_DOES_NOT_EXIST, f"{where}: {err}") from None
        if not parts:
            raise daq_error(PHYSICAL_CHAN_DOES_NOT_EXIST, f"{where}: no physical channel given")
        out: list[str] = []
        for part in parts:
            part = part.removeprefix("/")  # "/Dev1/ai0" names the same terminal
            dev = part.split("/", 1)[0]
            if dev.lower() != self.spec.name.lower():
                raise daq_error(
                    DEVICE_NOT_FOUND,
                    f"{where}: device {dev!r} in {part!r} does not exist "
                    f"(this server has {self.spec.name})",
                )
            found = self._physical.get(part.lower())
            if found is not None and found[1] == "port" and kind in ("do", "di"):
                out.extend(p for p in self.spec.do_lines()
                           if p.lower().startswith(found[0].lower() + "/"))
                continue
            if found is None or found[1] != kind.replace("di", "do"):  # port lines are both
                have = {"ai": "ai0..ai", "ao": "ao0..ao", "do": "port0/line0..",
                        "di": "port0/line0.."}[kind]
                count = {"ai": self.spec.ai_count, "ao": self.spec.ao_count,
                         "do": self.spec.do_lines_per_port, "di": self.spec.do_lines_per_port}[kind]
                raise daq_error(
                    PHYSICAL_CHAN_DOES_NOT_EXIST,
                    f"{where}: physical channel {part!r} does not exist on {self.spec.name} "
                    f"({self.spec.product}; {kind.upper()} channels are {have}{count - 1})",
                )
            out.append(found[0])
        return out

    def check_rate(self, rate_hz: float, where: str) -> None:
        if not math.isfinite(rate_hz) or rate_hz > self.spec.max_rate_hz:
            raise daq_error(
                SAMPLE_RATE_TOO_HIGH,
                f"{where}: sample rate {rate_hz:g} S/s is above the {self.spec.product} maximum "
                f"of {self.spec.max_rate_hz:g} S/s",
            )
        if rate_hz < self.spec.min_rate_hz:
            raise daq_error(
                SAMPLE_RATE_TOO_LOW,
                f"{where}: sample rate {rate_hz:g} S/s is below the {self.spec.product} minimum "
                f"of {self.spec.min_rate_hz:g} S/s",
            )

    def terminal(self, name: str) -> str:
        """The device's AI timing terminal, e.g. ``/Dev1/ai/SampleClock`` (compare lower-case)."""
        return f"/{self.spec.name}/ai/{name}"

    # --- start / stop ---------------------------------------------------------------------
    def start(self, task: SimTask, others: list[SimTask]) -> None:
        with self.lock:
            if task.running:
                return
            self.catch_up()
            self._check_free(task, others, "start")
            if triggers.waits_on_external(task):
                triggers.arm(task)  # nothing drives the line: armed, never triggered
                return
            if task.kind == "watchdog":
                self.safe.start(task.watchdog)
                task.running = True
                return
            if task.kind == "ai" and task.rate_hz is not None:
                self._start_ai(task, others)
            elif task.kind == "ai" and self.ai_task is not None:
                raise daq_error(
                    RESOURCE_RESERVED,
                    f"start {task.name!r}: the AI converter is in use by task "
                    f"{self.ai_task.name!r}",
                )
            elif task.kind in ("ao", "do") and task.rate_hz is not None:
                self._arm_ao(task)
            elif task.kind == "di" and task.rate_hz is not None:
                task.di_read = 0
                linked = task.clock_source.lower() == self.terminal("SampleClock").lower()
                task.t_start = (self.t0 if self.ai_task is not None else None) if linked \
                    else self.now()
            elif task.kind in ("ci", "co"):
                counters.start(self, task)
            elif task.kind is None:
                raise daq_error(NO_CHANS_IN_TASK, f"start {task.name!r}: the task has no channels")
            task.error = None
            task.done = False
            task.running = True
            task.run_id += 1

    def _check_free(self, task: SimTask, others: list[SimTask], what: str) -> None:
        """-50103 when a running or reserved (committed) task holds one of ``task``'s
        channels, or, for hardware-timed AI, the AI timing engine."""
        for other in others:
            if other is task or not (other.running or other.reserved):
                continue
            held = "running" if other.running else "reserved"
            busy = {p for c in other.channels for p in c.physical}
            clash = busy & {p for c in task.channels for p in c.physical}
            if clash:
                raise daq_error(
                    RESOURCE_RESERVED,
                    f"{what} {task.name!r}: {sorted(clash)} in use by {held} task "
                    f"{other.name!r}",
                )
            if task.kind == other.kind == "ai" and task.rate_hz and other.rate_hz:
                raise daq_error(
                    RESOURCE_RESERVED,
                    f"{what} {task.name!r}: the AI timing engine is in use by {held} task "
                    f"{other.name!r}",
                )

    def reserve(self, task: SimTask, others: list[SimTask]) -> None:
        """TaskControl commit / reserve: the task's channels and timing engine are held (a
        second task asking for them gets -50103) until it is unreserved or cleared."""
        with self.lock:
            if task.kind is None:
                raise daq_error(NO_CHANS_IN_TASK,
                                f"commit {task.name!r}: the task has no channels")
            self._check_free(task, others, "commit")
            task.reserved = True

    def _arm_ao(self, task: SimTask) -> None:
        if task.ao.written == 0 and (task.regenerating or task.finite):
            raise daq_error(
                OUTPUT_BUFFER_EMPTY,
                f"start {task.name!r}: nothing was written to the output buffer (write the "
                "samples to generate before starting a regenerating or finite AO task)",
            )
        linked = task.clock_source.lower() == self.terminal("SampleClock").lower()
        triggered = bool(task.trigger_source)
        if triggered and self.ai_task is not None:
            raise daq_error(
                RESOURCE_RESERVED,
                f"start {task.name!r}: AI task {self.ai_task.name!r} is already running, so "
                "its start trigger has passed; start AO first",
            )
        for ch in task.channels if task.kind == "ao" else []:
            if ch.physical[0] in self.locked_ao:
                raise daq_error(
                    WRITE_FAILED_WATCHDOG_EXPIRED,
                    f"start {task.name!r}: {ch.physical[0]} is held in its watchdog expiration "
                    "state; clear the expiration first",
                )
        ao_all = self._ao_all
        digital = task.kind == "do"
        task.wired_rows = [] if digital else [(row, ao_all.index(ch.physical[0]))
                                               for row, ch in enumerate(task.channels)]
        terms = rows_index([term for _, term in task.wired_rows])
        task.wired_slice = terms if isinstance(terms, slice) else None
        task.ao.generated = 0
        task.ao.last = np.array([
            digital_io.channel_value(self, task, ch) if digital
            else self.terminal_value(ch.physical[0]) for ch in task.channels], dtype=float)
        ao_stream.freeze_regeneration(task)
        task.first_sample = self.generated if (linked and self.ai_task is not None) else 0
        task.t_start = None if (linked or (triggered and self.ai_task is None)) else self.now()
        self.ao_tasks.append(task)

    def _start_ai(self, task: SimTask, others: list[SimTask]) -> None:
        assert task.rate_hz is not None
        if self.ai_task is not None:
            raise daq_error(
                RESOURCE_RESERVED,
                f"start {task.name!r}: the AI timing engine is in use by task "
                f"{self.ai_task.name!r}",
            )
        self.on_demand.release()  # the on-demand rig gives way to the hardware-timed one
        ai, self._rows = self.ai_sources(task)
        try:
            rig_map = ChannelMap(device=self.spec, sample_rate_hz=task.rate_hz, ai=tuple(ai),
                                 ao=self.wiring.ao, do=self.wiring.do)
        except ValueError as err:
            raise daq_error(INVALID_ATTRIBUTE_VALUE, f"start {task.name!r}: {err}") from None
        self.rig = self.new_rig(rig_map)  # before the clock starts: building it takes time
        t0 = self.now()
        self.ai_task = task
        self.ring = AiRing(len(task.channels), task.input_buffer())
        self.generated = self.read_pos = 0
        self.t0 = t0
        for ao_task in self.ao_tasks:  # AO armed on the AI start trigger starts now
            if ao_task.t_start is None and ao_task.clock_source.lower() != \
                    self.terminal("SampleClock").lower():
                ao_task.t_start = t0
        for other in others:  # DI and edge counts on the AI sample clock start with it
            if other.kind in ("di", "ci") and other.running and other.rate_hz is not None \
                    and other.t_start is None:
                other.t_start = t0

    def ai_sources(self, task: SimTask) -> tuple[list[AnalogInput], list[tuple[str, int] | None]]:
        """The wired inputs a rig must produce for ``task``, and where each task channel reads
        from: ("rig", row), ("ao", terminal index) for an internal AO channel, None: floating."""
        ao_all = [c.lower() for c in self.spec.ao_channels()]
        ai, wired = sensors_on(self.wiring, [(ch.physical[0], (ch.min_v, ch.max_v))
                                                    for ch in task.channels])
        rows: list[tuple[str, int] | None] = []
        for ch, row in zip(task.channels, wired, strict=True):
            internal = INTERNAL_AO.fullmatch(ch.physical[0].split("/", 1)[1])
            if internal is not None:  # never wired: the board reads its own AO terminal
                rows.append(("ao", ao_all.index(f"{self.spec.name}/ao{internal[1]}".lower())))
            else:
                rows.append(None if row is None else ("rig", row))
        return ai, rows

    def new_rig(self, rig_map: ChannelMap) -> RigModel:
        """The rig behind a new acquisition: the rig as last simulated, run on to now
        (`carry_to_now`), so a drive held between tasks is read at its steady response in the
        next acquisition's first sample. The same `RigModel` when it converts the same sensors
        at the same rate (its noise goes on, and what the hands set on it stays: a push, a
        journal taken out), otherwise a new one that takes over its state."""
        rig = RigModel(self.params, rig_map, self.seed) if self.carried is None else None
        if self.carried is not None:
            self.carry_to_now()
            old, _ = self.carried
            if _same_rig(old.channel_map, rig_map):
                rig = old
            else:
                rig = RigModel(self.params, rig_map, self.seed)
                rig.continue_from(old)
            self.carried = (rig, self.now())
        assert rig is not None
        for d in self.wiring.do:
            if self.lines.get(d.physical_channel):
                rig.set_relay(d.name, True)
        return rig

    def carry_to_now(self) -> None:
        """Run the rig no acquisition runs on from when it was last simulated to now, with the
        AO terminals as they are: at most `GAP_DYNAMIC_S` of motion, and the oil and film
        follow the rest of the gap (`RigModel.rest`)."""
        if self.carried is None or self.ai_task is not None:
            return
        old, since = self.carried
        now = self.now()
        gap = now - since
        if gap <= 0:
            return
        n = int(round(min(gap, GAP_DYNAMIC_S) * old.fs))
        wired = self._wired_ao
        drive = self.present_terminals()[wired]
        while n > 0:
            k = min(n, MAX_CHUNK)
            old.process(np.repeat(drive[:, None], k, axis=1))
            n -= k
        old.rest(gap - GAP_DYNAMIC_S)
        self.carried = (old, now)

    def stop(self, task: SimTask) -> None:
        """Stop ``task``; its pending samples and its error go (it can be restarted). The AO
        terminals of a stopped generation go to their idle output behaviour."""
        with self.lock:
            self.catch_up()
            if task.watchdog is not None:
                self.safe.stop(task.watchdog)
            task.running = False
            task.error = None
            task.auto_started = False
            if task is self.ai_task:
                linked = [t for t in self.ao_tasks if t.t_start is None or
                          t.clock_source.lower() == self.terminal("SampleClock").lower()]
                for ao_task in linked:  # their clock stopped with the AI task
                    self._end_generation(ao_task)
                self._reset_acquisition()
            elif task in self.ao_tasks:
                self._end_generation(task)
            task.ao.discard()

    def _end_generation(self, task: SimTask) -> None:
        idle = ao_stream.idle_values(task)
        for (row, term) in task.wired_rows:
            self.ao_hold[self.spec.ao_channels()[term]] = float(idle[row])
        task.running = False
        self.ao_tasks.remove(task)

    # --- the clock ------------------------------------------------------------------------
    def _due(self) -> int:
        """Samples the AI clock has produced by now (paced mode)."""
        # a hair over the float product: 0.15 s at 10 kS/s is 1,500 samples, not 1,499.99..
        due = int((self._clock() - self.t0) * self.ai_rate + 1e-6)
        assert self.ai_task is not None
        return min(due, self.ai_task.samps_per_chan) if self.ai_task.finite else due

    def _sample_at(self, t: float) -> int:
        """The AI samples produced by device time ``t`` (paced mode; never before now's)."""
        return max(int((t - self.t0) * self.ai_rate) + 1, self.generated)

    @property
    def ai_rate(self) -> float:
        assert self.ai_task is not None and self.ai_task.rate_hz is not None
        return self.ai_task.rate_hz

    def catch_up(self) -> None:
        """Run the board up to the present: the rig while AI runs (paced mode), the AO
        generations on their own clocks otherwise, and the watchdog timers."""
        with self.lock:
            if self.ai_task is not None and not self.fast:
                # a watchdog that expired on the way acts from its own instant, not from the
                # end of this catch-up (its thread does so live; a clock that jumped needs it)
                for deadline in sorted(self.watchdog_timer.deadlines()):
                    at = self._sample_at(deadline)
                    if self.generated < at < self._due():
                        self._advance(at)
                        self.watchdog_timer.expire_due(deadline)
                self._advance(self._due())
            ai_clock_done = self.ai_task is None or (
                self.ai_task.finite and self.generated >= self.ai_task.samps_per_chan)
            if ai_clock_done:
                now = self.now()
                for task in self.ao_tasks:
                    if task.t_start is not None and task.rate_hz is not None:
                        count = math.floor((now - task.t_start) * task.rate_hz + 1e-9) + 1
                        ao_stream.skip(task, count - task.ao.generated)
            for task in self.ao_tasks:
                if task.kind == "do" and task.ao.last is not None:
                    self._drive_do(task)
            self.watchdog_timer.check()

    def _drive_do(self, task: SimTask) -> None:
        """A sample-clocked DO task's lines show its last sample generated."""
        levels: dict[str, bool] = {}
        assert task.ao.last is not None
        for ch, value in zip(task.channels, task.ao.last, strict=True):
            levels.update(digital_io.lines_of(ch, int(value)))
        if any(self.lines.get(p) != v for p, v in levels.items()):
            self._set_lines(levels)

    def line_level_for(self, task: SimTask, line: str) -> bool:
        """What a line reads in ``task``: a DI task, what drives it from outside (else the
        pull-down: low); a DO task, what it drives."""
        with self.lock:
            if task.kind == "di":
                return self.inputs.get(line, False)
            return self.lines.get(line, False)

    def di_acquired(self, task: SimTask) -> int:
        """Samples a sample-clocked DI task has taken by now."""
        assert task.rate_hz is not None
        due = digital_io.di_due_at(task.t_start, task.rate_hz, 0)
        if not math.isfinite(due):
            return 0
        taken = math.floor((self.now() - due) * task.rate_hz) + 1
        return min(taken, task.samps_per_chan) if task.finite else taken

    def di_due_at(self, task: SimTask, k: int) -> float:
        assert task.rate_hz is not None
        if task.t_start is None and self.ai_task is not None:
            task.t_start = self.t0
        return digital_io.di_due_at(task.t_start, task.rate_hz, k)

    def stopping(self) -> bool:
        return self._stopping.is_set()

    def _advance(self, target: int, hand_over: bool = False) -> np.ndarray | None:
        """Take samples ``generated..target``: run the AO, the rig, fill the AI buffer.
        ``hand_over`` (a fast-mode read of exactly these samples): when they come in one piece
        they go straight to the reader, returned, and only counted in the buffer (a copy in and
        out of it saved per block); None otherwise."""
        task, ring, rig = self.ai_task, self.ring, self.rig
        assert task is not None and ring is not None and rig is not None
        if task.finite:
            target = min(target, task.samps_per_chan)
        if task.error is not None:  # overwritten: the acquisition is dead until restarted
            self.generated = max(self.generated, target)
            return None
        wired = self._wired_index
        hand_over = hand_over and 0 < target - self.generated <= MAX_CHUNK
        while self.generated < target:
            n = min(target - self.generated, MAX_CHUNK)
            terminals = self._terminals(self.generated, n)
            if self.on_terminals is not None:
                self.on_terminals(self.generated, terminals)
            rig_out = rig.process(terminals[wired])
            if self._rows == self._rig_rows_in_order(rig_out.shape[0]):
                out = rig_out  # every channel the rig's row of the same index
            else:
                out = np.empty((len(self._rows), n))
                for i, source in enumerate(self._rows):
                    if source is None:  # an unwired terminal: floating input
                        out[i] = floating(self.spec, self.floating_rng, n)
                    else:
                        out[i] = (rig_out if source[0] == "rig" else terminals)[source[1]]
            self.generated += n
            if hand_over:
                ring.skip(n)
                return out
            ring.put(out)
            behind = self.generated - self.read_pos
            if behind > ring.capacity and task.error is None:
                task.error = daq_error(
                    INPUT_BUFFER_OVERWRITTEN,
                    f"task {task.name!r}: the reader fell {behind} samples behind the "
                    f"acquisition; the input buffer holds {ring.capacity} (samples "
                    f"{self.read_pos}..{self.generated - ring.capacity - 1} were overwritten)",
                    samps_per_chan_read=0,
                )
        return None

    def _rig_rows_in_order(self, n: int) -> list[tuple[str, int] | None]:
        """The sources of an acquisition whose channels are the rig's ``n`` rows in order."""
        if len(self._in_order) != n:
            self._in_order = [("rig", i) for i in range(n)]
        return self._in_order

    def terminal_value(self, physical: str) -> float:
        """What an AO terminal shows when no generation drives it [V]."""
        return self.locked_ao.get(physical, self.ao_hold.get(physical, 0.0))

    def present_terminals(self) -> np.ndarray:
        """Every AO terminal's voltage now (after `catch_up`), shape (ao_count,)."""
        ao_all = self._ao_all
        out = np.array([self.terminal_value(p) for p in ao_all])
        for task in self.ao_tasks:
            now = (task.ao.last if ao_stream.generating(task) and task.ao.last is not None
                   else ao_stream.idle_values(task))
            for row, term in task.wired_rows:
                if ao_all[term] not in self.locked_ao and task.ao.generated > 0:
                    out[term] = now[row]
        return out

    def _terminals(self, first: int, n: int) -> np.ndarray:
        """Every AO terminal's voltage at AI samples ``first..first+n``, shape (ao_count, n)."""
        ao_all = self._ao_all
        out = np.empty((len(ao_all), n))
        out[:] = np.array([self.terminal_value(p) for p in ao_all])[:, None]
        for task in self.ao_tasks:
            if task.t_start is None:  # on the AI sample clock
                k0 = max(first, task.first_sample)
                if k0 >= first + n:
                    continue
                rows = task.wired_slice
                if rows is not None:  # the task's rows are terminals in order: generated there
                    ao_stream.take(task, first + n - k0, into=out[rows, k0 - first:])
                    continue
                block = ao_stream.take(task, first + n - k0)
                for row, term in task.wired_rows:
                    out[term, k0 - first:] = block[row]
                continue
            assert task.rate_hz is not None  # on its own clock: sample the AO at AI times
            t = self.t0 + (first + np.arange(n)) / self.ai_rate
            index = np.floor((t - task.t_start) * task.rate_hz + 1e-9).astype(np.int64)
            before = task.ao.generated
            prev = task.ao.last.copy() if task.ao.last is not None else None
            block = ao_stream.take(task, max(int(index[-1]) + 1 - before, 0))
            for row, term in task.wired_rows:
                value = np.full(n, out[term, 0] if prev is None else prev[row])
                fresh = index >= before
                value[fresh] = block[row, index[fresh] - before]
                value[index < 0] = out[term, 0]
                out[term] = value
        if self.locked_ao:
            for term, p in enumerate(ao_all):
                if p in self.locked_ao:
                    out[term] = self.locked_ao[p]
        return out

    # --- reading --------------------------------------------------------------------------
    def read(self, task: SimTask, n: int, timeout_s: float, others: list[SimTask]) -> np.ndarray:
        """`_read_volts`, with thermocouple channels in their temperature units."""
        return thermocouple.scale(self.wiring, task.channels,
                                  self._read_volts(task, n, timeout_s, others))

    def _read_volts(self, task: SimTask, n: int, timeout_s: float, others: list[SimTask]
                    ) -> np.ndarray:
        """The next ``n`` samples of an AI task, shape (n_ch, n); ``n < 0``: all available (a
        finite task: the rest of it). A read starts a task that is not running, as DAQmx
        does; a finite task started that way stops when its last sample is read."""
        if triggers.waits_on_external(task):
            if not task.running:
                self.start(task, others)
            return triggers.read_times_out(self, task, n, timeout_s)
        with self.lock:
            if task.error is not None and task.running:
                raise task.error
            if not task.running:
                self.start(task, others)
                task.auto_started = True
            if task.rate_hz is None:  # an implicitly started on-demand task ends with the read
                data = self.on_demand.read(task, 1 if n < 0 else n)
                if task.auto_started:
                    self.stop(task)
                return data
            if task is not self.ai_task:
                raise daq_error(TASK_NOT_RUNNING, f"read from {task.name!r}: the task is not "
                                "running; start it first", samps_per_chan_read=0)
            if n < 0 and task.finite:
                n = task.samps_per_chan - self.read_pos
            elif n < 0:  # DAQmx_Val_Auto / read all available
                self.catch_up()
                n = self.generated - self.read_pos
            need = self.read_pos + n
            if task.finite and need > task.samps_per_chan:
                raise daq_error(
                    SAMPLES_WILL_NEVER_BE_AVAILABLE,
                    f"read of {n} samples from {task.name!r}: only "
                    f"{task.samps_per_chan - self.read_pos} of the finite acquisition's "
                    f"{task.samps_per_chan} samples are left to read",
                    samps_per_chan_read=0,
                )
            assert self.ring is not None
            self.ring.grow(n)  # a read larger than the buffer enlarges it
            if not self.fast:
                ready_at = self.t0 + need / self.ai_rate
        if not self.fast:
            self._wait_until(ready_at, timeout_s, task, n)
        with self.lock:
            if task is not self.ai_task:
                raise daq_error(TASK_NOT_RUNNING, f"read from {task.name!r}: task stopped "
                                "while waiting", samps_per_chan_read=0)
            taken: np.ndarray | None = None
            if self.fast:  # the samples not yet taken, exactly these: straight to the reader
                taken = self._advance(need, hand_over=self.generated == self.read_pos)
            else:
                self._advance(max(need, self._due()))
            if task.error is not None:
                raise task.error
            assert self.ring is not None
            data = self.ring.get(self.read_pos, n) if taken is None else taken
            self.read_pos = need
            if task.finite and need >= task.samps_per_chan:
                task.done = True
                if task.auto_started:
                    self.stop(task)
            return data

    def _wait_until(self, ready_at: float, timeout_s: float, task: SimTask, n: int) -> None:
        now = self._clock()
        deadline = math.inf if timeout_s < 0 else now + timeout_s
        if ready_at > deadline:
            self._sleep(max(0.0, deadline - now))
            self.catch_up()
            raise daq_error(
                READ_TIMEOUT,
                f"read of {n} samples from {task.name!r} timed out after {timeout_s:g} s "
                f"({self.generated - self.read_pos} available; none were consumed)",
                samps_per_chan_read=0,
            )
        while now < ready_at and not self._stopping.is_set():
            self._sleep(ready_at - now)
            now = self._clock()

    def available(self, task: SimTask) -> int:
        with self.lock:
            if task is not self.ai_task:
                return 0
            self.catch_up()
            return self.generated - self.read_pos


    # --- writing --------------------------------------------------------------------------
    def write_ao(self, task: SimTask, block: np.ndarray, auto_start: bool, timeout_s: float,
                 others: list[SimTask], in_range: bool = False) -> int:
        """Write ``block`` (n_ch, n) to an output task. ``in_range``: the caller has checked it
        against the channels' ranges already (the in-process backend, with its own words)."""
        if task.kind == "ao" and block.size and not in_range:  # each row's extremes, 2 passes
            low, high = block.min(axis=1), block.max(axis=1)
            for row, ch in enumerate(task.channels):
                if low[row] < ch.min_v or high[row] > ch.max_v:
                    raise daq_error(
                        INVALID_AO_DATA_WRITE,
                        f"write to {task.name!r}: channel {ch.name} ({ch.physical[0]}) sample "
                        f"range [{low[row]:g}, {high[row]:g}] V is outside its range "
                        f"[{ch.min_v:g}, {ch.max_v:g}] V",
                    )
        with self.lock:
            self.catch_up()
            if self.locked_ao or self.locked_do:  # an expired watchdog holds some
                self.safe.refuse_locked(f"write to {task.name!r}",
                                        [p for ch in task.channels for p in ch.physical])
        if task.rate_hz is None:  # on-demand: the outputs take the last value at once
            if not task.running and not auto_start:
                raise daq_error(TASK_NOT_RUNNING, f"write to {task.name!r}: task not running")
            with self.lock:
                for row, ch in enumerate(task.channels):
                    self.ao_hold[ch.physical[0]] = float(block[row, -1])
            return block.shape[1]
        n = block.shape[1]
        deadline = self._clock() + (math.inf if timeout_s < 0 else timeout_s)
        while True:
            with self.lock:
                self.catch_up()
                if task.error is not None:
                    raise task.error
                if task.running and task.ao.loop is not None:
                    ao_stream.queue(task, block)  # overwrites the loop being played
                    break
                space = task.output_buffer() - task.ao.queued
                if task.running and not task.regenerating:
                    space += ao_stream.fifo_samples(task)  # the board drains into its FIFO
                if not task.running and task.ao.written == 0:
                    space = max(space, n)  # the first write sizes the buffer (NI behaviour)
                if n <= space:
                    ao_stream.queue(task, block)
                    if task.buffer_samples is None and not task.running:
                        task.buffer_samples = max(task.output_buffer(), task.ao.queued)
                    break
                moving = task in self.ao_tasks and not self.fast and (
                    task.t_start is not None or self.ai_task is not None)
                rate = task.rate_hz or 1.0
            now = self._clock()
            if not moving or now >= deadline:
                raise daq_error(
                    SAMPLES_CAN_NOT_YET_BE_WRITTEN,
                    f"write of {n} samples to {task.name!r}: only {max(space, 0)} of "
                    f"{task.output_buffer()} buffer samples free after {timeout_s:g} s",
                )
            self._sleep(min(deadline - now, (n - space) / rate))
        if auto_start and not task.running:
            self.start(task, others)
        return n

    def write_lines(self, lines: list[str], values: list[bool]) -> None:
        with self.lock:
            self.catch_up()  # the relay switches at this instant of the acquisition
            self.safe.refuse_locked("write", lines)
            self._set_lines(dict(zip(lines, values, strict=True)))

    def _set_lines(self, values: dict[str, bool]) -> None:
        idle = self.carried[0] if self.carried is not None and self.ai_task is None else None
        if idle is not None:
            self.carry_to_now()  # the rig up to now followed the lines as they were
        for line, value in values.items():
            self.lines[line] = value
            for d in self.wiring.do:
                if d.physical_channel != line:
                    continue
                for rig in {id(r): r for r in (self.rig, self.on_demand.rig, idle)
                            if r is not None}.values():
                    rig.set_relay(d.name, value)

    def samples_due(self) -> int:
        """AI samples the sample clock has produced since the AI start, taken or not: paced,
        counted from the clock without simulating them; fast, those taken (0: no AI runs)."""
        with self.lock:
            if self.ai_task is None:
                return 0
            return self.generated if self.fast else max(self._due(), self.generated)

    def generated_by(self, task: SimTask) -> int:
        with self.lock:
            self.catch_up()
            return task.ao.generated

    def is_done(self, task: SimTask) -> bool:
        """DAQmx IsTaskDone: a finite task that has ended, or any task not running; a task
        stopped by an error reports that error."""
        with self.lock:
            self.catch_up()
            if task.running and task.error is not None:
                raise task.error
            if task is self.ai_task and task.finite:
                return self.generated >= task.samps_per_chan
            if task.running and task.kind == "di" and task.finite:
                return self.di_acquired(task) >= task.samps_per_chan
            if task.kind == "co":
                return counters.generation_done(self, task)
            return task.done or not task.running

    def wait_until_done(self, task: SimTask, timeout_s: float) -> None:
        """DAQmx WaitUntilTaskDone; -200560 when the task is not done in time."""
        with self.lock:
            end = self._end_time(task)
            if end is not None and self.fast:  # nothing paces the clock: move it to the end
                if self.ai_task is task:
                    self._advance(task.samps_per_chan)
                else:
                    self._vtime = max(self._vtime, end)
                end = self.now()
        if end is not None and not self.fast:
            now = self._clock()
            if timeout_s < 0 or end <= now + timeout_s:
                while now < end and not self._stopping.is_set():
                    self._sleep(end - now)
                    now = self._clock()
            else:
                self._sleep(timeout_s)
        if not self.is_done(task):
            raise daq_error(
                WAIT_UNTIL_DONE_NOT_DONE,
                f"task {task.name!r} was not done after {timeout_s:g} s"
                + ("" if task.finite else " (a continuous task is never done until stopped)"),
            )

    def advance_to(self, target: int) -> None:
        """Take the AI samples up to ``target`` now (fast mode: an event stream paces it)."""
        with self.lock:
            if self.ai_task is not None and target > self.generated:
                self._advance(target)

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of device time (the injected sleep of a paced board)."""
        self._sleep(max(seconds, 0.0))

    def pause(self, seconds: float) -> None:
        """Wait ``seconds`` of wall time (or until the device shuts down)."""
        self._stopping.wait(max(seconds, 0.0))

    def end_time(self, task: SimTask) -> float | None:
        with self.lock:
            return self._end_time(task)

    def _end_time(self, task: SimTask) -> float | None:
        """Device time at which a running finite task ends; None if it never ends by itself."""
        if task.kind == "co":
            return counters.end_time(task)
        if not task.running or not task.finite or task.rate_hz is None:
            return None
        if task is self.ai_task:
            return self.t0 + task.samps_per_chan / task.rate_hz
        if task.t_start is not None:
            return task.t_start + task.samps_per_chan / task.rate_hz
        if task.kind == "di" and self.ai_task is None:
            return None
        if self.ai_task is not None:  # on the AI clock
            return self.t0 + (task.first_sample + task.samps_per_chan) / self.ai_rate
        return None
