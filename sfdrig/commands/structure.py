"""`sfdrig structure`: the structure and instrument tests of the report's sections IV-V and
Appendix A (static load steps, impact tests, eddy-current probe calibration, flow against
pressure), each stored as a run file that `sfdrig identify` reads.

By default the tests run on the daemon (`sfdrig daemon`, the simulated rig or `--backend nidaqmx`)
and this terminal is the operator: it shows each question the test asks and sends what is typed
(`sfdrig.terminal_operator`). ``--unattended`` runs them in this process on the simulated rig with
a stand-in operator (the demo).

A test holds the rig for the person at this terminal (a static load, the pump), so it never
outlives them: Ctrl-C, the terminal hanging up (SIGHUP) and SIGTERM send an abort (the daemon
ramps the drives to zero and closes the run "aborted" with what happened); if this process is
killed outright (SIGKILL) the daemon aborts the test once the terminal's lease lapses
(`control.daemon.lease`, `sfdrig daemon --operator-lease-s`)."""

from __future__ import annotations

import argparse
import contextlib
import errno
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from control.run.files import create_run_writer
from control.run.programs.procedures import (
    FlowSpec,
    ImpactSpec,
    ProbeCalSpec,
    StaticSpec,
    run_flow_test,
    run_impact_test,
    run_probe_calibration,
    run_static_test,
)
from control.wire.client import CommandClient, CommandRefused, DaemonUnavailable
from daq.channels import default_channel_map, load_channel_map
from daq.errors import ConfigFileError
from rig_model.params import RigParams, rig_params_named_or_file
from sfdrig.commands._client_args import add_connection_arguments, command_client
from sfdrig.commands._lost import (
    ClientLost,
    hold_further_signals,
    raising_when_lost,
    silence_hung_up_terminal,
)
from sfdrig.commands.sweep import sweep_fields
from sfdrig.simulated_operator import SimulatedHands, StandInOperator
from sfdrig.terminal_operator import run_test
from simulated_hw.backend import SimulatedBackend

if TYPE_CHECKING:
    from storage.runfile import RunWriter

NAME = "structure"
HELP = ("run the static, impact, probe-calibration and flow tests on the daemon's rig with this "
        "terminal as the operator, one run file each")
TESTS = ("static", "impact", "probe_calibration", "flow")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--only", choices=TESTS, action="append", help="run only these tests")
    p.add_argument("--load-by", choices=("shaker", "hand"), default=None,
                   help="static test: 'shaker' (default: the shakers hold each load, the load "
                   "cells read it) or 'hand' (the operator pushes with a force gauge and types "
                   "its reading, shakers at 0 V, as in the report's IV.1)")
    p.add_argument("--operator", default="", help="name stored in the run files")
    p.add_argument("--notes", default="", help="notes stored in the run files")
    p.add_argument("--spec", type=Path, metavar="FILE.toml",
                   help="test settings: one table per test ([static], [impact], ...)")
    p.add_argument("--set", dest="fields", action="append", default=[], metavar="TEST.KEY=VALUE",
                   help="one setting, e.g. --set static.repeats=2 --set impact.strikes=5")
    p.epilog = ("A test never outlives this terminal: `a` typed at any moment, Ctrl-C, the "
                "terminal hanging up or SIGTERM abort it (drives ramped to zero); if this "
                "process is killed, the daemon aborts it when its operator lease lapses "
                "(`sfdrig daemon --operator-lease-s`).")
    add_connection_arguments(p)
    u = p.add_argument_group("unattended (simulated rig in this process, stand-in operator)")
    u.add_argument("--unattended", action="store_true",
                   help="no daemon, no person: the simulated rig and a stand-in operator")
    u.add_argument("--out", type=Path, default=Path("runs"), help="directory for the run files")
    u.add_argument("--rig", metavar="NAME|RIG.toml",
                   help="'nominal' (default), 'report' (calibrated) or a rig TOML")
    u.add_argument("--channels", type=Path, help="channel map TOML (default: the report's rig)")
    u.add_argument("--seed", type=int, default=0)


