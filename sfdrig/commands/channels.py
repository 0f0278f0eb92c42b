"""`sfdrig channels write|check|live|calibrate`: a channel map as TOML, checked against the
connected device, its inputs read live (nothing is driven), and calibration results written
back into it (a diff, then the operator's confirmation)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from daq.channels import ChannelMap
    from daq.device_check import LiveValues
    from daq.nidaqmx_session import NidaqmxSession

NAME = "channels"
HELP = ("the channel map: write the default as TOML, check a map against the connected device "
        "(channels, ranges, terminal configurations, nothing wired twice), show live values, "
        "write calibration results into it")

#: how an engineering unit is shown: (shown unit, factor from the map's unit)
_SHOWN = {"m": ("um", 1e6), "Pa": ("kPa", 1e-3)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    w = sub.add_parser("write", help="write the default channel map (the report's rig) as TOML",
                       description="Write the default channel map (the report's rig on Dev1), "
                                   "or the map of --from with every field spelled out, as TOML.")
    w.add_argument("out", nargs="?", metavar="OUT.toml",
                   help="file to write (default: standard output); an existing file is kept "
                        "unless --force")
    w.add_argument("--from", dest="source", metavar="MAP.toml",
                   help="a channel map to write out in full instead of the default "
                        "(e.g. examples/channels_report_rig.toml)")
    w.add_argument("--force", action="store_true", help="overwrite OUT.toml")
    for name, text in (("check", "check MAP.toml against the connected device: its channels "
                                 "exist, ranges and terminal configurations allowed, nothing "
                                 "wired twice (exit 0: fits, 1: problems, 2: unusable input)"),
                       ("live", "show each input of MAP.toml live, in engineering units, a few "
                                "times a second (Ctrl-C ends); nothing is driven")):
        p = sub.add_parser(name, help=text, description=text)
        p.add_argument("map", metavar="MAP.toml", help="the channel map")
        p.add_argument("--grpc-target", metavar="HOST:PORT",
                       help="an NI gRPC Device Server (e.g. `sfdrig sim-server`); default: the "
                            "map's grpc_target, else the local NI-DAQmx driver")
        p.add_argument("--connect-timeout-s", type=float, default=5.0,
                       help="how long to wait for a gRPC server [s] (default: %(default)s)")
    cal = sub.add_parser(
        "calibrate", help="write probe-calibration and static-test results into a map",
        description="Propose the corrections RUN.h5 (a probe_calibration or static run) gives "
                    "MAP.toml: probe gains (Table A1), the drives' N/V from a static test by "
                    "the shakers; dial- and force-gauge entries inconsistent with what the "
                    "probes read are questioned and left out. Shows the diff, then asks before "
                    "writing (exit 0: written or nothing to change, 1: not written, 2: bad "
                    "input).")
    cal.add_argument("runs", nargs="+", metavar="RUN.h5", help="calibration run file(s)")
    cal.add_argument("--map", required=True, metavar="MAP.toml", help="the channel map")
    cal.add_argument("--yes", action="store_true", help="write without asking")
    cal.add_argument("--out", metavar="NEW.toml",
                     help="write the corrected map here instead of over MAP.toml")
    cal.add_argument("--keep-step", type=int, action="append", default=[], metavar="N",
                     help="keep a questioned gauge entry in the fit (step N, from 1)")
    live = sub.choices["live"]
    live.add_argument("--once", action="store_true", help="one table, then exit")
    live.add_argument("--record-s", type=float, default=0.1,
                      help="acquisition per refresh [s] (default: %(default)s)")
    live.add_argument("--period-s", type=float, default=0.3,
                      help="time between refreshes [s] (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    from daq.board import NIDAQMX, Board
    from daq.errors import ConfigFileError, DaqConnectionError, DaqError
    from sfdrig.commands._board import BoardBusy, board_held, grpc_target_error

    local = False  # the local NI-DAQmx driver
    try:
        if args.action == "write":
            return _write(args)
        if args.action == "calibrate":
            return _calibrate(args)
        if line := grpc_target_error(f"channels {args.action}", args.grpc_target):
            print(line, file=sys.stderr)
            return 2
        cm = _load(args.map, args.grpc_target)
        local = cm.grpc_target is None
        # one tool per board: refused while another holds it (a daemon, idle or not)
        with board_held(f"channels {args.action}", Board(NIDAQMX, cm.device.name,
                                                         cm.grpc_target)):
            if args.action == "check":
                return _check(args, cm)
            return _live(args, cm)
    except ConfigFileError as err:
        for line in err.lines():
            print(f"channels {args.action}: {line}", file=sys.stderr)
        return 2
    except BoardBusy as err:
        print(err, file=sys.stderr)
        return 2
    except DaqError as err:
        hint = (" (install NI-DAQmx, or give --grpc-target HOST:PORT of an NI gRPC device "
                "server)" if isinstance(err, DaqConnectionError) and local else "")
        print(f"channels {args.action}: {' '.join(str(err).split())}{hint}", file=sys.stderr)
        return 2


def _load(path: str, grpc_target: str | None) -> ChannelMap:
    from daq.channels import load_channel_map

    cm = load_channel_map(path)
    if grpc_target is not None:
        cm = cm.model_copy(update={"grpc_target": grpc_target})
    return cm


def _write(args: argparse.Namespace) -> int:
    from daq.channels import default_channel_map, load_channel_map

    cm = load_channel_map(args.source) if args.source else default_channel_map()
    origin = args.source or "daq.channels.default_channel_map() (the report's rig)"
    text = (f"# sfdrig channel map, written by `sfdrig channels write` from {origin}\n"
            "# every analog input: volts = gain_v_per_unit * value + offset_v\n\n"
            + cm.to_toml())
    if args.out is None:
        sys.stdout.write(text)
        return 0
    out = Path(args.out)
    if out.exists() and not args.force:
        print(f"channels write: {out} exists; give --force to overwrite it", file=sys.stderr)
        return 2
    return _write_file("write", out, text, _counts(cm))


def _write_file(action: str, path: Path, text: str, what: str) -> int:
    """Write ``text`` to ``path``: 0 and a line saying so, or 2 and one line why not."""
    try:
        path.write_text(text)
    except OSError as err:
        print(f"channels {action}: {path}: cannot write: {err.strerror}", file=sys.stderr)
        return 2
    print(f"wrote {path}: {what}")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from analysis.channel_calibration import calibration_flow_back
    from daq.channels import load_channel_map
    from daq.map_edits import apply_corrections, edit_map_text, text_diff
    from storage import RunFileError, open_run

    cm = load_channel_map(args.map)
    corrections, questions, notes = [], [], []
    for path in args.runs:
        try:
            with open_run(path) as run:
                fb = calibration_flow_back(run, cm, args.keep_step)
        except (RunFileError, OSError, ValueError) as err:
            print(f"channels calibrate: {' '.join(str(err).split())}", file=sys.stderr)
            return 2
        corrections += fb.corrections
        questions += fb.questions
        notes += fb.notes
    for line in questions:
        print(f"QUESTION {line}")
    for line in notes:
        print(f"note {line}")
    if not corrections:
        print(f"{args.map}: nothing to change")
        return 0
    for c in corrections:
        print(f"change {c.line()}")
    apply_corrections(cm, corrections, args.map)  # a correction the map refuses: exit 2
    original = Path(args.map).read_text()
    new = edit_map_text(original, cm, corrections)
    target = Path(args.out or args.map)
    sys.stdout.write(text_diff(original, new, args.map, str(target)))
    if not args.yes:
        print(f"write {len(corrections)} change{'s' * (len(corrections) != 1)} to {target}? "
              "[y/N]", flush=True)
        if sys.stdin.readline().strip().lower() not in ("y", "yes"):
            print(f"{target}: not written")
            return 1
    return _write_file("calibrate", target, new,
                       f"{len(corrections)} change{'s' * (len(corrections) != 1)}")


def _session(args: argparse.Namespace, cm: ChannelMap) -> NidaqmxSession:
    from daq.nidaqmx_session import NidaqmxSession

    return NidaqmxSession(cm.grpc_target, args.connect_timeout_s)


def _counts(cm: ChannelMap) -> str:
    def n(count: int, what: str) -> str:
        return f"{count} {what}{'s' * (count != 1)}"

    return (f"{n(len(cm.ai), 'input')}, {n(len(cm.ao), 'drive')}, {n(len(cm.do), 'relay')}"
            f"{', an emergency stop' if cm.estop else ''}")


def _check(args: argparse.Namespace, cm: ChannelMap) -> int:
    from daq.device_check import device_problems

    session = _session(args, cm)
    try:
        problems = device_problems(cm, session)
    finally:
        session.close()
    for line in problems:
        print(line)
    where = f"{cm.device.name}{session.where or ' (local NI-DAQmx)'}"
    if problems:
        print(f"{args.map}: {len(problems)} problem{'s' * (len(problems) != 1)} on {where}")
        return 1
    print(f"{args.map}: fits {where}: {_counts(cm)}")
    return 0


def _live(args: argparse.Namespace, cm: ChannelMap) -> int:
    from daq.device_check import LiveReader

    if not 0 < args.record_s <= 10 or not 0 <= args.period_s <= 60:
        print("channels live: --record-s must be in (0, 10] s and --period-s in [0, 60] s",
              file=sys.stderr)
        return 2
    session = _session(args, cm)
    redraw = sys.stdout.isatty() and not args.once
    try:
        with LiveReader(cm, session) as reader:
            while True:
                started = time.monotonic()
                table = format_table(cm, reader.read(args.record_s))
                sys.stdout.write(("\x1b[H\x1b[J" if redraw else "") + table + "\n")
                sys.stdout.flush()
                if args.once:
                    return 0
                time.sleep(max(0.0, args.period_s - (time.monotonic() - started)))
    except KeyboardInterrupt:
        print("channels live: stopped", file=sys.stderr)
        return 0
    finally:
        session.close()


def format_table(cm: ChannelMap, values: LiveValues) -> str:
    """One line per input: name, physical channel, mean and standard deviation in engineering
    units, the mean in volts and the input range; ``AT RANGE LIMIT`` where the volts touched
    the range's edge (a clipped input: a proximitor's gap voltage beyond -10 V, say)."""
    rows = [("input", "physical", "mean", "std", "unit", "volts", "range [V]", "")]
    for i, ch in enumerate(cm.ai):
        unit, factor = _SHOWN.get(ch.units, (ch.units, 1.0))
        lo, hi = ch.range_v
        edge = 0.001 * (hi - lo)
        flag = "AT RANGE LIMIT" if values.min_v[i] <= lo + edge or values.max_v[i] >= hi - edge \
            else ""
        rows.append((ch.name, ch.physical_channel, f"{values.mean[i] * factor:.4g}",
                     f"{values.std[i] * factor:.3g}", unit, f"{values.mean_v[i]:.4f}",
                     f"{lo:g} to {hi:g}", flag))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) if c < 2 or c == 4 else cell.rjust(w)
                       for c, (cell, w) in enumerate(zip(r, widths, strict=True))).rstrip()
             for r in rows]
    lines.append(f"{values.samples} samples per input at {cm.sample_rate_hz:g} S/s, "
                 f"{time.strftime('%H:%M:%S')}")
    return "\n".join(lines)
