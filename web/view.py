"""What the browser draws, computed from the daemon's live stream (no I/O here).

`LiveView` is fed every message of a `control.wire.client.Subscriber` (blocks, steps, events, status
heartbeats) and keeps only what the page shows: the last second of samples in a ring buffer, the
step points of the run, the recent events and the latest status. `LiveView.frame` turns that into
one small JSON-safe dict, decimated on the server: a few triggered cycles of each trace and of the
orbit (at most ``points`` samples each), the 1X-5X harmonics of the current step, and the step
table. The browser gets what it draws, never the 1 MS/s stream.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Mapping
from typing import Any, NotRequired, TypedDict

import numpy as np

from control.wire.client import Message
from control.wire.harmonics import LockIn
from control.wire.heartbeat import Heartbeat
from control.wire.summary_lines import CONTACT, peak_line
from storage.records import BlockHeader, EventRecord, StepRecord

UM = 1e-6
STALE_AFTER_S = 1.0  # traces older than this are drawn grey, with the time of their data
TWO_AXIS = ("circular_forward", "circular_backward", "elliptical")
TRACE_UNITS = ("N", "m", "m/s^2")  # drawn as traces; the rest (pressure, flow, oil) as means


class Link(TypedDict):
    """How the page's link to the daemon is (`web.feed.DaemonLink` judges it): ``state``
    ("connecting", "live", "late", "lost") and why, the endpoints followed, the daemon's pid
    (None: not known), how often the link followed a restarted daemon."""

    state: str
    message: str
    command: NotRequired[str]
    data: NotRequired[str]
    pid: NotRequired[int | None]
    reconnects: NotRequired[int]


def _mean_z(harmonics: Mapping[str, tuple[complex, ...]],
            names: tuple[str, ...]) -> complex | None:
    zs = [harmonics[n][0] for n in names if n in harmonics and harmonics[n]]
    return sum(zs) / len(zs) if zs else None


def step_point(step: StepRecord, tolerance_amplitude_pct: float,
               tolerance_phase_deg: float) -> dict[str, Any]:
    """One row of the step table and one point of the plots against frequency.

    The amplitude is the 1X of the reference axis (Y for motion "y", else X): the mean of the two
    probes [um] for a displacement target, the load cell [N] for a load target. The phase is Y
    relative to X [deg] for two-axis motions (the controlled quantity, with its target), else the
    reference displacement relative to its load (not controlled: no target). Also the largest
    drive's 1X amplitude [V] and each axis's direct dynamic stiffness F/X [MN/m, re and im].
    """
    h = step.harmonics
    axis = "y" if step.motion == "y" else "x"
    other = "x" if axis == "y" else "y"
    disp = {a: _mean_z(h, (f"{a}1", f"{a}2")) or _mean_z(h, (a,)) for a in ("x", "y")}
    force = {a: _mean_z(h, (f"f{a}",)) for a in ("x", "y")}
    load = step.target_kind == "load"
    ref = force[axis] if load else disp[axis]
    scale = 1.0 if load else 1 / UM
    target = step.target_value * scale
    motion = step.motion
    phase_target: float | None = None
    if motion in TWO_AXIS:
        zx, zy = (force["x"], force["y"]) if load else (disp["x"], disp["y"])
        phase = math.degrees(np.angle(zy / zx)) if zx and zy else math.nan
        # the elliptical target's phase is in the spec, not the step: shown without a band
        phase_target = {"circular_forward": -90.0, "circular_backward": 90.0}.get(motion)
    else:
        z, f = disp[axis], force[axis]
        phase = math.degrees(np.angle(z / f)) if z and f else math.nan
    achieved = abs(ref) * scale if ref is not None else math.nan
    drives = [abs(v) for v in step.drive_v.values()]
    # the direct dynamic stiffness F/X of each axis [MN/m] (1X; for two-axis orbits it holds
    # the cross-coupled terms too): what the rig looks like across the sweep
    k: dict[str, complex | None] = {}
    for a in ("x", "y"):
        fa, za = force[a], disp[a]
        k[a] = fa / za / 1e6 if fa and za else None
    return {
        "index": step.index,
        "freq_hz": step.freq_hz,
        "motion": motion,
        "unit": "N" if load else "um",
        "target": target,
        "achieved": achieved,
        "error_pct": 100.0 * (achieved - target) / target if target else math.nan,
        "band_pct": tolerance_amplitude_pct,
        "phase_deg": phase,
        "phase_label": f"{other.upper()} rel. {axis.upper()}" if motion in TWO_AXIS
        else f"{axis} rel. f{axis}",
        "phase_target_deg": phase_target,
        "phase_band_deg": tolerance_phase_deg if phase_target is not None else None,
        "x_um": abs(disp["x"]) / UM if disp["x"] is not None else math.nan,
        "y_um": abs(disp["y"]) / UM if disp["y"] is not None else math.nan,
        "fx_n": abs(force["x"]) if force["x"] is not None else math.nan,
        "fy_n": abs(force["y"]) if force["y"] is not None else math.nan,
        "drive_v": max(drives) if drives else math.nan,
        "kx_re_mn_per_m": k["x"].real if k["x"] is not None else math.nan,
        "kx_im_mn_per_m": k["x"].imag if k["x"] is not None else math.nan,
        "ky_re_mn_per_m": k["y"].real if k["y"] is not None else math.nan,
        "ky_im_mn_per_m": k["y"].imag if k["y"] is not None else math.nan,
        "updates": step.updates,
        "converged": step.converged,
        "reason": step.reason,
    }


def upward_crossings(v: np.ndarray) -> np.ndarray:
    """Indices i where ``v`` goes from < 0 at i - 1 to >= 0 at i."""
    return np.flatnonzero((v[:-1] < 0) & (v[1:] >= 0)) + 1


def rounded(row: np.ndarray, digits: int = 5) -> list[float]:
    """``row`` to ``digits`` significant digits of its largest value (a short JSON text);
    non-finite samples become 0 (JSON has no NaN)."""
    row = np.nan_to_num(row, nan=0.0, posinf=0.0, neginf=0.0)
    peak = float(np.abs(row).max()) if row.size else 0.0
    decimals = digits - 1 - math.floor(math.log10(peak)) if peak > 0 else 0
    return np.round(row, decimals).tolist()


def finite(x: float) -> float | None:
    """JSON has no NaN: None instead."""
    return float(x) if math.isfinite(x) else None


class LiveView:
    """The page's state, fed from a subscriber thread and read from the web server's loop.

    Parameters
    ----------
    buffer_s : float
        Seconds of samples kept for the traces (enough for ``cycles`` at the lowest frequency).
    cycles : int
        Drive cycles shown in traces and orbit.
    points : int
        Most points per trace sent to the browser (the server decimates to this).
    max_events : int
        Events kept for the page.
    """

    def __init__(self, buffer_s: float = 1.0, cycles: int = 3, points: int = 600,
                 max_events: int = 200) -> None:
        self.buffer_s = buffer_s
        self.cycles = cycles
        self.points = points
        self._lock = threading.Lock()
        self._buf: np.ndarray | None = None
        self._write = 0  # samples written into the ring (total)
        self._channels: list[str] = []
        self._n_ai = 0
        self._fs = 0.0
        self._last_sample = -1  # run sample index of the newest sample
        self._t_acquired = 0.0  # daemon's time.time() of the newest block
        self._block_seq = -1
        self.status: Heartbeat | None = None  # the latest heartbeat (None before the first)
        self.steps: list[dict[str, Any]] = []
        self._step_times: list[float] = []
        self._run_started: float | None = None
        self.events: deque[dict[str, Any]] = deque(maxlen=max_events)
        self.run_id = ""
        self.tolerance = (1.0, 1.0)
        self.lost: dict[str, int] = {}
        self._lockin: LockIn | None = None
        # this run's peak orbit radius and load, seen live, and its first contact (issue 21)
        self._peak_m = 0.0
        self._peak_n = 0.0
        self._contact = ""
        # the link to the daemon (`web.feed.DaemonLink` says how it is) and the last heartbeat
        self._link: Link = {"state": "connecting", "message": ""}
        self._heartbeat_at: float | None = None
        self._malformed = 0
        self._malformed_last = ""

    # --- fed from the subscriber thread ----------------------------------------------------
    def on_message(self, msg: Message) -> None:
        with self._lock:
            h = msg.header
            if h.get("run_id") and h["run_id"] != self.run_id:
                self._new_run(h["run_id"])
            if msg.topic == "block" and msg.array is not None:
                self._on_block(BlockHeader.from_wire(h), int(h["seq"]), msg.array)
            elif msg.topic == "step":
                # JSON-safe once, not per frame
                point = step_point(StepRecord.from_wire(h["step"]), *self.tolerance)
                self.steps.append({k: finite(v) if isinstance(v, float) else v
                                   for k, v in point.items()})
                self._step_times.append(msg.received_at)
            elif msg.topic == "event":
                ev = EventRecord.from_wire(h)
                self.events.append({"time": h.get("time", msg.received_at), "kind": ev.kind,
                                    "message": ev.message, "run_id": h.get("run_id", "")})
                if (ev.kind in ("fault", "limit_trip") and ev.message.startswith(CONTACT)
                        and not self._contact):
                    self._contact = ev.message
            elif msg.topic == "status":
                self._on_status(msg.heartbeat(), msg.received_at)
                self._heartbeat_at = msg.received_at

    def note_heartbeat(self, now: float | None = None) -> None:
        """A heartbeat seen elsewhere (the subscription's first, which proves it live)."""
        with self._lock:
            self._heartbeat_at = time.time() if now is None else now

    def heartbeat_age(self, now: float | None = None) -> float | None:
        """Seconds since the daemon's last heartbeat on the stream (None: none yet)."""
        with self._lock:
            if self._heartbeat_at is None:
                return None
            return (time.time() if now is None else now) - self._heartbeat_at

    def set_link(self, link: Link) -> None:
        """How the link to the daemon is (`web.feed.DaemonLink`)."""
        with self._lock:
            self._link = link.copy()

    def note_malformed(self, count: int, what: str) -> None:
        """A message the feed could not use (skipped): counted and shown."""
        with self._lock:
            self._malformed = count
            self._malformed_last = what[:300]

    def set_status(self, status: Heartbeat, now: float | None = None) -> None:
        """A status reply (late join) or heartbeat."""
        with self._lock:
            if status["run_id"] and status["run_id"] != self.run_id:
                self._new_run(status["run_id"])
            self._on_status(status, time.time() if now is None else now)

    def set_lost(self, lost: dict[str, int]) -> None:
        with self._lock:
            self.lost = dict(lost)

    def _new_run(self, run_id: str) -> None:
        self.run_id = run_id
        self.steps = []
        self._step_times = []
        self._run_started = None
        self._write = 0
        self._last_sample = -1
        self._peak_m = self._peak_n = 0.0
        self._contact = ""

    def _on_status(self, status: Heartbeat, now: float) -> None:
        self.status = status
        tol = status["tolerance"]
        if tol:
            self.tolerance = (tol["amplitude_pct"], tol["phase_deg"])
        if status["run_id"] and self._run_started is None:
            self._run_started = now

    def _on_block(self, h: BlockHeader, seq: int, block: np.ndarray) -> None:
        rows, n = block.shape
        fs = h.sample_rate_hz
        if self._buf is None or self._buf.shape[0] != rows or fs != self._fs:
            size = max(int(self.buffer_s * fs), n)
            self._buf = np.zeros((rows, size))
            self._channels = list(h.channels)
            self._n_ai = h.n_ai
            self._fs = fs
            self._write = 0
            # a frame's window (whole cycles between two crossings) is a new n as the sweep
            # moves on: keep the current step's few windows only; 32 of them at low frequency
            # held about 26 MB, the web process's slow growth over a long sweep
            self._lockin = LockIn(fs, cache_size=4)
        first = h.first_sample
        if first != self._last_sample + 1:
            self._write = 0  # a lost block or a new run: traces start afresh
        size = self._buf.shape[1]
        if n >= size:
            self._buf[:] = block[:, n - size:]
            self._write = size
        else:
            i = self._write % size
            k = min(n, size - i)
            self._buf[:, i:i + k] = block[:, :k]
            self._buf[:, :n - k] = block[:, k:]
            self._write += n
        self._last_sample = first + n - 1
        self._t_acquired = h.t_acquired
        self._block_seq = seq
        self._note_peaks(block)

    def _note_peaks(self, block: np.ndarray) -> None:
        """The run's largest orbit radius (mean of each axis's probes) and load, live."""
        rows = {name: block[i] for i, name in enumerate(self._channels[: self._n_ai])}
        x = self._mean_rows(rows, ("x1", "x2"), "x")
        y = self._mean_rows(rows, ("y1", "y2"), "y")
        if x is not None and y is not None:
            self._peak_m = max(self._peak_m, float(np.max(np.hypot(x, y))))
        loads = [np.abs(rows[f]).max() for f in ("fx", "fy") if f in rows]
        if loads:
            self._peak_n = max(self._peak_n, float(max(loads)))

    def _peaks(self, status: Heartbeat | None) -> dict[str, Any] | None:
        """The run's peaks for the page: the daemon's summary once the run has ended (every
        block counted), else what this view has seen so far (blocks may be dropped)."""
        last = status["last_run"] if status is not None else {}
        summary = last.get("summary")
        if (status is not None and not status["run_id"] and summary
                and last.get("run_id") == self.run_id):
            return {"run_id": self.run_id, "final": True, "text": peak_line(summary),
                    "peak_displacement_m": finite(summary["peak_displacement_m"]),
                    "peak_load_n": finite(summary["peak_load_n"]),
                    "contact": summary.get("contact") or "",
                    "tripped": bool(summary.get("tripped_at"))}
        if not self.run_id or self._last_sample < 0:
            return None
        limit = status["safety"]["displacement_limit_m"] if status is not None else None
        text = f"peak orbit {self._peak_m / UM:.1f} um" + (
            f" of the {limit / UM:.4g} um limit" if limit else "") + (
            f", peak load {self._peak_n:.1f} N; ") + (self._contact or f"no {CONTACT}")
        return {"run_id": self.run_id, "final": False, "text": text,
                "peak_displacement_m": finite(self._peak_m), "peak_load_n": finite(self._peak_n),
                "contact": self._contact, "tripped": False}

    def _span(self, lo: int, hi: int, rows: slice = slice(None)) -> np.ndarray:
        """Buffered samples ``lo:hi`` (0 = the oldest kept) of ``rows``, in time order: a view
        when they lie in one piece of the ring, else a copy of just that span."""
        assert self._buf is not None
        size = self._buf.shape[1]
        p0 = (self._write - min(self._write, size) + lo) % size
        length = hi - lo
        if p0 + length <= size:
            return self._buf[rows, p0:p0 + length]
        return np.concatenate([self._buf[rows, p0:], self._buf[rows, :p0 + length - size]], axis=1)

    # --- read from the web server's loop ---------------------------------------------------
    def frame(self, now: float | None = None) -> dict[str, Any]:
        """Everything the page draws, JSON-safe, decimated."""
        now = time.time() if now is None else now
        with self._lock:
            traces = self._traces() if self._buf is not None and self._write else None
            status = self.status
            link = self._link_now(now)
            return {
                "type": "frame",
                "server_time": now,
                "t_acquired": self._t_acquired,
                "block_seq": self._block_seq,
                "link": link,
                "status": dict(status) if status is not None else {},
                "time_left_s": self._time_left(status, now)
                if link["state"] in ("live", "late") else None,
                "peaks": self._peaks(status),
                "traces": traces,
                "steps": list(self.steps),
                "events": list(self.events)[-50:],
                "lost": dict(self.lost),
            }

    def _link_now(self, now: float) -> dict[str, Any]:
        """The link for the page: its state and message, the heartbeat's and the data's age,
        whether the traces are stale (no block for `STALE_AFTER_S`, or the link not live)."""
        hb = None if self._heartbeat_at is None else max(0.0, now - self._heartbeat_at)
        data_at = self._t_acquired if self._t_acquired > 0 else None
        data_age = None if data_at is None else max(0.0, now - data_at)
        live = self._link["state"] in ("live", "late")
        return {**self._link, "heartbeat_age_s": hb, "data_age_s": data_age,
                "last_data_time": data_at,
                "stale": not live or data_age is None or data_age > STALE_AFTER_S,
                "malformed": self._malformed, "malformed_last": self._malformed_last}

    def _time_left(self, status: Heartbeat | None, now: float) -> float | None:
        """Remaining steps times the mean duration of the finished ones (None before the first)."""
        if status is None or not status["run_id"]:
            return None
        total, done = status["progress"].get("steps_total"), len(self.steps)
        if not isinstance(total, int) or not total or not done or self._run_started is None:
            return None
        per_step = (self._step_times[-1] - self._run_started) / done
        return max(0.0, per_step * (total - done) - (now - self._step_times[-1]))

    def _traces(self) -> dict[str, Any]:
        """Per frame, whatever the number of browsers: the trigger search reads the drive rows
        only, and only the shown window of all rows is read (never a copy of the whole ring)."""
        assert self._buf is not None
        m = min(self._write, self._buf.shape[1])
        fs = self._fs
        names = self._channels
        drives = names[self._n_ai:]
        progress_freq = self.status["progress"].get("freq_hz") if self.status else None
        freq = float(progress_freq) if isinstance(progress_freq, int | float) else 0.0
        # trigger on the first drive that moves: `cycles` drive periods starting at an upward
        # crossing, so the picture stands still
        start, stop, triggered = max(0, m - int(0.1 * fs)), m, False
        drive_rows = self._span(0, m, slice(self._n_ai, None))
        for v in drive_rows:
            if np.ptp(v) <= 1e-6:
                continue
            up = upward_crossings(v)
            if len(up) > self.cycles:
                start, stop, triggered = int(up[-1 - self.cycles]), int(up[-1]), True
                freq = self.cycles * fs / (stop - start)
            break
        window = self._span(start, stop)
        n = window.shape[1]
        step = max(1, math.ceil(n / self.points))
        dec = window[:, ::step]
        t_ms = (np.arange(dec.shape[1]) * step / fs * 1e3).round(3)
        rows = {name: dec[i] for i, name in enumerate(names)}
        units = self.status["units"] if self.status is not None else {}
        drawn = [n for n in names if n in drives or units.get(n, "N") in TRACE_UNITS]
        ai_means = window[: self._n_ai].mean(axis=1) if n else np.full(self._n_ai, math.nan)
        means = {name: finite(float(v)) for name, v in zip(names[: self._n_ai], ai_means,
                                                            strict=True)}
        levels = self._levels(window[: self._n_ai], ai_means) if n else {}
        x = self._mean_rows(rows, ("x1", "x2"), "x")
        y = self._mean_rows(rows, ("y1", "y2"), "y")
        harmonics: dict[str, list[float]] = {}
        if triggered and self._lockin is not None and n > 11:
            harm, _ = self._lockin.demodulate(window[: self._n_ai], 0, freq)
            harmonics = {names[i]: np.abs(harm[i]).tolist() for i in range(self._n_ai)}
        return {
            "t_ms": t_ms.tolist(),
            "channels": {name: rounded(rows[name]) for name in drawn},
            "means": means,
            "drives": drives,
            "orbit_x_um": rounded(x / UM) if x is not None else [],
            "orbit_y_um": rounded(y / UM) if y is not None else [],
            "triggered": triggered,
            "freq_hz": finite(freq),
            "decimation": step,
            "harmonics": harmonics,
            "levels": levels,
            "last_sample": self._last_sample,
        }

    def _levels(self, ai: np.ndarray, means: np.ndarray) -> dict[str, dict[str, float | None]]:
        """Per input over the shown window: RMS about the mean, peak |value| and how much of
        the input range the samples reach [%] (from the range's middle to the nearer end;
        100 % is the ADC's limit), when the status gives the range."""
        ranges = self.status["input_ranges"] if self.status is not None else {}
        rms = np.sqrt(np.mean((ai - means[:, None]) ** 2, axis=1))
        lo_v, hi_v = ai.min(axis=1), ai.max(axis=1)
        out: dict[str, dict[str, float | None]] = {}
        for i, name in enumerate(self._channels[: self._n_ai]):
            used = None
            r = ranges.get(name)
            if isinstance(r, list) and len(r) == 2 and r[1] > r[0]:
                mid, half = 0.5 * (r[0] + r[1]), 0.5 * (r[1] - r[0])
                used = 100.0 * max(hi_v[i] - mid, mid - lo_v[i]) / half
            out[name] = {"rms": finite(float(rms[i])),
                         "peak": finite(float(max(abs(lo_v[i]), abs(hi_v[i])))),
                         "range_pct": finite(used) if used is not None else None}
        return out

    @staticmethod
    def _mean_rows(rows: dict[str, np.ndarray], pair: tuple[str, str],
                   single: str) -> np.ndarray | None:
        if all(p in rows for p in pair):
            return 0.5 * (rows[pair[0]] + rows[pair[1]])
        return rows.get(single)
