"""sfdrig web under load: 16 AI at 62.5 kS/s, N browsers at once, sample-to-screen latency, memory.

A real daemon process paced to the wall clock (the 16-channel map of bench_e2e: 1 MS/s of AI), a
real `sfdrig web` process subscribed to it, and N pages in Debian's headless Chromium (one
browser, a separate context and renderer per page) driven by Playwright. A lubricated sweep runs
for ``--seconds``. Reported:

- sample-to-screen latency per painted frame: the page's clock when the frame is painted
  (``requestAnimationFrame`` after drawing) minus the daemon's ``t_acquired`` of the newest block
  in that frame: the age of the newest sample on the screen. (A sample that arrives just after a
  frame tick is first drawn up to one tick later, 100 ms at 10 frames/s, in a frame that also
  holds newer samples; that wait is not in this figure);
- blocks lost: by the daemon's publisher queue (``dropped_in_daemon``), by the web process's
  subscription (sequence gaps), and in the run file (samples written against samples acquired);
- the web process's resident memory, sampled every 5 s, its CPU and the daemon's (CPU-seconds
  per second: the figure that does not depend on the machine's other load), and the load
  average.

The browsers run at niceness 10 (``--browser-nice``): on the rig the browsers sit on other
machines, here they share 2 cores with the paced daemon.

Usage: .venv/bin/python benchmarks/bench_web.py [--seconds 300] [--browsers 8]
"""

from __future__ import annotations

import argparse
import asyncio
import atexit
import json
import math
import os
import selectors
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_e2e import channel_map_toml, cpu_s, pct  # noqa: E402  (same directory)

REPO = Path(__file__).resolve().parents[1]
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync"]


def first_line(proc: subprocess.Popen[str], what: str, timeout_s: float = 120.0) -> str:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
    ready = sel.select(timeout_s)
    sel.close()
    if not ready:
        proc.kill()
        raise SystemExit(f"{what} did not start within {timeout_s:g} s")
    return proc.stdout.readline().strip()  # type: ignore[union-attr]


def rss_mb(pid: int) -> tuple[float, float, float]:
    """(resident, of it anonymous, of it file-backed) [MB] from ``/proc/PID/status``.

    The anonymous part (heap, malloc's mmaps, Python's arenas, stacks) is the process's own
    memory, where a leak shows. The file-backed part is pages of mapped shared libraries: clean
    pages the kernel drops when the machine runs short of memory and reads back when the code
    runs again (a transfer request runs HDF5's and zlib's code that the frames do not), so it
    follows the machine's memory pressure, not the process."""
    kb = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, rest = line.partition(":")
        if key in ("VmRSS", "RssAnon", "RssFile", "RssShmem"):
            kb[key] = int(rest.split()[0])
    return (kb["VmRSS"] / 1024, kb["RssAnon"] / 1024,
            (kb["RssFile"] + kb.get("RssShmem", 0)) / 1024)


