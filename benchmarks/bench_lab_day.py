"""A lab day on one daemon: a scripted session of every kind of run beside K busy processes.

One paced daemon process (the simulated rig, or the nidaqmx backend against `sfdrig sim-server`)
lives through the whole session, as it does on the rig PC. The script repeats, until ``--minutes``
are up: a dry circular load sweep, a lubricated X displacement sweep between `pump on` and
`pump off`, a load target above the resonance, a Y displacement sweep, a sweep aborted after its
first step, a sweep paused and resumed, and (simulated rig) one of the structure tests (static,
impact, probe calibration, flow; answered by this script from the daemon's questions). Beside it:
K busy-loop processes competing for the cores, clients that come and go (subscribers that connect
and vanish, command clients that ask and hang up without reading the reply), and ``--browsers``
headless Chromium pages of `sfdrig web`. Also checked on the way: the pump is refused during a
dry run.

Printed: every action as it ends (kind, status, wall time, the daemon's RSS, file descriptors and
threads); then failed runs, underflows (DAQmx -200290) and other DAQ errors, wall times per kind,
the daemon's RSS, descriptors and threads at the start and the end, the client churn counts and
the pages' frames.

Usage: .venv/bin/python benchmarks/bench_lab_day.py [--minutes 30] [--busy 3]
           [--priority normal] [--backend sim|nidaqmx] [--browsers 1] [--dir DIR]
"""

from __future__ import annotations

import argparse
import atexit
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_web import CHROMIUM_FLAGS, first_line  # noqa: E402  (same directory)

BUSY_LOOP = "import time, sys\nend = time.monotonic() + float(sys.argv[1])\n" \
            "while time.monotonic() < end:\n    pass\n"


def proc_stats(pid: int) -> tuple[float, int, int]:
    """(RSS [MB], open file descriptors, threads) of a live process."""
    rss = float("nan")
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024
    return rss, len(os.listdir(f"/proc/{pid}/fd")), len(os.listdir(f"/proc/{pid}/task"))


# --- the session's runs -----------------------------------------------------------------------
def _example(name: str) -> dict[str, Any]:
    with open(REPO / "examples" / name, "rb") as f:
        return tomllib.load(f)


DRY_CIRCULAR = _example("dry_circular.toml")
LUBRICATED_X = {**_example("lubricated_x.toml"), "amplitude_m": [13e-6, 25e-6, 38e-6],
                "freq_step_hz": 20.0}
LOAD_ABOVE_RESONANCE = {"name": "load above the resonance", "motion": "x", "load_n": [400.0],
                        "freq_hz": [150.0]}
DISPLACEMENT_Y = {"name": "Y displacement", "motion": "y", "amplitude_m": [20e-6],
                  "freq_hz": [25.0, 60.0, 90.0]}
SHORT_CIRCULAR = {"name": "short circular", "motion": "circular_forward", "load_n": [40.0],
                  "freq_hz": [80.0, 100.0, 120.0], "record_cycles": 80}
STRUCTURE_TESTS = ["static", "impact", "probe_calibration", "flow"]


@dataclass
class Action:
    kind: str
    status: str
    wall_s: float
    reason: str = ""
    stats: tuple[float, int, int] = (float("nan"), 0, 0)


