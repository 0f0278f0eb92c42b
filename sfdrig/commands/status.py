"""`sfdrig status`: the daemon's state, current run and progress (one request, plain text)."""

from __future__ import annotations

import argparse
import json

from control.wire.client import CommandRefused, DaemonUnavailable
from control.wire.summary_lines import peak_line
from sfdrig.commands._client_args import add_connection_arguments, command_client, not_done
from sfdrig.commands.sweep import progress_text

NAME = "status"
HELP = "show the daemon's state, the current run and its progress"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the full status as JSON")
    parser.add_argument("--reset", action="store_true",
                        help="acknowledge a fault (fault -> idle) before showing the status; "
                             "when idle there is nothing to reset (exit 0)")


def run(args: argparse.Namespace) -> int:
    try:
        with command_client(args) as client:
            if args.reset:
                reply = client.reset()
                print("nothing to reset: the daemon is idle" if reply.data.get("nothing_to_reset")
                      else "fault acknowledged")
            st = client.status()
    except (DaemonUnavailable, CommandRefused) as err:
        print(f"status: {not_done(err)}")
        return 1
    if args.json:
        print(json.dumps(st, indent=2))
        return 0
    print(f"board      {st['board'].get('description', '?')}")
    print(f"state      {st['state']}")
    print(f"pump       {'on' if st['pump_on'] else 'off'}")
    if st["run_id"]:
        p = st["progress"]
        print(f"run        {st['run_id']}  ({st['run_path']})")
        print(f"samples    {st['samples']} at {st['sample_rate_hz']:g} S/s")
        if p:
            print("progress   " + progress_text(p))
        lease = st["operator_lease"]
        if lease:  # a structure test: aborted if its client is silent for the lease
            print(f"operator   last heard {lease['silent_s']:.1f} s ago (the test is aborted "
                  f"after {lease['lease_s']:g} s without)")
    if st["fault_reason"] or st["state"] == "fault":
        print(f"fault      {st['fault_reason'] or '?'} (once its cause is cleared, reset it "
              "with `sfdrig status --reset`)")
    last = st["last_run"]
    if last:
        print(f"last run   {last.get('run_id', '?')}: {last.get('status', '?')}"
              + (f" ({last['reason']})" if last.get("reason") else ""))
        summary = last.get("summary")
        if summary:
            print(f"           {peak_line(summary)}")
    print(f"endpoints  command={st['endpoints']['command']} data={st['endpoints']['data']}")
    return 0
