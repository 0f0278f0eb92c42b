"""`sfdrig watch`: live per-channel amplitudes and the current step.

From the daemon's live stream (default), or from a run file being written (``--file RUN.h5``,
read live through HDF5 SWMR: works on any host that sees the file, with no daemon connection).
Amplitude here is half the peak-to-peak over the last ``--window`` seconds, in display units
(um for displacement, N, m/s^2, kPa, L/min, degC).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

from control.wire.client import DaemonUnavailable
from sfdrig.commands._client_args import add_connection_arguments, subscriber
from sfdrig.commands.sweep import progress_text, step_line
from storage.records import BlockHeader, StepRecord

NAME = "watch"
HELP = "show live per-channel amplitudes and the current step (or follow a run file)"

# display scale per engineering unit: (factor, shown unit)
_DISPLAY = {"m": (1e6, "um"), "Pa": (1e-3, "kPa")}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--file", type=Path, metavar="RUN.h5",
                        help="follow a run file live (SWMR) instead of the daemon's stream")
    parser.add_argument("--interval", type=float, default=1.0,
                        help="seconds between tables (default: %(default)s)")
    parser.add_argument("--window", type=float, default=1.0,
                        help="seconds of data per amplitude (default: %(default)s)")
    parser.add_argument("--count", type=int, default=0,
                        help="stop after this many tables (default: until Ctrl-C or run end)")
    add_connection_arguments(parser, data=True)


def table(names: list[str], data: np.ndarray, units: dict[str, str], header: str) -> str:
    """One text table: channel, half peak-to-peak amplitude and mean, display units."""
    lines = [header, f"  {'channel':<10}{'amplitude':>12}{'mean':>12}  unit"]
    for i, name in enumerate(names):
        row = data[i]
        if row.size == 0:
            continue
        factor, unit = _DISPLAY.get(units.get(name, ""), (1.0, units.get(name, "")))
        amp = 0.5 * (row.max() - row.min()) * factor
        lines.append(f"  {name:<10}{amp:12.4g}{row.mean() * factor:12.4g}  {unit}")
    return "\n".join(lines)


def _watch_stream(args: argparse.Namespace) -> int:
    with subscriber(args, topics=["block", "step", "status"]) as sub:
        st = sub.wait_connected(timeout_s=args.timeout)
        blocks: deque[np.ndarray] = deque()
        names: list[str] = []
        fs = st["sample_rate_hz"]
        shown, next_table, malformed = 0, time.monotonic() + args.interval, 0
        while args.count == 0 or shown < args.count:
            try:
                msg = sub.recv(timeout_s=args.interval)
                if msg is not None:
                    if msg.topic == "block" and msg.array is not None:
                        new_names = list(BlockHeader.from_wire(msg.header).channels)
                        if len(new_names) != msg.array.shape[0]:
                            raise ValueError(f"{len(new_names)} channel names for "
                                             f"{msg.array.shape[0]} rows")
                        if new_names != names:
                            blocks.clear()
                        names = new_names
                        blocks.append(msg.array)
                        while sum(b.shape[1] for b in blocks) - blocks[0].shape[1] >= \
                                args.window * fs:
                            blocks.popleft()
                    elif msg.topic == "status":
                        st = msg.heartbeat()
                    elif msg.topic == "step":
                        print(step_line(StepRecord.from_wire(msg.header["step"])), flush=True)
            except (ValueError, KeyError, TypeError, AttributeError) as err:
                # a message this watch cannot use (another sender, a damaged frame): skipped
                # and counted, never the end of the watch
                malformed += 1
                if malformed == 1 or malformed % 1000 == 0:
                    print(f"watch: skipped a malformed message ({type(err).__name__}: {err}); "
                          f"{malformed} so far", file=sys.stderr, flush=True)
            if time.monotonic() < next_table:
                continue
            next_table += args.interval
            shown += 1
            lost = sum(sub.lost.values())
            head = (f"state {st['state']}  run {st['run_id'] or '-'}  "
                    + progress_text(st["progress"])
                    + (f"  lost {lost} messages" if lost else "")
                    + (f"  skipped {malformed} malformed" if malformed else ""))
            if blocks:
                print(table(names, np.concatenate(list(blocks), axis=1), st["units"], head),
                      flush=True)
            else:
                print(head + "\n  (no samples: no run in progress)", flush=True)
    return 0


def _watch_file(args: argparse.Namespace) -> int:
    from storage.reader import open_run

    run = open_run(args.file)
    try:
        units = {n: run.units(n) for n in run.channel_names + run.drive_names}
        names = run.channel_names + run.drive_names
        fs, shown, n_steps, idle_since = run.sample_rate_hz, 0, 0, time.monotonic()
        last_n = -1
        while args.count == 0 or shown < args.count:
            run.refresh()
            n = run.n_samples
            steps = run.step_records
            for s in steps[n_steps:]:
                print(step_line(s), flush=True)
            n_steps = len(steps)
            start = max(0, n - int(args.window * fs))
            data = np.stack([run.channel(c, start, n) for c in names]) if n else \
                np.empty((len(names), 0))
            print(table(names, data, units, f"{args.file.name}  {n / fs:.1f} s recorded, "
                                             f"{n_steps} steps"), flush=True)
            shown += 1
            if n != last_n:
                last_n, idle_since = n, time.monotonic()
            elif time.monotonic() - idle_since > max(3.0, 3 * args.interval):
                run.close()  # the final status is written once SWMR ends: look again
                run = open_run(args.file)
                if run.status != "running":
                    print(f"run {run.status}" + (f": {run.attrs.get('status_reason')}"
                                                 if run.attrs.get("status_reason") else ""))
                    return 0
            time.sleep(args.interval)  # pacing the display, not synchronisation
    finally:
        run.close()
    return 0


def run(args: argparse.Namespace) -> int:
    try:
        return _watch_file(args) if args.file else _watch_stream(args)
    except DaemonUnavailable as err:
        print(f"watch: {err}", file=sys.stderr)
        return 1