@dataclass
class Session:
    client: Any
    sub: Any
    daemon_pid: int
    actions: list[Action] = field(default_factory=list)
    interlock_failures: list[str] = field(default_factory=list)
    resets: int = 0

    def wait_end(self, run_id: str, timeout_s: float = 600.0,
                 on_step: Any = None) -> tuple[str, str]:
        """(status, reason) of ``run_id`` from its closing event; ``on_step(n)`` after each step."""
        steps = 0
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self.sub.recv(timeout_s=5.0)
            if msg is None:
                continue
            h = msg.header
            if msg.topic == "step" and h.get("run_id") == run_id:
                steps += 1
                if on_step is not None:
                    on_step(steps)
            elif msg.topic == "event" and h["message"].startswith(f"run {run_id} "):
                rest = h["message"][len(f"run {run_id} "):]
                status, _, reason = rest.partition(": ")
                return status, reason
        return "timeout", f"no end of run within {timeout_s:g} s"

    def record(self, kind: str, t0: float, status: str, reason: str) -> None:
        a = Action(kind, status, time.monotonic() - t0, reason, proc_stats(self.daemon_pid))
        self.actions.append(a)
        rss, fds, thr = a.stats
        print(f"  {kind:28s} {status:11s} {a.wall_s:6.1f} s   RSS {rss:6.1f} MB, {fds} fds, "
              f"{thr} threads" + (f"   ({reason[:100]})" if reason else ""), flush=True)
        st = self.client.status()
        if st["state"] == "fault":  # as the operator does: read the reason, reset, go on
            print(f"  daemon in fault ({st.get('fault_reason')}): reset", flush=True)
            self.resets += 1
            self.client.reset()

    def sweep(self, kind: str, spec: dict[str, Any], on_step: Any = None) -> None:
        if not spec.get("lubricated"):
            self.wait_film_drained()
        t0 = time.monotonic()
        try:
            run_id = self.client.start_sweep(spec, operator="bench_lab_day").data["run_id"]
        except Exception as err:  # a refusal is a failed action, not the end of the session
            self.record(kind, t0, "refused", str(err))
            return
        status, reason = self.wait_end(run_id, on_step=on_step)
        self.record(kind, t0, status, reason)

    def dry_with_pump_check(self) -> None:
        def try_pump(step: int) -> None:
            if step == 1:
                reply = self.client.request("pump", check=False, on=True)
                if reply.ok:
                    self.interlock_failures.append("pump on accepted during a dry sweep")
                    self.client.request("pump", check=False, on=False)
        self.sweep("dry circular (pump refused?)", DRY_CIRCULAR, on_step=try_pump)

    def lubricated(self) -> None:
        self.client.request("pump", check=False, on=True)
        self.sweep("lubricated X", LUBRICATED_X)
        self.client.request("pump", check=False, on=False)

    def wait_film_drained(self) -> None:
        """Dry sweeps are refused while the film drains after the pump went off (a lubricated
        sweep's, the flow test's; --film-drain-s): wait as an operator would."""
        t0 = time.monotonic()
        if self.client.status()["film_drains_for_s"] <= 0:
            return
        while (left := self.client.status()["film_drains_for_s"]) > 0:
            time.sleep(min(left, 1.0))
        self.record("film drained", t0, "completed", "")

    def aborted(self) -> None:
        self.sweep("aborted after step 1", SHORT_CIRCULAR,
                   on_step=lambda n: n == 1 and self.client.abort("bench: operator abort"))

    def paused(self) -> None:
        def pause_resume(n: int) -> None:
            if n == 1:
                self.client.pause()
                self.client.resume()
        self.sweep("paused and resumed", SHORT_CIRCULAR, on_step=pause_resume)

    def structure(self, test: str, timeout_s: float = 600.0) -> None:
        """A structure test, answered as a patient operator would: the simulated instrument's
        reading where one is asked for, ``ok`` otherwise (``skip`` after a refusal)."""
        t0 = time.monotonic()
        reply = self.client.request("start_test", check=False, test=test,
                                    operator="bench_lab_day")
        if not reply.ok:
            self.record(f"structure {test}", t0, "refused", str(reply.error))
            return
        run_id = reply.data["run_id"]
        answered: dict[int, int] = defaultdict(int)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            # the operator is here: renew the test's lease (`control.daemon.lease`)
            self.client.request("alive", check=False, lease=reply.data["lease"])
            msg = self.sub.recv(timeout_s=0.2)
            if msg is not None and msg.topic == "event" and \
                    msg.header["message"].startswith(f"run {run_id} "):
                rest = msg.header["message"][len(f"run {run_id} "):]
                status, _, reason = rest.partition(": ")
                self.record(f"structure {test}", t0, status, reason)
                return
            q = self.client.status().get("question")
            if not q or answered[q["id"]] > 1:
                continue
            choice = "ok" if answered[q["id"]] == 0 and "ok" in q["choices"] else "skip"
            text = q.get("shows", "") if q.get("entry") and choice == "ok" else ""
            self.client.request("answer", check=False, question_id=q["id"], choice=choice,
                                text=text)
            answered[q["id"]] += 1
        self.client.abort("bench: structure test took too long")
        self.record(f"structure {test}", t0, "timeout", f"over {timeout_s:g} s")


