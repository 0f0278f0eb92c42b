"""`sfdrig sweep`: start a sweep on the daemon, then follow it on the live stream.

Plain text that works without a TTY: a line per progress change (step bar and whole-sweep bar,
frequency, controller updates), and a line per finished step with the achieved amplitudes. On a
TTY the progress line is redrawn in place. Ctrl-C while following aborts the sweep (the daemon
ramps the drives to zero and closes the run file as aborted); ``--no-follow`` only starts it.

A sweep is a batch job: losing its follower does not stop it. The terminal hanging up (SIGHUP),
SIGTERM or SIGKILL end the following only; the sweep runs to its plan under the daemon's own
safety limits (trips, the board's watchdog) and ends with the drives ramped to zero, as a sweep
started with ``--no-follow`` does. Ctrl-C is a person at the terminal asking to stop: that
aborts. (A structure test is the other case: it holds a load for a person, so losing its
terminal aborts it; `sfdrig.commands.structure`.)
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from control.wire.client import CommandClient, CommandRefused, DaemonUnavailable, Subscriber
from control.wire.heartbeat import RunSummary
from control.wire.summary_lines import end_line, lateness_line, peak_line
from sfdrig.commands._client_args import (
    add_connection_arguments,
    command_client,
    not_done,
    subscriber,
)
from sfdrig.commands._lost import (
    ClientLost,
    hold_further_signals,
    raising_when_lost,
    silence_hung_up_terminal,
)
from storage.records import StepRecord

NAME = "sweep"
HELP = "start a sweep (sweep file and/or KEY=VALUE fields) and follow it live"

UM = 1e-6


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sweep_file", nargs="?", type=Path, help="sweep TOML file")
    parser.add_argument("--set", dest="fields", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="a sweep field given inline, VALUE in TOML syntax "
                             "(e.g. --set 'freq_hz=[20, 40]'); overrides the file")
    parser.add_argument("--operator", default="", help="recorded in the run file")
    parser.add_argument("--notes", default="", help="recorded in the run file")
    parser.add_argument("--no-follow", action="store_true",
                        help="start the sweep and return without following it")
    parser.add_argument("--check", action="store_true",
                        help="check the sweep (file and --set fields) offline, no daemon, as "
                             "the daemon's start would: one line per problem; exit 0 valid, "
                             "2 invalid")
    parser.add_argument("--channels", type=Path, metavar="CHANNELS.toml",
                        help="with --check: the channel map the daemon runs with (default: "
                             "the daemon's default map)")
    parser.epilog = ("Ctrl-C while following aborts the sweep: the daemon ramps the drives to "
                     "zero and closes the run file as aborted (the steps so far are kept); "
                     "with --no-follow, stop it with `sfdrig abort`; `sfdrig pause` and "
                     "`sfdrig resume` hold it at zero drive and go on. A hung-up terminal "
                     "(SIGHUP) or a killed `sfdrig sweep` stops only the following: the sweep "
                     "runs to its plan under the daemon's safety limits.")
    add_connection_arguments(parser, data=True)


#: Fields that are alternatives: an override of one side replaces the file's other side (the
#: frequencies as a list or as a range, a range by step or by points, the target's kind).
ALTERNATIVES = (
    ({"freq_hz"}, {"freq_start_hz", "freq_stop_hz", "freq_step_hz", "freq_points", "spacing"}),
    ({"freq_step_hz"}, {"freq_points", "spacing"}),
    ({"amplitude_m"}, {"load_n"}),
)


def sweep_fields(path: Path | None, assignments: list[str], who: str = "sweep",
                 required: bool = True) -> dict[str, Any]:
    """The sweep spec dict from a TOML file plus ``KEY=VALUE`` overrides (dotted keys nest);
    an override of the frequencies or of the target replaces whichever form the file used."""
    spec: dict[str, Any] = {}
    if path is not None:
        try:
            spec = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError) as err:
            raise SystemExit(f"{who}: cannot read {path}: {err}") from None
    overridden = {a.partition("=")[0].strip() for a in assignments}
    for one, other in ALTERNATIVES:
        for mine, theirs in ((one, other), (other, one)):
            if overridden & mine and not overridden & theirs:
                for key in theirs:
                    spec.pop(key, None)
    for a in assignments:
        key, sep, value = a.partition("=")
        if not sep or not key.strip():
            raise SystemExit(f"{who}: --set {a!r} is not KEY=VALUE")
        try:
            parsed = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            parsed = value  # a bare word is a string
        node = spec
        *parents, leaf = key.strip().split(".")
        for p in parents:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise SystemExit(f"{who}: --set {a!r}: {p!r} is not a table")
        node[leaf] = parsed
    if required and not spec:
        raise SystemExit("sweep: give a sweep file or --set fields")
    return spec


# --- formatting shared with `watch` and `demo` ----------------------------------------------
def amplitude(harmonics: Mapping[str, tuple[complex, ...]], *names: str) -> float:
    """|1X| of the complex mean of the named channels (NaN if none is present)."""
    zs = [harmonics[n][0] for n in names if n in harmonics]
    return abs(sum(zs) / len(zs)) if zs else float("nan")


def achieved(step: StepRecord) -> dict[str, float]:
    """Achieved 1X amplitudes of a step: x, y [m] (mean of the probes), fx, fy [N]."""
    h = step.harmonics
    return {
        "x_m": amplitude(h, "x1", "x2") if "x1" in h else amplitude(h, "x"),
        "y_m": amplitude(h, "y1", "y2") if "y1" in h else amplitude(h, "y"),
        "fx_n": amplitude(h, "fx"),
        "fy_n": amplitude(h, "fy"),
    }


def step_line(step: StepRecord, total: int | None = None) -> str:
    a = achieved(step)
    unit = "um" if step.target_kind == "displacement" else "N"
    target = step.target_value / UM if unit == "um" else step.target_value
    of = f"/{total}" if total else ""
    verdict = "converged" if step.converged else f"NOT converged: {step.reason or '?'}"
    return (f"step {step.index + 1}{of}  {step.freq_hz:6.1f} Hz  "
            f"{step.motion} target {target:.3g} {unit}  achieved x {a['x_m'] / UM:6.2f}"
            f" um  y {a['y_m'] / UM:6.2f} um  fx {a['fx_n']:6.1f} N  fy {a['fy_n']:6.1f} N  "
            f"{step.updates} updates, {verdict}")


def bar(fraction: float, width: int = 20) -> str:
    f = min(max(fraction, 0.0), 1.0) if np.isfinite(fraction) else 0.0
    n = int(round(f * width))
    return "[" + "#" * n + "." * (width - n) + "]"


def progress_line(progress: dict[str, Any]) -> str:
    """Whole-sweep bar (steps done), step bar (controller updates used), frequency, state."""
    total = int(progress.get("steps_total") or 0)
    done = int(progress.get("steps_done") or 0)
    index = int(progress.get("step_index", -1))
    updates = int(progress.get("updates") or 0)
    max_updates = progress.get("max_updates")
    sweep_frac = done / total if total else float("nan")
    line = f"sweep {bar(sweep_frac)} {done}/{total or '?'} steps done"
    if index >= 0:
        line += f" | step {index + 1}: {float(progress.get('freq_hz', 0.0)):6.1f} Hz"
        if max_updates:
            line += f" updates {bar(updates / max_updates, 8)} {updates}/{max_updates}"
        else:
            line += f" updates {updates}"
    return line + f" | {progress.get('state', '')}"


def progress_text(progress: dict[str, Any]) -> str:
    """A run's progress for people: a sweep's as `progress_line` (steps counted from 1), any
    other run's (a structure test's) as its fields."""
    if "step_index" in progress:
        return progress_line(progress)
    return "  ".join(f"{k}={v}" for k, v in progress.items())


def _fmt(v: object) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def follow(sub: Subscriber, run_id: str, out: TextIO = sys.stdout, idle_timeout_s: float = 30.0,
           total: int | None = None, steps: list[StepRecord] | None = None,
           ) -> tuple[str, str, list[StepRecord]]:
    """Print progress and step results of ``run_id`` until it ends.

    ``steps`` collects the steps as they come (pass the same list again to go on after an
    interruption: the steps before it still count).

    Returns
    -------
    (status, reason, steps)
        How the run ended ("completed", "aborted", "failed") and its step dicts.
    """
    tty = out.isatty() if hasattr(out, "isatty") else False
    steps = [] if steps is None else steps
    last_progress = ""
    last_msg = time.monotonic()
    while True:
        msg = sub.recv(timeout_s=1.0)
        if msg is None:
            if time.monotonic() - last_msg > idle_timeout_s:
                raise DaemonUnavailable(f"no live data for {idle_timeout_s:g} s")
            continue
        last_msg = time.monotonic()
        h = msg.header
        if msg.topic == "status":
            st = h["status"]
            last = st.get("last_run") or {}
            if st["run_id"] != run_id and last.get("run_id") == run_id:
                return last["status"], last.get("reason", ""), steps
            if st["run_id"] == run_id and st.get("progress"):
                total = st["progress"].get("steps_total") or total
                line = progress_line(st["progress"])
                if line != last_progress:
                    last_progress = line
                    print(("\r" + line + "\x1b[K") if tty else line, end="" if tty else "\n",
                          file=out, flush=True)
        elif msg.topic == "step" and h["run_id"] == run_id:
            step = StepRecord.from_wire(h["step"])
            steps.append(step)
            print(("\r\x1b[K" if tty else "") + step_line(step, total), file=out, flush=True)
        elif msg.topic == "event" and h["run_id"] in (run_id, ""):
            if h["kind"] in ("limit_trip", "fault", "abort", "error", "warning", "pump",
                             "operator"):
                print(("\r\x1b[K" if tty else "") + f"{h['kind']}: {h['message']}", file=out,
                      flush=True)
            prefix = f"run {run_id} "
            if h["kind"] == "state" and h["message"].startswith(prefix):
                status, _, reason = h["message"][len(prefix):].partition(": ")
                return status, reason, steps


def run_summary(client: CommandClient, run_id: str) -> RunSummary | None:
    """The ended run's summary from the daemon's status (peaks, contact, trip), or None."""
    try:
        last = client.status()["last_run"]
    except (CommandRefused, DaemonUnavailable):
        return None
    summary = last.get("summary") if last.get("run_id") == run_id else None
    return summary or None


def _located(problems: list[str], args: argparse.Namespace) -> list[str]:
    """Each problem led by where its field came from: ``--set`` or the sweep file."""
    overridden = {a.partition("=")[0].strip().split(".")[0] for a in args.fields}
    file = str(args.sweep_file) if args.sweep_file is not None else "--set"
    return [("--set" if line.partition(" = ")[0].split(".")[0] in overridden else file)
            + f": {line}" for line in problems]


def _check(args: argparse.Namespace, spec: dict[str, Any]) -> int:
    """`--check`: the sweep checked offline (`sfdrig.sweep_check`)."""
    from daq.errors import ChannelConfigError
    from sfdrig.sweep_check import limits_line, sweep_problems

    try:
        model, problems = sweep_problems(spec, args.channels)
    except ChannelConfigError as err:
        print(f"sweep: {err}", file=sys.stderr)
        return 2
    for line in _located(problems, args):
        print(line)
    if problems:
        return 2
    assert model is not None
    freqs = model.frequencies()
    unit, scale = ("um", 1e6) if model.target_kind == "displacement" else ("N", 1.0)
    where = args.sweep_file if args.sweep_file is not None else "--set"
    print(f"{where}: valid: {len(model.steps())} steps, {model.motion}, {model.target_kind} "
          f"{', '.join(f'{v * scale:g}' for v in model.targets)} {unit} at {len(freqs)} "
          f"frequencies {min(freqs):g}-{max(freqs):g} Hz; checked against {limits_line()} and "
          + (f"the channel map {args.channels}" if args.channels else "the default channel map"))
    return 0


def run(args: argparse.Namespace) -> int:
    spec = sweep_fields(args.sweep_file, args.fields)
    if args.check:
        return _check(args, spec)
    run_id = ""
    try:
        with raising_when_lost(), command_client(args) as client:
            if args.no_follow:
                reply = client.start_sweep(spec, args.operator, args.notes)
                print(f"run {reply.data['run_id']} started: {reply.data['path']}")
                return 0
            with subscriber(args, topics=["step", "event", "status"]) as sub:
                sub.wait_connected(timeout_s=args.timeout)
                reply = client.start_sweep(spec, args.operator, args.notes)
                run_id = reply.data["run_id"]
                print(f"run {run_id} started: {reply.data['path']}", flush=True)
                steps: list[StepRecord] = []  # those before a Ctrl-C count too
                try:
                    status, reason, steps = follow(sub, run_id, steps=steps,
                                                   total=reply.data.get("steps_total"))
                except KeyboardInterrupt:
                    # The operator stopped watching a sweep they started: stop the sweep too.
                    client.abort("operator pressed Ctrl-C in `sfdrig sweep`")
                    print(f"\nrun {run_id}: abort sent (drives ramp to zero)", flush=True)
                    status, reason, steps = follow(sub, run_id, steps=steps)
                summary = run_summary(client, run_id)
    except (CommandRefused, DaemonUnavailable) as err:
        print(f"sweep: {not_done(err)}")
        return 1
    except ClientLost as lost:
        # the sweep is not aborted: it runs to its plan under the daemon's safety limits
        hold_further_signals()
        if lost.hung_up:
            silence_hung_up_terminal()
        elif run_id:
            with contextlib.suppress(OSError):
                print(f"\nrun {run_id}: no longer followed ({lost.how}); the sweep runs on "
                      "to its end (`sfdrig status` shows it, `sfdrig abort` stops it)",
                      flush=True)
        return lost.exit_code
    if summary is not None:
        print(peak_line(summary))
        if late := lateness_line(summary):
            print(late)
    # the last line: how it ended; after a trip what tripped, where, the peak, what to do
    print(end_line(run_id, status, reason, len(steps), summary))
    return 0 if status == "completed" else 1