def run_structure_tests(out_dir: Path, params: RigParams, channels_path: Path | None = None,
                        seed: int = 0, only: list[str] | None = None,
                        operator: str = "", quiet: bool = False,
                        load_by: str | None = None) -> list[Path]:
    """Run the tests and return the run files written, in order.

    A closed stdout (`sfdrig structure --unattended | head -1`) does not stop the tests: they
    run to the end quietly, then `BrokenPipeError` tells the CLI (exit 141, as `export`)."""
    pipe_closed = False

    def say(text: str) -> None:
        nonlocal pipe_closed
        if quiet or pipe_closed:
            return
        try:
            print(text, flush=True)
        except BrokenPipeError:  # the reader has gone; said at the end, when the files are
            pipe_closed = True   # complete

    out_dir.mkdir(parents=True, exist_ok=True)
    cm = load_channel_map(channels_path) if channels_path else default_channel_map()
    written: list[Path] = []
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    for i, kind in enumerate(only or TESTS):
        test_params = params.model_copy(deep=True)
        if kind in ("static", "impact", "probe_calibration"):
            # the report's static and impact tests ran without the journal: no seal contact
            test_params.seal.enabled = False
        backend = SimulatedBackend(test_params, seed=seed + i)
        backend.configure(cm)
        hands = SimulatedHands(backend, seed=seed + i)
        run_id = f"{stamp}-{kind}"
        path = out_dir / f"{run_id}.h5"
        spec: StaticSpec | ImpactSpec | ProbeCalSpec | FlowSpec
        spec = {"static": StaticSpec, "impact": ImpactSpec, "probe_calibration": ProbeCalSpec,
                "flow": FlowSpec}[kind]()
        if isinstance(spec, StaticSpec) and load_by:
            spec = spec.model_copy(update={"load_by": load_by})
        say(f"{kind}: running ...")
        writer = create_run_writer(path, kind, backend.channel_map, run_id=run_id,
                                   rig_config=test_params, test_spec=spec, operator=operator,
                                   lubricated=kind == "flow", overwrite=True,
                                   paced=backend.realtime, board=backend.board)
        desk = StandInOperator(_logged_to(writer))
        try:
            if isinstance(spec, StaticSpec):
                outcome = run_static_test(backend, writer, spec, operator=desk, hands=hands)
            elif isinstance(spec, ImpactSpec):
                outcome = run_impact_test(backend, writer, desk, spec, hands=hands)
            elif isinstance(spec, ProbeCalSpec):
                outcome = run_probe_calibration(backend, writer, desk, spec, hands=hands)
            else:
                outcome = run_flow_test(backend, writer, desk, spec, hands=hands)
        except Exception as err:
            # what was recorded stays readable: the file is closed as failed, with the reason
            _close_failed(writer, f"{kind} test failed: {err}")
            backend.close()
            raise OSError(f"{kind} test failed: {err} (what it recorded is in {path}, "
                          "closed as failed)") from err
        writer.close(outcome.status, outcome.reason)
        backend.close()
        why = f": {outcome.reason}" if outcome.reason else ""
        say(f"{kind}: {outcome.steps} steps, {outcome.status}{why} -> {path}")
        written.append(path)
    if pipe_closed:
        raise BrokenPipeError(errno.EPIPE, "stdout's reader has gone")
    return written


def _close_failed(writer: RunWriter, reason: str) -> None:
    """Close ``writer`` as failed after an error in its run. After a failed write `close`
    still records the status and reason, and then raises what went wrong: the caller
    reports that error already."""
    with contextlib.suppress(OSError, RuntimeError):
        writer.close("failed", reason)


def _logged_to(writer: RunWriter) -> Callable[[str, str], None]:
    return lambda kind, message: writer.on_event(kind, message, writer.samples_received)


def _abort_lost(client: CommandClient, test: str, how: str, hung_up: bool) -> None:
    """Send the abort first (refused only when no test runs), then say so where the terminal
    still is."""
    hold_further_signals()
    with contextlib.suppress(CommandRefused, DaemonUnavailable):
        client.request("abort", check=False, reason=f"{how} in `sfdrig structure` ({test})")
    if hung_up:
        silence_hung_up_terminal()
        return
    with contextlib.suppress(OSError):
        print(f"\n{test}: abort sent (drives ramp to zero)", flush=True)


def run(args: argparse.Namespace) -> int:
    if args.load_by and args.only and "static" not in args.only:
        print(f"sfdrig structure: --load-by {args.load_by} sets how the static test is loaded, "
              f"but --only {' '.join(args.only)} leaves the static test out", file=sys.stderr)
        return 2
    if args.unattended:
        try:
            params = rig_params_named_or_file(args.rig) if args.rig else RigParams()
            run_structure_tests(args.out, params, args.channels, args.seed, args.only,
                                args.operator, load_by=args.load_by)
        except ConfigFileError as err:  # a channel map: one line per problem
            for line in err.lines():
                print(f"sfdrig structure: {line}", file=sys.stderr)
            return 2
        except BrokenPipeError:
            raise  # stdout's reader has gone: the CLI ends quietly, 141 (sfdrig.cli)
        except (ValueError, OSError) as err:
            print(f"sfdrig structure: {err}", file=sys.stderr)
            return 2
        return 0
    specs = sweep_fields(args.spec, args.fields, who="structure", required=False)
    if args.load_by:
        specs.setdefault("static", {})["load_by"] = args.load_by
    unknown = sorted(set(specs) - set(TESTS))
    if unknown:
        print(f"sfdrig structure: settings for unknown test(s) {', '.join(unknown)} (tests: "
              f"{', '.join(TESTS)})", file=sys.stderr)
        return 2
    failed = False
    try:
        with raising_when_lost(), command_client(args) as client:
            for test in args.only or TESTS:
                try:
                    end = run_test(client, test, dict(specs.get(test, {})), args.operator,
                                   args.notes, sys.stdin, sys.stdout)
                except KeyboardInterrupt:
                    _abort_lost(client, test, "operator pressed Ctrl-C", hung_up=False)
                    return 130
                except ClientLost as lost:
                    _abort_lost(client, test, lost.how, lost.hung_up)
                    return lost.exit_code
                status, reason = end.run.get("status", "?"), end.run.get("reason", "")
                why = f": {reason}" if reason else ""
                print(f"{test}: {end.steps} steps, {status}{why} -> {end.run.get('path', '?')}",
                      flush=True)
                if status != "completed":
                    failed = True
                    break
    except (CommandRefused, DaemonUnavailable) as err:
        print(f"sfdrig structure: {err}", file=sys.stderr)
        return 1
    except ClientLost as lost:  # before a test started or between two: nothing runs to abort
        return lost.exit_code
    return 1 if failed else 0
