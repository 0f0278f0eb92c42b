"""How fast RunWriter stores samples: 16 AI channels (+2 drives) through on_block.

The daemon pushes 16 x 62.5 kS/s = 1 MS/s (AI) through on_block. This script feeds realistic
blocks (sines plus noise, quantised like a 16-bit ADC over +/-10 V, converted to engineering units)
as fast as the writer takes them and reports sustained throughput per compression setting (wall
clock, and per CPU-second, which a shared machine disturbs less), the share of one core the writer
needs at the rig's 1 MS/s, the worst on_block latency, the file size and the read-back speed.

Usage: .venv/bin/python benchmarks/bench_storage.py [--seconds 20] [--block 6250] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from storage import RunWriter, open_run
from storage.records import StepRecord

N_AI = 16
N_AO = 2
FS_HZ = 62_500.0


def make_blocks(n_blocks: int, block: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """A few distinct realistic blocks, reused cyclically (generation must not be timed)."""
    rng = np.random.default_rng(seed)
    lsb_v = 20.0 / 2**16
    gains = rng.uniform(0.01, 8000.0, size=(N_AI, 1))  # V per engineering unit
    out = []
    for b in range(n_blocks):
        t = (np.arange(block) + b * block) / FS_HZ
        volts = (2.0 * np.sin(2 * np.pi * 80.0 * t + np.arange(N_AI)[:, None])
                 + 0.01 * rng.standard_normal((N_AI, block)))
        volts = np.round(volts / lsb_v) * lsb_v
        ao = np.stack([np.sin(2 * np.pi * 80.0 * t), np.cos(2 * np.pi * 80.0 * t)])
        out.append((volts / gains, ao))
    return out


def bench(directory: Path, compression: str, seconds: float, block: int,
          chunk_samples: int | None = None) -> dict[str, float]:
    n_total = int(seconds * FS_HZ)
    blocks = make_blocks(8, block)
    path = directory / f"bench_{compression}.h5"
    w = RunWriter.create(path, "bench", "sweep", [f"ch{i:02d}" for i in range(N_AI)],
                         ["shaker_x", "shaker_y"], FS_HZ, compression=compression,
                         chunk_samples=chunk_samples, max_backlog_s=2 * seconds, overwrite=True)
    latencies = []
    first = 0
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    k = 0
    while first < n_total:
        ai, ao = blocks[k % len(blocks)]
        t_call = time.perf_counter()
        w.on_block(first, ai, ao)
        latencies.append(time.perf_counter() - t_call)
        first += block
        k += 1
        if k % 50 == 0:  # a dwell every 5 s of data at the default block: one step flush
            w.on_step(StepRecord.from_wire({
                "index": k // 50, "freq_hz": 80.0, "first_sample": first - 50 * block,
                       "last_sample": first}))
    w.close()
    elapsed = time.perf_counter() - t0
    cpu_s = time.process_time() - cpu0
    size = path.stat().st_size
    raw = first * (N_AI + N_AO) * 8
    t0 = time.perf_counter()
    with open_run(path) as run:
        for name in run.channel_names:
            run.channel(name)
    read_s = time.perf_counter() - t0
    path.unlink()
    return {
        "ai_msps": first * N_AI / elapsed / 1e6,
        "ai_msps_cpu": first * N_AI / cpu_s / 1e6,
        "core_fraction": cpu_s / (first / FS_HZ),
        "realtime_factor": first / FS_HZ / elapsed,
        "worst_block_ms": max(latencies) * 1e3,
        "p99_block_ms": float(np.percentile(latencies, 99)) * 1e3,
        "ratio": raw / size,
        "size_mb": size / 1e6,
        "read_msps": first * N_AI / read_s / 1e6,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="seconds of data at 62.5 kS/s")
    ap.add_argument("--block", type=int, default=6250, help="samples per on_block call")
    ap.add_argument("--dir", type=Path, default=None, help="where to write (default: a temp dir)")
    ap.add_argument("--chunk", type=int, default=None,
                    help="samples per chunk (default: the writer's, about 1/8 s)")
    args = ap.parse_args()
    print(f"{N_AI} AI + {N_AO} AO channels at {FS_HZ:g} S/s (1.0 MS/s AI aggregate), "
          f"{args.seconds:g} s of data, blocks of {args.block} samples")
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        for compression in ("lzf", "gzip"):
            r = bench(Path(tmp), compression, args.seconds, args.block, args.chunk)
            print(f"{compression:5s}: write {r['ai_msps']:6.2f} MS/s AI wall "
                  f"({r['realtime_factor']:4.1f}x real time), {r['ai_msps_cpu']:6.2f} MS/s per "
                  f"CPU-second ({100 * r['core_fraction']:.0f}% of a core at 1 MS/s), "
                  f"on_block p99 {r['p99_block_ms']:.2f} ms, worst "
                  f"{r['worst_block_ms']:6.1f} ms, file {r['size_mb']:7.1f} MB "
                  f"(ratio {r['ratio']:.2f}), read {r['read_msps']:6.1f} MS/s")


if __name__ == "__main__":
    main()