# --- clients that come and go ---------------------------------------------------------------
class Churn:
    """Subscribers that connect, take a few messages and vanish; command clients that ask and
    hang up without reading the reply; every 2 s, until stopped."""

    def __init__(self, command: str, data: str) -> None:
        self.command, self.data = command, data
        self.counts: dict[str, int] = defaultdict(int)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _loop(self) -> None:
        import zmq

        from control.wire.client import CommandClient, Subscriber

        while not self._stop.wait(2.0):
            try:
                with Subscriber(self.data) as sub:
                    for _ in range(20):
                        sub.recv(timeout_s=0.1)
                self.counts["subscribers"] += 1
                with CommandClient(self.command, timeout_s=10) as c:
                    c.status()
                self.counts["status clients"] += 1
                ctx = zmq.Context.instance()
                s = ctx.socket(zmq.DEALER)
                s.setsockopt(zmq.LINGER, 0)
                s.connect(self.command)
                s.send_multipart([b"", b'{"cmd": "status"}'])
                s.close()  # gone before the reply
                self.counts["hung-up clients"] += 1
            except Exception as err:
                self.counts[f"error: {type(err).__name__}"] += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(10)


def start_daemon(work: Path, backend: str, procs: list[subprocess.Popen[str]],
                 options: list[str]) -> tuple[subprocess.Popen[str], dict[str, str]]:
    """A paced daemon process with its run files in ``work`` and ``options``: the simulated rig
    (``backend`` "sim"), or the nidaqmx backend against a `sfdrig sim-server` started for it
    ("nidaqmx"); (the daemon, its endpoints). Both processes go into ``procs``."""
    cli: list[str] = []
    if backend == "nidaqmx":
        server = subprocess.Popen([sys.executable, "-m", "sfdrig", "sim-server", "--port", "0"],
                                  cwd=REPO, stdout=subprocess.PIPE, text=True)
        procs.append(server)
        address = first_line(server, "sim-server").removeprefix("listening on ")
        cli = ["--backend", "nidaqmx", "--grpc-target", address]
    daemon = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "daemon", "--runs-dir", str(work / "runs"), *cli,
         *options], cwd=REPO, stdout=subprocess.PIPE, text=True)
    procs.append(daemon)
    return daemon, dict(p.split("=", 1) for p in shlex.split(first_line(daemon, "daemon")))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="session length [min]")
    ap.add_argument("--busy", type=int, default=3, help="busy-loop processes beside it")
    ap.add_argument("--priority", choices=["normal", "high", "realtime"], default="normal")
    ap.add_argument("--backend", choices=["sim", "nidaqmx"], default="sim",
                    help="nidaqmx: through the nidaqmx package against `sfdrig sim-server`")
    ap.add_argument("--browsers", type=int, default=1, help="headless Chromium pages")
    ap.add_argument("--dir", type=Path, default=None, help="keep the run files here")
    args = ap.parse_args()

    from control.wire.client import CommandClient, Subscriber

    if args.dir is not None:
        args.dir.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="bench_lab_day_", dir=args.dir))
    if args.dir is None:
        atexit.register(shutil.rmtree, work, True)
    procs: list[subprocess.Popen[str]] = []
    atexit.register(lambda: [p.kill() for p in procs if p.poll() is None])
    end_s = 60.0 * args.minutes
    for _ in range(args.busy):
        procs.append(subprocess.Popen([sys.executable, "-c", BUSY_LOOP, str(end_s + 600)]))
    daemon, eps = start_daemon(work, args.backend, procs,
                               ["--priority", args.priority] if args.priority != "normal" else [])
    print(f"daemon pid {daemon.pid} ({args.backend}, priority {args.priority}); {args.busy} busy "
          f"processes; {args.browsers} browser pages; {args.minutes:g} min; load average "
          f"{os.getloadavg()[0]:.1f}", flush=True)

    pw = browser = None
    pages: list[Any] = []
    if args.browsers:
        from playwright.sync_api import sync_playwright

        web = subprocess.Popen([sys.executable, "-m", "sfdrig", "web", "--port", "0",
                                "--command-endpoint", eps["command"],
                                "--data-endpoint", eps["data"]],
                               cwd=REPO, stdout=subprocess.PIPE, text=True)
        procs.append(web)
        url = first_line(web, "sfdrig web").removeprefix("url=")
        pw = sync_playwright().start()
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_FLAGS)
        for _ in range(args.browsers):
            page = browser.new_context(bypass_csp=True).new_page()  # Playwright waits use eval
            page.goto(url)
            pages.append(page)

    churn = Churn(eps["command"], eps["data"])
    with CommandClient(eps["command"], timeout_s=20) as c, \
            Subscriber(eps["data"], topics=["event", "step"], rcvhwm=0) as sub:
        sub.wait_connected(60)
        s = Session(c, sub, daemon.pid)
        start = proc_stats(daemon.pid)
        churn.start()
        t0 = time.monotonic()
        cycle = 0
        script = [s.dry_with_pump_check, s.lubricated,
                  lambda: s.sweep("load 400 N at 150 Hz", LOAD_ABOVE_RESONANCE),
                  lambda: s.sweep("Y displacement", DISPLACEMENT_Y), s.aborted, s.paused]
        while time.monotonic() - t0 < end_s:
            cycle += 1
            print(f"cycle {cycle} at {(time.monotonic() - t0) / 60:.1f} min, load average "
                  f"{os.getloadavg()[0]:.1f}", flush=True)
            for action in script:
                action()
                if time.monotonic() - t0 >= end_s:
                    break
            else:
                if args.backend == "sim":
                    s.structure(STRUCTURE_TESTS[(cycle - 1) % len(STRUCTURE_TESTS)])
        churn.close()
        end = proc_stats(daemon.pid)
        elapsed = time.monotonic() - t0
    frames = [p.evaluate("window.sfdrig ? window.sfdrig.frames : -1") for p in pages]
    if browser is not None and pw is not None:
        browser.close()
        pw.stop()
    daemon.send_signal(signal.SIGTERM)
    daemon.wait(60)

    acts = s.actions
    expected = {"aborted after step 1": "aborted"}
    failed = [a for a in acts if a.status != expected.get(a.kind, "completed")]
    underflows = [a for a in acts if "200290" in a.reason or "underflow" in a.reason.lower()]
    daq_errors = [a for a in acts if "DAQmx" in a.reason or "-200" in a.reason]
    print(f"\n{len(acts)} actions in {elapsed / 60:.1f} min ({cycle} cycles); load average "
          f"{os.getloadavg()[0]:.1f} at the end")
    print(f"failed: {len(failed)}; underflows: {len(underflows)}; other DAQ errors: "
          f"{len(daq_errors) - len(underflows)}")
    for a in failed:
        print(f"  FAILED {a.kind}: {a.status} {a.reason}")
    print(f"faults reset: {s.resets}; interlock failures: {s.interlock_failures or 'none'}")
    print("wall time per kind [s] (min / median / max, n):")
    by_kind: dict[str, list[float]] = defaultdict(list)
    for a in acts:
        by_kind[a.kind].append(a.wall_s)
    for kind, w in by_kind.items():
        print(f"  {kind:28s} {min(w):6.1f} / {float(np.median(w)):6.1f} / {max(w):6.1f}  "
              f"({len(w)})")
    print(f"daemon RSS {start[0]:.1f} -> {end[0]:.1f} MB, file descriptors {start[1]} -> "
          f"{end[1]}, threads {start[2]} -> {end[2]}")
    print(f"client churn: {dict(churn.counts)}")
    if pages:
        print(f"browser pages' frames: {frames}")
    return 1 if failed or underflows or s.interlock_failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
