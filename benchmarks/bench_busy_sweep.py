"""The README's example sweeps on a busy PC: wall time beside K busy processes over the idle time,
and the daemon's own CPU.

One paced daemon process at normal priority (the simulated rig in process, or the nidaqmx backend
against `sfdrig sim-server`: `--backend nidaqmx`, the lab's path), and the README's "Using it"
sweeps run through it as a client runs them: the dry circular 40 N sweep at 20, 80 and 100 Hz
(README line `sfdrig sweep --set motion=circular_forward ...`) and the report's lubricated X
programme at 25 um (`examples/lubricated_x.toml --set amplitude_m=[25e-6]`, the pump on). Each
sweep runs once per load level: 0 busy processes (`python3 -c "while True: pass"`, normal
priority) and then each of ``--busy``. The dry sweeps go first at every level, then the pump is
switched on once and the lubricated ones follow (a dry sweep after the pump waits 30 s for the
film to drain).

Printed per sweep and level: wall time from the request to the run's end, the ratio to the idle
level's, the steps converged of the steps run, the daemon's CPU over the run [% of a core, user +
system from /proc] and the run's AO ring report (how late the host was). The load average at the
start says what else was running (other work on the machine adds to the busy processes).

Targets (issue 41): beside 6 busy processes at most 1.5x the idle time, beside 3 at most 1.2x,
every step converged; the daemon at most 8 % of a core on the nidaqmx path.

Usage: .venv/bin/python benchmarks/bench_busy_sweep.py [--backend sim|nidaqmx] [--busy 3 6]
(``--busy`` with no counts: the idle level alone)
"""

from __future__ import annotations

import argparse
import atexit
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))
from bench_lab_day import start_daemon  # noqa: E402  (same directory)

BUSY_LOOP = "while True: pass"
TICKS = os.sysconf("SC_CLK_TCK")


def readme_sweeps() -> dict[str, dict[str, Any]]:
    """The README's two example sweeps as requests (name -> spec)."""
    with open(REPO / "examples" / "lubricated_x.toml", "rb") as f:
        lubricated = tomllib.load(f)
    lubricated["amplitude_m"] = [25e-6]
    dry = {"motion": "circular_forward", "load_n": [40.0], "freq_hz": [20.0, 80.0, 100.0]}
    return {"dry circular 40 N, 20/80/100 Hz": dry, "lubricated X 25 um, 20-60 Hz": lubricated}


def cpu_s(pid: int) -> float:
    """User + system CPU of a live process [s]."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


@dataclass
class Result:
    sweep: str
    busy: int
    wall_s: float
    cpu_pct: float
    steps: int
    converged: int
    status: str
    ring: str


def run_sweep(client: Any, sub: Any, name: str, spec: dict[str, Any], busy: int,
              daemon_pid: int) -> Result:
    c0, t0 = cpu_s(daemon_pid), time.monotonic()
    run_id = client.start_sweep(spec, operator="bench_busy_sweep").data["run_id"]
    steps: list[dict[str, Any]] = []
    ring, end = "", ""
    while not end:
        msg = sub.recv(timeout_s=300)
        if msg is None:
            raise SystemExit(f"{name}: the daemon's stream went silent")
        h = msg.header
        if msg.topic == "step" and h["run_id"] == run_id:
            steps.append(h["step"])
        elif msg.topic == "event":
            text = h["message"]
            if text.startswith("AO ring"):
                ring = text
            elif text.startswith(f"run {run_id} "):
                end = text
    wall = time.monotonic() - t0
    cpu = cpu_s(daemon_pid) - c0
    return Result(name, busy, wall, 100 * cpu / wall, len(steps),
                  sum(bool(s["converged"]) for s in steps), end.split(" ", 3)[2].rstrip(":"), ring)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", choices=["sim", "nidaqmx"], default="sim",
                    help="nidaqmx: through the nidaqmx package against `sfdrig sim-server`")
    ap.add_argument("--busy", type=int, nargs="*", default=[3, 6],
                    help="busy-process counts to run beside (after the idle run); none: the "
                         "idle run alone (the daemon's CPU)")
    args = ap.parse_args()
    if any(b < 1 for b in args.busy):
        print("bench_busy_sweep: --busy counts must be >= 1", file=sys.stderr)
        return 2

    from control.wire.client import CommandClient, Subscriber

    work = Path(tempfile.mkdtemp(prefix="bench_busy_sweep_"))
    atexit.register(shutil.rmtree, work, True)
    procs: list[subprocess.Popen[str]] = []
    atexit.register(lambda: [p.kill() for p in procs if p.poll() is None])
    daemon, eps = start_daemon(work, args.backend, procs, [])
    print(f"daemon pid {daemon.pid} ({args.backend}, normal priority); load average "
          f"{os.getloadavg()[0]:.1f} at the start; {os.cpu_count()} cores", flush=True)

    levels = [0, *args.busy]
    sweeps = readme_sweeps()
    results: list[Result] = []
    with CommandClient(eps["command"], timeout_s=60) as client, \
            Subscriber(eps["data"], topics=["step", "event"], rcvhwm=0) as sub:
        sub.wait_connected()
        for name, spec in sweeps.items():
            for busy in levels:
                if spec.get("lubricated") and not client.status().get("pump_on"):
                    client.pump(True)  # again after a fault, which switches it off
                loops = [subprocess.Popen([sys.executable, "-c", BUSY_LOOP])
                         for _ in range(busy)]
                try:
                    time.sleep(1.0 if busy else 0.0)  # the loops running before the sweep
                    r = run_sweep(client, sub, name, spec, busy, daemon.pid)
                finally:
                    for p in loops:
                        p.kill()
                        p.wait(10)
                results.append(r)
                if r.status != "completed" and client.status().get("state") == "fault":
                    client.reset()  # the next level starts from a clean daemon
                print(f"  {name}, {busy} busy: {r.wall_s:.2f} s, {r.status}, "
                      f"{r.converged}/{r.steps} converged, daemon {r.cpu_pct:.1f} % of a core; "
                      f"load average {os.getloadavg()[0]:.1f}", flush=True)
        if client.status().get("state") == "fault":
            client.reset()  # the last level faulted (its watchdog switched the pump off)
        client.pump(False)
    daemon.terminate()
    daemon.wait(60)

    print(f"\n{'sweep':34} {'busy':>4} {'wall s':>7} {'x idle':>6} {'converged':>9} "
          f"{'daemon CPU %':>12}  status")
    for r in results:
        idle = next(x for x in results if x.sweep == r.sweep and x.busy == 0)
        print(f"{r.sweep:34} {r.busy:4d} {r.wall_s:7.2f} {r.wall_s / idle.wall_s:6.2f} "
              f"{r.converged:>4d}/{r.steps:<4d} {r.cpu_pct:12.1f}  {r.status}")
    print("\nhow late the host was (the run's AO ring report):")
    for r in results:
        print(f"  {r.sweep}, {r.busy} busy: {r.ring or '(none)'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
