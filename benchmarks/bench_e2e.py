"""End to end: simulated rig -> daemon -> HDF5 + PUB -> 2 subscribers, 16 channels at 62.5 kS/s.

The daemon runs as a real process, paced to the wall clock (as on the rig), with a 16-AI channel
map at 62.5 kS/s (the report's 14 channels plus two more accelerometers): 1 MS/s of AI. Two
subscriber processes take every block; the script reports, per subscriber, blocks received and
lost (sequence gaps), contiguity, and the block latency from acquisition (the daemon's
``t_acquired``, stamped as the block reaches the publisher) to receipt. The run file is checked to
hold every sample. Then, in the same invocation, raw pyzmq PUB/SUB moves the same payload (same
frames, same size, same block rate) between processes, paced and as fast as possible, and the
ratios are printed.

Targets: >= 1 MS/s aggregate for 60 s, zero lost blocks for subscribers that keep up, p99 latency
under 50 ms.

Usage: .venv/bin/python benchmarks/bench_e2e.py [--seconds 60] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import selectors
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

FS_HZ = 62_500.0
REPO = Path(__file__).resolve().parents[1]


# --- the 16-channel map -------------------------------------------------------------------------
def channel_map_toml() -> str:
    """The default map plus accelerometers ax2, ay2 on ai14, ai15, at 62.5 kS/s, as TOML."""
    from daq.channels import default_channel_map

    d = default_channel_map().to_json_dict()
    d["sample_rate_hz"] = FS_HZ
    acc = next(c for c in d["ai"] if c["name"] == "ax")
    d["ai"] = d["ai"] + [
        {**acc, "name": "ax2", "physical_channel": "Dev1/ai14", "sensor": "second accel X"},
        {**acc, "name": "ay2", "physical_channel": "Dev1/ai15", "sensor": "second accel Y"},
    ]
    return _toml(d)


def _val(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_val(x) for x in v) + "]"
    return json.dumps(str(v))


def _toml(d: dict[str, Any]) -> str:
    lines: list[str] = []
    tables = []
    for k, v in d.items():
        if v is None:
            continue
        if isinstance(v, dict):
            tables.append((k, v, False))
        elif isinstance(v, list | tuple) and v and isinstance(v[0], dict):
            tables.append((k, v, True))
        else:
            lines.append(f"{k} = {_val(v)}")
    for k, v, many in tables:
        for item in (v if many else [v]):
            lines.append(f"\n[[{k}]]" if many else f"\n[{k}]")
            lines += [f"{kk} = {_val(vv)}" for kk, vv in item.items() if vv is not None]
    return "\n".join(lines) + "\n"


# --- subscriber processes -----------------------------------------------------------------------
def subscriber_main(endpoint: str, ready: Any, results: Any, name: str, stop_after_s: float
                    ) -> None:
    from control.wire.client import Subscriber

    lat: list[float] = []
    blocks = samples = 0
    contiguous = True
    next_first: int | None = None
    run_id = ""
    with Subscriber(endpoint, topics=["block", "event"]) as sub:
        sub.wait_connected(30)
        ready.put(name)
        t_first = t_last = None
        deadline = time.monotonic() + stop_after_s
        while time.monotonic() < deadline:
            msg = sub.recv(timeout_s=1.0)
            if msg is None:
                continue
            h = msg.header
            if msg.topic == "event":
                if run_id and h["message"].startswith(f"run {run_id} "):
                    break
                continue
            run_id = h["run_id"]
            if next_first is not None and h["first_sample"] != next_first:
                contiguous = False
            next_first = h["first_sample"] + h["n_samples"]
            lat.append(msg.received_at - h["t_acquired"])
            blocks += 1
            samples += h["n_samples"] * h["shape"][0]
            t_last = time.monotonic()
            t_first = t_first or t_last
        results.put({"name": name, "blocks": blocks, "values": samples, "lost": sub.lost,
                     "contiguous": contiguous, "latency_s": lat,
                     "span_s": (t_last - t_first) if t_first and t_last else 0.0})


# --- raw pyzmq baseline -------------------------------------------------------------------------
def raw_pub_main(endpoint_q: Any, go: Any, n_msgs: int, rate_hz: float, rows: int, n: int
                 ) -> None:
    import zmq

    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.sndhwm = 1000
    pub.bind("tcp://127.0.0.1:*")
    endpoint_q.put(pub.last_endpoint.decode())
    payload = np.random.default_rng(0).normal(size=(rows, n))
    go.wait()
    t0 = time.monotonic()
    for i in range(n_msgs):
        if rate_hz > 0:
            wait = t0 + i / rate_hz - time.monotonic()
            if wait > 0:
                time.sleep(wait)  # pacing the source, as the DAQ clock does
        header = json.dumps({"topic": "block", "seq": i, "t_acquired": time.time(),
                             "shape": [rows, n]}).encode()
        pub.send_multipart([b"block", header, memoryview(payload).cast("B")], copy=False)
    pub.send_multipart([b"end", b"{}", b""])
    pub.close(linger=5000)
    ctx.term()


def raw_sub_main(endpoint: str, ready: Any, results: Any, name: str) -> None:
    import zmq

    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.subscribe(b"")
    sub.connect(endpoint)
    ready.put(name)
    lat, lost, nxt, values = [], 0, None, 0
    t_first = t_last = None
    while sub.poll(30_000):
        topic, hb, payload = sub.recv_multipart(copy=False)
        if topic.bytes == b"end":
            break
        now = time.time()
        h = json.loads(hb.bytes)
        arr = np.frombuffer(payload.buffer, dtype="<f8")
        values += arr.size
        if nxt is not None and h["seq"] != nxt:
            lost += h["seq"] - nxt
        nxt = h["seq"] + 1
        lat.append(now - h["t_acquired"])
        t_last = time.monotonic()
        t_first = t_first or t_last
    sub.close(0)
    ctx.term()
    results.put({"name": name, "blocks": len(lat), "lost": lost, "latency_s": lat,
                 "values": values, "span_s": (t_last - t_first) if t_first and t_last else 0.0})


def raw_baseline(ctx: Any, n_msgs: int, rate_hz: float, rows: int, n: int) -> list[dict]:
    ep_q, ready, results, go = ctx.Queue(), ctx.Queue(), ctx.Queue(), ctx.Event()
    pub = ctx.Process(target=raw_pub_main, args=(ep_q, go, n_msgs, rate_hz, rows, n))
    pub.start()
    ep = ep_q.get(timeout=60)
    subs = [ctx.Process(target=raw_sub_main, args=(ep, ready, results, f"raw{i}"))
            for i in range(2)]
    for s in subs:
        s.start()
    for _ in subs:
        ready.get(timeout=60)
    # A SUB's subscription reaches the PUB asynchronously; a short grace keeps the first
    # messages from being filtered out (the baseline only, never the system under test).
    time.sleep(0.5)
    go.set()
    out = [results.get(timeout=600) for _ in subs]
    pub.join(60)
    for s in subs:
        s.join(60)
    return out


# --- helpers --------------------------------------------------------------------------------------
def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def pct(x: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(x), q)) if x else float("nan")


def describe(r: dict[str, Any], fs_values: float | None = None) -> str:
    lat_ms = [v * 1e3 for v in r["latency_s"]]
    rate = r["values"] / r["span_s"] / 1e6 if r["span_s"] else float("nan")
    return (f"{r['name']:>6}: {r['blocks']} blocks, lost {r['lost'] or 0}, "
            f"{'contiguous' if r.get('contiguous', True) else 'NOT contiguous'}, "
            f"{rate:.3f} MS/s (AI+AO values), latency ms p50 {pct(lat_ms, 50):.2f} "
            f"p99 {pct(lat_ms, 99):.2f} max {max(lat_ms, default=float('nan')):.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="acquisition to measure [s]")
    ap.add_argument("--dir", type=Path, default=None, help="where the run file goes")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_e2e_", dir=args.dir))
    channels = work / "channels16.toml"
    channels.write_text(channel_map_toml())
    runs = work / "runs"
    cmd = [sys.executable, "-m", "sfdrig", "daemon", "--runs-dir", str(runs), "--channels",
           str(channels)]
    print("daemon:", " ".join(cmd))
    daemon = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, text=True)
    sel = selectors.DefaultSelector()
    sel.register(daemon.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
    if not sel.select(60):
        daemon.kill()
        raise SystemExit("daemon did not start")
    line = daemon.stdout.readline()  # type: ignore[union-attr]
    eps = dict(p.split("=", 1) for p in shlex.split(line))
    print(line.strip())

    from control.wire.client import CommandClient

    mpctx = mp.get_context("spawn")
    ready, results = mpctx.Queue(), mpctx.Queue()
    subs = [mpctx.Process(target=subscriber_main,
                          args=(eps["data"], ready, results, f"sub{i}", args.seconds + 120),
                          daemon=True)
            for i in range(2)]
    for s in subs:
        s.start()
    for _ in subs:
        ready.get(timeout=60)
    # Long enough to outlast the measurement: 3 amplitudes x 5 frequencies x 200 cycles.
    spec = {"name": "bench_e2e", "motion": "x", "lubricated": True,
            "amplitude_m": [13e-6, 25e-6, 38e-6],
            "freq_hz": [20.0, 30.0, 40.0, 50.0, 60.0], "settle_cycles": 10,
            "record_cycles": 400, "control": {"block_s": 0.0125, "ahead_blocks": 3}}
    status: dict[str, Any] = {}
    with CommandClient(eps["command"], timeout_s=20) as c:
        c.pump(True)
        reply = c.start_sweep(spec, operator="bench_e2e")
        while (status := c.status())["samples"] == 0 and status["state"] in ("arming",
                                                                               "running"):
            time.sleep(0.05)
        t0, cpu0, s0 = time.monotonic(), cpu_s(daemon.pid), status["samples"]
        t1, s1 = t0, s0
        while t1 - t0 < args.seconds:
            time.sleep(min(1.0, max(0.0, args.seconds - (t1 - t0))))  # the duration measured
            status = c.status()
            t1, s1 = time.monotonic(), status["samples"]
            if status["state"] not in ("arming", "running", "paused"):
                break
        elapsed, cpu = t1 - t0, cpu_s(daemon.pid) - cpu0
        samples = s1 - s0
        if status["state"] in ("running", "paused"):
            c.abort("bench_e2e: measurement over")
        while c.status()["state"] not in ("idle", "fault"):
            time.sleep(0.2)
        last = c.status()["last_run"]
    sub_results = [results.get(timeout=120) for _ in subs]
    for s in subs:
        s.join(30)
    daemon.send_signal(signal.SIGTERM)
    daemon.wait(60)

    from storage.reader import open_run

    with open_run(reply.data["path"]) as run:
        n_file, n_ch = run.n_samples, len(run.channel_names)
    ai_rate = samples * 16 / elapsed
    print(f"\nrun {reply.data['run_id']}: {last['status']} ({last['reason']})")
    print(f"acquired {samples} samples x 16 AI in {elapsed:.1f} s: {ai_rate / 1e6:.3f} MS/s AI "
          f"aggregate (target >= 1.000); daemon CPU {100 * cpu / elapsed:.0f} % of one core")
    print(f"run file: {n_file} samples x {n_ch} channels (+2 drives), "
          f"{(runs / (reply.data['run_id'] + '.h5')).stat().st_size / 1e6:.0f} MB")
    for r in sub_results:
        print(describe(r))

    block_rows, block_n = 18, int(round(0.0125 * FS_HZ))
    rate_hz = FS_HZ / block_n
    n_msgs = int(rate_hz * min(args.seconds, 20.0))
    raw_paced = raw_baseline(mpctx, n_msgs, rate_hz, block_rows, block_n)
    raw_fast = raw_baseline(mpctx, 4000, 0.0, block_rows, block_n)
    print(f"\nraw pyzmq PUB/SUB, same payload ({block_rows} x {block_n} float64, "
          f"{block_rows * block_n * 8 / 1e3:.0f} kB) at the same {rate_hz:.0f} blocks/s:")
    for r in raw_paced:
        print(describe(r))
    print("raw pyzmq PUB/SUB, same payload, as fast as possible:")
    for r in raw_fast:
        print(describe(r))
    d99 = max(pct(r["latency_s"], 99) for r in sub_results)
    r99 = max(pct(r["latency_s"], 99) for r in raw_paced)
    raw_max = min(r["values"] / r["span_s"] for r in raw_fast if r["span_s"])
    need = 18 * FS_HZ
    print(f"\nratios: daemon p99 latency / raw p99 latency = {d99 / r99:.1f}; raw PUB/SUB capacity"
          f" / the stream's rate = {raw_max / need:.1f}x")
    lost = sum(sum((r["lost"] or {}).values()) if isinstance(r["lost"], dict) else r["lost"]
               for r in sub_results)
    ok = ai_rate >= 0.999e6 and lost == 0 and d99 < 0.050 and elapsed >= args.seconds - 1
    print(f"\nverdict: {'PASS' if ok else 'FAIL'} (>= 1 MS/s for {args.seconds:g} s, 0 lost, "
          f"p99 < 50 ms)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
