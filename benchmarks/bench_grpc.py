"""Sustained AI throughput of `NidaqmxBackend` against `sfdrig sim-server --fast`.

Starts the simulated NI-DAQmx gRPC device server as a separate process on a free loopback port,
configures 16 AI channels (the report's 14 plus two spare terminals), and reads for a fixed time
in blocks of 1,000 and 10,000 samples per channel: AI only (no AO task), then the control
loop's pattern (read a block, write a 2-channel AO block). Also times the rig model alone, in
process, since in fast mode the server computes every sample it sends.

    .venv/bin/python benchmarks/bench_grpc.py [--seconds 3] [--blocks 1000 10000]
"""

from __future__ import annotations

import argparse
import shlex
import signal
import subprocess
import sys
import time

import numpy as np

from daq.channels import AnalogInput, ChannelKind, ChannelMap, default_channel_map
from daq.nidaqmx_backend import NidaqmxBackend
from rig_model import RigModel, RigParams


def sixteen_channel_map(address: str, with_ao: bool) -> ChannelMap:
    cm = default_channel_map()
    spare = tuple(
        AnalogInput(name=f"aux{i}", physical_channel=f"Dev1/ai{i}", kind=ChannelKind.THERMOCOUPLE,
                    units="degC", gain_v_per_unit=0.01)
        for i in (14, 15)
    )
    return cm.model_copy(update={"ai": cm.ai + spare, "grpc_target": address,
                                 "ao": cm.ao if with_ao else (), "do": ()})


def measure(address: str, block: int, seconds: float, with_ao: bool) -> tuple[float, int]:
    """Samples per channel per second, and blocks read."""
    cm = sixteen_channel_map(address, with_ao)
    backend = NidaqmxBackend()
    ao = np.zeros((len(cm.ao), block))
    try:
        backend.configure(cm)
        if with_ao:
            backend.write_ao(ao)
            backend.write_ao(ao)
        backend.start()
        backend.read_ai(block)  # warm-up
        if with_ao:
            backend.write_ao(ao)
        n_blocks = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            backend.read_ai(block)
            if with_ao:
                backend.write_ao(ao)
            n_blocks += 1
        elapsed = time.perf_counter() - t0
        backend.stop()
    finally:
        backend.close()
    return n_blocks * block / elapsed, n_blocks


def rig_only(block: int, seconds: float) -> float:
    cm = sixteen_channel_map("unused:0", True)
    rig = RigModel(RigParams(), cm, 0)
    ao = np.zeros((2, block))
    rig.process(ao)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        rig.process(ao)
        n += 1
    return n * block / (time.perf_counter() - t0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="per measurement")
    parser.add_argument("--blocks", type=int, nargs="+", default=[1_000, 10_000])
    args = parser.parse_args()
    print("command:", shlex.join([sys.executable, *sys.argv]))
    server_cmd = [sys.executable, "-m", "sfdrig", "sim-server", "--port", "0", "--fast"]
    print("server: ", shlex.join(server_cmd))
    proc = subprocess.Popen(server_cmd, stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline().strip() if proc.stdout else ""
        if not line.startswith("listening on "):
            print(f"server did not start: {line!r}", file=sys.stderr)
            return 1
        address = line.removeprefix("listening on ")
        n_ch = 16
        print(f"\n{n_ch} AI channels, float64, loopback gRPC, server --fast "
              f"({args.seconds:g} s per row)")
        print(f"{'pattern':<22}{'block':>8}{'S/s per channel':>18}{'aggregate S/s':>16}"
              f"{'MB/s':>8}{'blocks':>8}")
        for with_ao in (False, True):
            for block in args.blocks:
                rate, blocks = measure(address, block, args.seconds, with_ao)
                pattern = "AI + AO write (2 ch)" if with_ao else "AI only"
                print(f"{pattern:<22}{block:>8}{rate:>18,.0f}{rate * n_ch:>16,.0f}"
                      f"{rate * n_ch * 8 / 1e6:>8.1f}{blocks:>8}")
        for block in args.blocks:
            rate = rig_only(block, args.seconds)
            print(f"{'rig model alone':<22}{block:>8}{rate:>18,.0f}{rate * n_ch:>16,.0f}")
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
