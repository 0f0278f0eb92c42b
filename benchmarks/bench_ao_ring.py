"""AO generation on a busy PC (issue 21): a paced drive session at normal priority beside K
busy-loop processes, on the simulated backend or through nidaqmx against `sfdrig sim-server`.

The session is the sweep's own streaming (`control.run.stream.DriveStream`, 10 ms blocks, 30 ms
lead, the report's 14 AI and 2 AO at 10 kS/s) driving a circular sine that changes frequency
and amplitude every 2 s (seeded), ending each ``--session-s`` with an abort (a ramped stop,
`DriveStream.shutdown`), then starting again. Reported: underflows (-200290, each ends its
session), how often and how late the host was (it had to skip forward: the ring played what it
held), samples the ring repeated, and each abort's time to zero (from the generation count
when the abort was handled to the first sample after which both recorded drives stay 0 V; the
recorded drive is what played, see tests/control/run/test_ao_ring.py).

    .venv/bin/python benchmarks/bench_ao_ring.py --minutes 5 --busy 3 --backend sim
    .venv/bin/python benchmarks/bench_ao_ring.py --minutes 5 --busy 3 --backend nidaqmx
    .venv/bin/python benchmarks/bench_ao_ring.py --minutes 1 --busy 3 --ring-s 0   # the old stream

``--ring-s 0`` is the non-regenerating stream (before the ring). The sim-server runs at normal
priority too (it computes the rig on the same cores; a real board generates by DMA).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time

import numpy as np

BUSY = ("import random, sys, time\n"
        "rng = random.Random(int(sys.argv[1]))\n"
        "end = time.monotonic() + float(sys.argv[2])\n"
        "x = 0.0\n"
        "while time.monotonic() < end:\n"
        "    x += rng.random()\n")


def _backend(kind: str, ring_s: float | None, address: str | None):
    from daq.channels import default_channel_map

    cm = default_channel_map()
    if kind == "sim":
        from simulated_hw.backend import SimulatedBackend

        backend = SimulatedBackend(seed=1, realtime=True, ao_ring_s=ring_s)
    else:
        from daq.nidaqmx_backend import NidaqmxBackend

        cm = cm.model_copy(update={"grpc_target": address})
        backend = NidaqmxBackend(watchdog_timeout_s=1.0 if ring_s else None, ao_ring_s=ring_s)
    backend.configure(cm)
    return backend, cm


def session(backend, cm, seconds: float, rng: np.random.Generator) -> dict:
    """One paced session: drive for ``seconds``, then abort; what happened."""
    from control.run.listener import RecordingListener
    from control.run.safety import SafetyLimits, SafetyMonitor
    from control.run.stream import DriveStream
    from control.signal.synthesis import SineSynthesizer
    from daq.errors import DaqError, DaqUnderflowError, DaqWatchdogExpiredError

    fs = cm.sample_rate_hz
    block = int(0.01 * fs)
    synth = SineSynthesizer(len(cm.ao), fs)
    listener = RecordingListener()
    stream = DriveStream(backend, synth, SafetyMonitor(SafetyLimits(), cm), listener, block,
                         ahead_blocks=3, keep_samples=4 * block)
    stream.check_limits = False
    out: dict = {"underflow_after_s": None, "watchdog_expired_after_s": None, "error": None}
    stream.start()
    t0 = time.monotonic()
    next_change = 0.0
    try:
        while time.monotonic() - t0 < seconds:
            if time.monotonic() - t0 >= next_change:
                amp = float(rng.uniform(0.3, 1.0))
                synth.ramp_to(np.array([amp, 1j * amp]), float(rng.integers(20, 120)), 0.1)
                next_change += 2.0
            stream.cycle()
        abort_at = backend.ao_generated() if backend.ao_ring_samples else stream.sample
    except DaqUnderflowError:
        out["underflow_after_s"] = time.monotonic() - t0
        abort_at = None
    except DaqWatchdogExpiredError:  # the host stalled past the watchdog: the board safed
        out["watchdog_expired_after_s"] = time.monotonic() - t0
        abort_at = None
    except DaqError as err:
        out["error"] = str(err)
        abort_at = None
    stream.shutdown(0.04)
    ao = (np.concatenate([b[2] for b in listener.blocks], axis=1) if listener.blocks
          else np.zeros((len(cm.ao), 0)))
    live = np.flatnonzero(np.any(ao != 0.0, axis=0))
    w = stream.writer
    out.update(
        seconds=time.monotonic() - t0,
        late_events=w.late_events, max_late_ms=1e3 * w.max_late / fs,
        repeated_s=w.repeated / fs,
        min_lead_ms=None if w.min_backlog is None else 1e3 * w.min_backlog / fs,
        abort_to_zero_ms=None if abort_at is None or not len(live)
        else 1e3 * (int(live[-1]) + 1 - abort_at) / fs,
        report=stream.margin_report())
    return out


def run(args: argparse.Namespace, address: str | None) -> list[dict]:
    ring = args.ring_s if args.ring_s > 0 else None
    backend, cm = _backend(args.backend, ring, address)
    rng = np.random.default_rng(args.seed)
    results = []
    end = time.monotonic() + 60 * args.minutes
    try:
        while time.monotonic() < end:
            r = session(backend, cm, min(args.session_s, max(end - time.monotonic(), 1.0)), rng)
            results.append(r)
            print(json.dumps({k: v for k, v in r.items() if k != "report"}), flush=True)
    finally:
        backend.close()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--busy", type=int, default=3, help="busy-loop processes beside it")
    parser.add_argument("--backend", choices=["sim", "nidaqmx"], default="sim")
    parser.add_argument("--ring-s", type=float, default=2.0,
                        help="AO ring [s]; 0: the non-regenerating stream")
    parser.add_argument("--session-s", type=float, default=20.0,
                        help="drive this long, then abort, then start again [s]")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    busy = [subprocess.Popen([sys.executable, "-c", BUSY, str(args.seed + i),
                              str(60 * args.minutes + 120)]) for i in range(args.busy)]
    server = None
    try:
        address = None
        if args.backend == "nidaqmx":
            server = subprocess.Popen([sys.executable, "-m", "sfdrig", "sim-server", "--port",
                                       "0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                      text=True)
            assert server.stdout is not None
            address = server.stdout.readline().strip().removeprefix("listening on ")
        with open("/proc/loadavg") as f:
            load0 = f.read().split()[0]
        results = run(args, address)
        with open("/proc/loadavg") as f:
            load1 = f.read().split()[0]
    finally:
        for p in busy:
            p.kill()
            p.wait(10)
        if server is not None:
            server.send_signal(signal.SIGTERM)
            server.communicate(timeout=10)
    aborts = [r["abort_to_zero_ms"] for r in results if r["abort_to_zero_ms"] is not None]
    late = sum(r["late_events"] for r in results)
    print(f"backend {args.backend}, ring {args.ring_s:g} s, {args.busy} busy processes, "
          f"{sum(r['seconds'] for r in results) / 60:.1f} min in {len(results)} sessions, "
          f"load average {load0} -> {load1}")
    print(f"underflows: {sum(r['underflow_after_s'] is not None for r in results)} "
          f"(after {[round(r['underflow_after_s'], 2) for r in results if r['underflow_after_s']]}"
          f" s)")
    expired = [round(r["watchdog_expired_after_s"], 2) for r in results
               if r["watchdog_expired_after_s"] is not None]
    print(f"watchdog expiries (the host stalled past it; the board set 0 V): {len(expired)} "
          f"(after {expired} s); other errors: "
          f"{[r['error'] for r in results if r['error']]}")
    print(f"host late {late} times, its next sample at worst "
          f"{max(r['max_late_ms'] for r in results):.1f} ms short of the generation + margin; "
          f"played from the ring while late: {sum(r['repeated_s'] for r in results):.2f} s")
    if aborts:
        print(f"abort to 0 V: {len(aborts)} aborts, max {max(aborts):.1f} ms, median "
              f"{float(np.median(aborts)):.1f} ms")


if __name__ == "__main__":
    main()
