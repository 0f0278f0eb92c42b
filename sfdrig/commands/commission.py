"""`sfdrig commission MAP.toml`: the guided first power-up (`control.commissioning.procedure`):
every input
at rest, the emergency stop and the watchdog with the operator, a small drive per shaker; a
record (run file and report) and the proposed corrections of the map as a diff."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from daq.board import NIDAQMX, SIM, Board
from sfdrig.commands._board import BoardBusy, board_held, grpc_target_error

if TYPE_CHECKING:  # imported where the board is chosen
    from control.commissioning.procedure import CommissionSpec, Operator
    from daq.backend import DaqBackend
    from daq.channels import ChannelMap
    from rig_model.params import RigParams

NAME = "commission"
HELP = ("guided first power-up: inputs at rest, the e-stop and the watchdog with the operator, "
        "a small drive per shaker (swapped, dead, inverted, mis-scaled sensors); writes a "
        "record and the proposed map corrections (exit 0: passed, 1: problems, 2: bad input)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("map", metavar="MAP.toml", help="the channel map under test")
    parser.add_argument("--backend", choices=["sim", "nidaqmx"], default="sim",
                        help="sim: the in-process simulated rig, a stand-in operator at it "
                             "(default); nidaqmx: the board (or --grpc-target), you the operator")
    parser.add_argument("--grpc-target", metavar="HOST:PORT",
                        help="with --backend nidaqmx: an NI gRPC Device Server (e.g. `sfdrig "
                             "sim-server`); default: the map's grpc_target, else the local driver")
    parser.add_argument("--watchdog-s", type=float, default=1.0,
                        help="the board's watchdog timeout to test [s]; 0: not tested "
                             "(default: %(default)s)")
    parser.add_argument("--drive-n", type=float, default=2.0,
                        help="force amplitude per shaker, at most 2 N (default: %(default)s)")
    parser.add_argument("--freq-hz", type=float, default=20.0,
                        help="test frequency, away from the ~45 Hz resonance (default: "
                             "%(default)s)")
    parser.add_argument("--pump-s", type=float, default=2.0,
                        help="the pump relay switched on (off), the inlet pressure and flow must "
                             "rise (fall) within this [s] (default: %(default)s)")
    parser.add_argument("--rest-s", type=float, default=1.0,
                        help="reading at rest [s] (default: %(default)s)")
    parser.add_argument("--out", default="out/commission", metavar="DIR",
                        help="where the record, report and proposed map go (default: "
                             "%(default)s)")
    parser.add_argument("--yes", action="store_true",
                        help="answer the tool's yes/no questions yes (the e-stop is still "
                             "pressed by hand)")
    sim = parser.add_argument_group("simulated rig (--backend sim)")
    sim.add_argument("--rig", default="nominal", metavar="NAME|RIG.toml",
                     help="simulated rig (default: %(default)s)")
    sim.add_argument("--wiring", metavar="WIRING.toml",
                     help="how the simulated rig is really wired (a channel map; default: as "
                          "MAP.toml says): rehearse a mis-wired rig")
    sim.add_argument("--seed", type=int, default=0, help="noise seed (default: %(default)s)")


class TerminalOperator:
    """The person at the rig, on this terminal: instructions printed, yes/no read from stdin
    (one line each; end of input is no)."""

    def __init__(self, yes: bool) -> None:
        self.yes = yes

    def instruct(self, action: str, text: str) -> None:
        print(f"OPERATOR: {text}", flush=True)

    def confirm(self, action: str, question: str) -> bool:
        print(f"OPERATOR: {question} [y/n]{' y (--yes)' if self.yes else ''}", flush=True)
        if self.yes:
            return True
        return sys.stdin.readline().strip().lower() in ("y", "yes")


def run(args: argparse.Namespace) -> int:
    from control.commissioning.procedure import CommissionError, CommissionSpec
    from daq.channels import load_channel_map
    from daq.errors import ConfigFileError, DaqConnectionError, DaqError

    def bad(text: str) -> int:
        print(f"commission: {' '.join(text.split())}", file=sys.stderr)
        return 2

    if not 0 <= args.watchdog_s <= 60 or not 0.1 <= args.rest_s <= 60:
        return bad("--watchdog-s must be in [0, 60] s and --rest-s in [0.1, 60] s")
    if not 0.2 <= args.pump_s <= 120:
        return bad(f"--pump-s must be in [0.2, 120] s, got {args.pump_s:g}")
    if args.backend == "sim" and args.grpc_target is not None:
        return bad("--grpc-target needs --backend nidaqmx")
    if line := grpc_target_error("commission", args.grpc_target):
        print(line, file=sys.stderr)
        return 2
    try:
        cm = load_channel_map(args.map)
        if args.grpc_target is not None:
            cm = cm.model_copy(update={"grpc_target": args.grpc_target})
        spec = CommissionSpec(drive_n=args.drive_n, freq_hz=args.freq_hz, rest_s=args.rest_s,
                              watchdog_s=args.watchdog_s or None, pump_s=args.pump_s)
        spec.check(cm)
        backend, operator, rig = _backend(args, cm)
    except ConfigFileError as err:
        for line in err.lines():
            print(f"commission: {line}", file=sys.stderr)
        return 2
    except (CommissionError, ValueError) as err:
        return bad(str(err).splitlines()[0])
    # one tool per board: refused while another holds it (a daemon, idle or not); the
    # simulated rig in process is this process's own
    board = Board(NIDAQMX, cm.device.name, cm.grpc_target) if args.backend == "nidaqmx" \
        else Board(SIM, cm.device.name)
    try:
        with board_held("commission", board):
            try:
                try:
                    backend.configure(cm)
                    # after configure: a device that says it is simulated (an NI simulated
                    # device, or `sfdrig sim-server`) is named so; a rehearsal never reads as
                    # the rig
                    described = backend.board.describe()
                except DaqError as err:
                    hint = (" (install NI-DAQmx, or give --grpc-target HOST:PORT)"
                            if isinstance(err, DaqConnectionError) and cm.grpc_target is None
                            else "")
                    return bad(f"{err}{hint}")
                return _commission(args, cm, spec, backend, operator, rig, described)
            finally:
                with contextlib.suppress(DaqError):
                    backend.close()
    except BoardBusy as err:
        print(err, file=sys.stderr)
        return 2


def _backend(args: argparse.Namespace, cm: ChannelMap
             ) -> tuple[DaqBackend, Operator, RigParams | None]:
    if args.backend == "nidaqmx":
        from daq.nidaqmx_backend import NidaqmxBackend

        return (NidaqmxBackend(grpc_target=cm.grpc_target,
                               watchdog_timeout_s=args.watchdog_s or None),
                TerminalOperator(args.yes), None)
    from daq.channels import load_channel_map
    from rig_model.params import RigParamsError, rig_params_named_or_file
    from sfdrig.simulated_operator import SimulatedCommissioner
    from simulated_hw.backend import SimulatedBackend

    try:
        params = rig_params_named_or_file(args.rig)
    except RigParamsError as err:  # the file and the first problem, one line
        raise ValueError(" ".join(str(err).splitlines()[:2])) from None
    wiring = load_channel_map(args.wiring, wiring=True) if args.wiring else None
    backend = SimulatedBackend(params, seed=args.seed, wiring=wiring,
                               watchdog_s=args.watchdog_s or None)
    return backend, SimulatedCommissioner(backend), params


def _commission(args: argparse.Namespace, cm: ChannelMap, spec: CommissionSpec,
                backend: DaqBackend, operator: Operator, rig: RigParams | None,
                board: str) -> int:
    from control.commissioning.procedure import (
        Commissioning,
        CommissionInterrupted,
        report_markdown,
    )
    from control.run.files import create_run_writer

    out = Path(args.out)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    try:
        out.mkdir(parents=True, exist_ok=True)
        record = out / f"commission-{stamp}.h5"
        writer = create_run_writer(
            record, "commissioning", backend.channel_map, run_id=f"commission-{stamp}",
            rig_config=rig, board=backend.board,
            test_spec={"map": str(args.map), "board": board, "drive_n": spec.drive_n,
                       "freq_hz": spec.freq_hz, "rest_s": spec.rest_s,
                       "watchdog_s": spec.watchdog_s, "pump_s": spec.pump_s},
            notes="sfdrig commission: rest, e-stop, watchdog and drives back to back; the "
                  "steps name each stage, the events hold the findings")
    except (OSError, ValueError) as err:
        print(f"commission: {out}: cannot write the record: {err}", file=sys.stderr)
        return 2
    print(f"commissioning {args.map} on the {board}; record {record}", flush=True)
    job = Commissioning(backend, operator, spec, listener=writer,
                        log=lambda line: print(line, flush=True))
    try:
        result = job.run()
    except KeyboardInterrupt as err:  # CommissionInterrupted: a drive ramped down first
        why = str(err) if isinstance(err, CommissionInterrupted) else "interrupted"
        writer.close("aborted", f"operator pressed Ctrl-C: {why}")
        print(f"commission: {why}; record {record}", file=sys.stderr)
        return 130
    except BaseException:
        writer.close("failed", "the commissioning tool failed")
        raise
    n = len(result.failed)
    verdict = ("passed" if result.passed else "stopped early" if not n else
               f"{n} problem{'s' * (n != 1)}" + (" (stopped early)" if result.stopped else ""))
    writer.close("completed", f"commissioning {verdict} on the {board}")
    diff = ""
    if result.proposed is not None:
        from daq.map_edits import edit_map_text, text_diff

        proposed_path = out / f"commission-{stamp}-proposed.toml"
        original = Path(args.map).read_text()
        proposed = edit_map_text(original, cm, result.corrections)
        diff = text_diff(original, proposed, str(args.map), str(proposed_path))
        proposed_path.write_text(proposed)
        (out / f"commission-{stamp}.diff").write_text(diff)
        print(f"proposed corrections ({proposed_path}; review, then replace the map with it):")
        sys.stdout.write(diff)
    report = out / f"commission-{stamp}.md"
    report.write_text(report_markdown(result, str(args.map), str(record), diff, spec, board))
    print(f"report {report}")
    print(f"commissioning {verdict} on the {board}: {args.map}")
    return 0 if result.passed else 1
