"""The AO underflow margin the acquisition loop keeps through nidaqmx, per AO lead and priority.

Starts `sfdrig sim-server` (paced: samples appear with the wall clock, as on a board) as a
separate process on a free loopback port, then runs the control loop's pattern through
`NidaqmxBackend` (the report's 14 AI, 2 AO, 10 kS/s, 10 ms blocks): write one block, read one
block, for ``--seconds``, with the AO ``lead`` blocks ahead. Before each write it asks the board how
many AO samples are still queued (as `control.run.stream.DriveStream` does); the minimum is the
margin
the lead left. An underflow (-200290) ends that run. Each lead runs in a child process at the
priority asked (``normal``, ``high`` = nice -10, ``realtime`` = SCHED_FIFO), like the daemon.

    .venv/bin/python benchmarks/bench_ao_margin.py [--seconds 5] [--leads 3 5 10] \
        [--server-realtime]

``--server-realtime`` runs the simulated board under SCHED_FIFO: a real board generates by DMA
and needs no CPU, while the simulated one computes the rig on the same cores as the client.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time

import numpy as np

BLOCK = 100  # samples: 10 ms at 10 kS/s


def run_loop(address: str, lead_blocks: int, seconds: float, priority: str) -> dict:
    """One measurement (in this process, at ``priority``)."""
    from daq.channels import default_channel_map
    from daq.errors import DaqUnderflowError
    from daq.nidaqmx_backend import NidaqmxBackend
    from sfdrig.commands._priority import apply_priority

    apply_priority(priority)
    cm = default_channel_map().model_copy(update={"grpc_target": address})
    fs = cm.sample_rate_hz
    backend = NidaqmxBackend(watchdog_timeout_s=None)
    backend.configure(cm)
    zeros = np.zeros((len(cm.ao), BLOCK))
    margins: list[int] = []
    underflow_at = None
    try:
        for _ in range(lead_blocks):
            backend.write_ao(zeros)
        backend.start()
        t0 = time.monotonic()
        blocks = 0
        while time.monotonic() - t0 < seconds:
            margins.append(backend.ao_backlog())
            try:
                backend.write_ao(zeros)
            except DaqUnderflowError:
                underflow_at = time.monotonic() - t0
                break
            backend.read_ai(BLOCK)
            blocks += 1
        backend.stop()
    finally:
        backend.close()
    m = np.array(margins) * 1e3 / fs
    return {"lead_ms": lead_blocks * BLOCK * 1e3 / fs, "priority": priority, "blocks": blocks,
            "min_margin_ms": float(m.min()), "p1_margin_ms": float(np.percentile(m, 1)),
            "median_margin_ms": float(np.median(m)), "underflow_after_s": underflow_at}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--leads", type=int, nargs="+", default=[3, 5, 10],
                        help="AO lead in 10 ms blocks")
    parser.add_argument("--priorities", nargs="+", default=["normal", "realtime"])
    parser.add_argument("--server-realtime", action="store_true",
                        help="run the sim-server under SCHED_FIFO too (chrt -f 10)")
    parser.add_argument("--child", nargs=4, metavar=("ADDR", "LEAD", "SECONDS", "PRIORITY"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        address, lead, seconds, priority = args.child
        print(json.dumps(run_loop(address, int(lead), float(seconds), priority)))
        return
    chrt = ["chrt", "-f", "10"] if args.server_realtime else []
    server = subprocess.Popen([*chrt, sys.executable, "-m", "sfdrig", "sim-server", "--port", "0"],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        address = server.stdout.readline().strip().removeprefix("listening on ")
        with open("/proc/loadavg") as f:
            print(f"load average before: {f.read().split()[0]}")
        for priority in args.priorities:
            for lead in args.leads:
                out = subprocess.run(
                    [sys.executable, __file__, "--child", address, str(lead),
                     str(args.seconds), priority], capture_output=True, text=True)
                if out.returncode != 0:
                    print(f"lead {lead} blocks, {priority}: failed: "
                          f"{out.stderr.strip().splitlines()[-1]}")
                    continue
                r = json.loads(out.stdout)
                ended = (f"underflow after {r['underflow_after_s']:.2f} s"
                         if r["underflow_after_s"] is not None else "no underflow")
                print(f"lead {r['lead_ms']:.0f} ms, {priority:8s}: {r['blocks']} blocks, margin "
                      f"min {r['min_margin_ms']:.1f} / p1 {r['p1_margin_ms']:.1f} / median "
                      f"{r['median_margin_ms']:.1f} ms; {ended}")
    finally:
        server.send_signal(signal.SIGTERM)
        server.communicate(timeout=10)


if __name__ == "__main__":
    main()