class SocketClients:
    """N WebSocket clients of the page's /ws in a thread: frames received and the latency from
    the daemon's ``t_acquired`` to receipt (what a browser gets before it draws)."""

    def __init__(self, url: str, n: int, transfer: bool = False) -> None:
        self.url = url
        self.ws_url = url.replace("http://", "ws://") + "ws"
        self.n = n
        # the first client also asks for the running run's transfer at each new step, as the
        # page does (`--transfer`): (request time [s], points, pending) per request
        self.transfer = transfer
        self.transfers: list[tuple[float, int, int]] = []
        self.latencies: list[float] = []
        self.frames = [0] * n
        self.last: dict[str, Any] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)

    def start(self) -> None:
        self._thread.start()

    def reset(self) -> None:
        self.latencies = []

    async def _ask_transfer(self, session: Any, fr: dict[str, Any], asked: dict[str, Any]
                            ) -> None:
        run = (fr.get("status") or {}).get("run_id")
        key = (run, len(fr.get("steps") or []))
        again = asked.get("pending") and time.monotonic() - asked.get("at", 0.0) > 1.0
        if not run or (key == asked.get("key") and not again):
            return
        t = time.monotonic()
        async with session.get(f"{self.url}api/runs/{run}/transfer") as r:
            out = await r.json()
        asked.update(key=key, at=time.monotonic(), pending=out.get("pending", 0))
        self.transfers.append((time.monotonic() - t, len(out.get("points", [])),
                               int(out.get("pending", 0))))

    async def _client(self, session: Any, i: int) -> None:
        last_seq = None
        asked: dict[str, Any] = {}
        async with session.ws_connect(self.ws_url, max_msg_size=0) as ws:
            while not self._stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.receive(), 0.5)
                except TimeoutError:
                    continue
                fr = json.loads(msg.data)
                if fr.get("type") != "frame":
                    continue
                await ws.send_str("drawn")  # as the page does: the server sends the next frame
                self.frames[i] += 1
                self.last = fr
                if self.transfer and i == 0:
                    await self._ask_transfer(session, fr, asked)
                if fr["t_acquired"] > 0 and fr["block_seq"] != last_seq:
                    self.latencies.append(time.time() - fr["t_acquired"])
                last_seq = fr["block_seq"]

    async def _main(self) -> None:
        import aiohttp

        async with aiohttp.ClientSession() as session:
            await asyncio.gather(*(self._client(session, i) for i in range(self.n)))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(10)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=300.0, help="sweep time measured [s]")
    ap.add_argument("--browsers", type=int, default=8, help="Chromium pages")
    ap.add_argument("--transfer", action="store_true",
                    help="sfdrig web reads the runs directory and the first WebSocket client "
                         "asks for the run's transfer function at each new step, as the page")
    ap.add_argument("--record-cycles", type=int, default=None,
                    help="cycles recorded per step (default: 1500 or more, 15 steps outlasting "
                         "--seconds); fewer make steps, and so transfer requests, come more "
                         "often, with more amplitudes to outlast --seconds (a short run that "
                         "shows what 30 min of requests do)")
    ap.add_argument("--ws-clients", type=int, default=0,
                    help="plain WebSocket clients of the page's frame stream (no drawing)")
    ap.add_argument("--browser-nice", type=int, default=10,
                    help="niceness of the browsers (and of this script) [0-19]")
    ap.add_argument("--fast", action="store_true",
                    help="daemon in --fast mode (not paced: more data than real time, no AO "
                         "underflow; latencies then mean nothing): for memory and lost blocks")
    ap.add_argument("--priority", choices=["normal", "high", "realtime"], default="normal",
                    help="the daemon's --priority (realtime: SCHED_FIFO, as on the rig's PC)")
    ap.add_argument("--dir", type=Path, default=None,
                    help="where the run file goes (kept; default: a temporary directory, "
                         "removed at the end)")
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    from control.wire.client import CommandClient
    from storage.reader import open_run

    work = Path(tempfile.mkdtemp(prefix="bench_web_", dir=args.dir))
    if args.dir is None:  # a 30-min run file is about 4 GB: not left in /tmp
        atexit.register(shutil.rmtree, work, True)
    channels = work / "channels16.toml"
    channels.write_text(channel_map_toml())
    runs = work / "runs"
    daemon = subprocess.Popen([sys.executable, "-m", "sfdrig", "daemon", "--runs-dir", str(runs),
                               "--channels", str(channels), *(["--fast"] if args.fast else []),
                               *(["--priority", args.priority] if args.priority != "normal"
                                 else [])],
                              cwd=REPO, stdout=subprocess.PIPE,
                              text=True)
    eps = dict(p.split("=", 1) for p in shlex.split(first_line(daemon, "daemon")))
    web = subprocess.Popen([sys.executable, "-m", "sfdrig", "web", "--port", "0",
                            "--command-endpoint", eps["command"], "--data-endpoint", eps["data"],
                            *(["--runs-dir", str(runs)] if args.transfer else [])],
                           cwd=REPO, stdout=subprocess.PIPE, text=True)
    # a refused spec or a browser failure ends this script: never leave the two servers behind
    atexit.register(lambda: [q.kill() for q in (daemon, web) if q.poll() is None])
    url = first_line(web, "sfdrig web").removeprefix("url=")
    print(f"daemon {eps}; web {url}; {args.browsers} browsers, {args.ws_clients} WebSocket "
          f"clients; {args.seconds:g} s")
    sockets = SocketClients(url, args.ws_clients, args.transfer)
    if args.ws_clients:
        sockets.start()
    freqs = [20.0, 30.0, 40.0, 50.0, 60.0]
    # long enough to outlast the measurement (15 steps; 1500 cycles: about 11 min)
    cycles = max(1500, math.ceil(1.2 * args.seconds / (3 * sum(1 / f for f in freqs))))
    amplitudes = [13e-6, 25e-6, 38e-6]
    if args.record_cycles:
        cycles = args.record_cycles
        n_amp = max(3, math.ceil(1.2 * args.seconds / (cycles * sum(1 / f for f in freqs))))
        amplitudes = [float(a) for a in np.linspace(13e-6, 38e-6, n_amp)]
    spec = {"name": "bench_web", "motion": "x", "lubricated": True,
            "amplitude_m": amplitudes, "freq_hz": freqs,
            "settle_cycles": 10, "record_cycles": cycles,
            "control": {"block_s": 0.0125, "ahead_blocks": 3}}
    rss: list[tuple[float, float, float, float]] = []  # (t, resident, anonymous, file) [s, MB]
    # The browsers (children of this process from here on) run at lower priority than the daemon:
    # at full priority, 1-8 software-rendered pages on this 2-core machine starve the paced
    # daemon past its 37.5 ms of AO lead and it faults (DAQmx -200290) within 0.2 s of the start.
    os.nice(args.browser_nice)
    with sync_playwright() as p, CommandClient(eps["command"], timeout_s=20) as c:
        # no browser process at all when only WebSocket clients are measured
        browser = (p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_FLAGS)
                   if args.browsers else None)
        pages = []
        for _ in range(args.browsers):
            assert browser is not None
            page = browser.new_context(bypass_csp=True).new_page()  # Playwright waits use eval
            page.goto(url)
            page.wait_for_function("window.sfdrig.frames >= 1", timeout=60_000)
            pages.append(page)
        c.pump(True)
        seq0 = c.status()["next_seq"]["block"]
        reply = c.start_sweep(spec, operator="bench_web")
        while (st := c.status())["samples"] == 0 and st["state"] in ("arming", "running"):
            time.sleep(0.05)  # polling the daemon's status, not synchronisation
        for page in pages:
            page.evaluate("window.sfdrig.latencies = []")
        sockets.reset()
        st = c.status()  # the pages' resets above may take seconds on a loaded machine
        t0, cpu0, s0 = time.monotonic(), cpu_s(web.pid), st["samples"]
        dcpu0, load0 = cpu_s(daemon.pid), os.getloadavg()[0]
        while (t := time.monotonic() - t0) < args.seconds:
            rss.append((t, *rss_mb(web.pid)))
            print(f"  t {t:6.1f} s: web RSS {rss[-1][1]:.1f} MB (anonymous {rss[-1][2]:.1f}, "
                  f"file {rss[-1][3]:.1f}), daemon {st['state']}, "
                  f"{st['samples']} samples", flush=True)  # progress survives an interruption
            for page in pages:  # lets Playwright service the pages while we wait
                page.wait_for_timeout(5000 / len(pages))
            if not pages:
                time.sleep(5.0)  # the sampling period of the memory figure
            st = c.status()
            if st["state"] not in ("arming", "running", "paused"):
                break
        elapsed, cpu = time.monotonic() - t0, cpu_s(web.pid) - cpu0
        dcpu, load1 = cpu_s(daemon.pid) - dcpu0, os.getloadavg()[0]
        samples = st["samples"] - s0
        lat = [v for page in pages for v in page.evaluate("window.sfdrig.latencies")]
        frames = [page.evaluate("window.sfdrig.frames") for page in pages]
        web_lost = pages[0].evaluate("window.sfdrig.lastFrame.lost") if pages else \
            sockets.last.get("lost")
        socket_lat, socket_frames = list(sockets.latencies), list(sockets.frames)
        if st["state"] in ("running", "paused"):
            c.abort("bench_web: measurement over")
        while (st := c.status())["state"] not in ("idle", "fault"):
            time.sleep(0.2)
        n_blocks = st["next_seq"]["block"] - seq0
        if browser is not None:
            browser.close()
    if args.ws_clients:
        sockets.close()
    web.send_signal(signal.SIGTERM)
    web.wait(30)
    daemon.send_signal(signal.SIGTERM)
    daemon.wait(60)
    with open_run(reply.data["path"]) as run:
        n_file = run.n_samples
    last = st["last_run"]
    mem = np.asarray(rss)
    warm = mem[mem[:, 0] >= 30.0] if (mem[:, 0] >= 30.0).sum() >= 2 else mem
    print(f"run {reply.data['run_id']}: {last['status']} ({last['reason']}); "
          f"{samples} samples x 16 AI in {elapsed:.1f} s = {samples * 16 / elapsed / 1e6:.3f} MS/s")
    block_n = int(round(spec["control"]["block_s"] * 62_500))  # type: ignore[index]
    print(f"daemon: dropped_in_daemon {st['dropped_in_daemon']}; {n_blocks} blocks published; "
          f"run file {n_file} samples = {n_file / block_n:.2f} blocks of {block_n}")
    print(f"web subscription lost (seq gaps): {web_lost}; web CPU "
          f"{100 * cpu / elapsed:.1f} % of one core; daemon CPU {100 * dcpu / elapsed:.0f} %; "
          f"load average (1 min) {load0:.1f} at the start, {load1:.1f} at the end")
    for what, fr, lt in (("browser (painted)", frames, lat),
                         ("WebSocket client (received)", socket_frames, socket_lat)):
        if not fr:
            continue
        ms = np.asarray(lt) * 1e3
        print(f"frames per {what}: min {min(fr)} max {max(fr)} ({min(fr) / elapsed:.1f}-"
              f"{max(fr) / elapsed:.1f} /s); sample-to-{what.split()[0]} latency over {len(ms)} "
              f"frames: p50 {pct(list(ms), 50):.0f} ms, p99 {pct(list(ms), 99):.0f} ms, "
              f"max {ms.max() if ms.size else float('nan'):.0f} ms")
    if sockets.transfers:
        tt = np.asarray(sockets.transfers)
        print(f"transfer requests: {len(tt)}, points at the end {int(tt[-1, 1])}, time p50 "
              f"{np.median(tt[:, 0]) * 1e3:.0f} ms, max {tt[:, 0].max() * 1e3:.0f} ms")
    # the anonymous part is the figure (a leak shows there); the file-backed part follows the
    # machine's memory pressure (`rss_mb`), so the whole RSS is given beside it, not judged
    for col, what in ((2, "web RSS anonymous (the figure)"), (3, "web RSS file-backed"),
                      (1, "web RSS whole")):
        slope = (np.polyfit(warm[:, 0] / 60, warm[:, col], 1)[0] if len(warm) >= 2
                 else float("nan"))
        print(f"{what}: start {mem[0, col]:.1f} MB, after 30 s {warm[0, col]:.1f} MB, end "
              f"{mem[-1, col]:.1f} MB, max {mem[:, col].max():.1f} MB; slope after 30 s "
              f"{slope:+.2f} MB/min over {mem[-1, 0] / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
