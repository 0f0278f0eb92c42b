"""Helper processes for the storage tests (run as scripts, never imported by runtime code).

``writer PATH``: writes a deterministic run forever, printing ``flushed N`` whenever the flushed
sample count grows, until killed.
``reader PATH``: for every line ``read`` on stdin, refreshes the open run and prints
``n_samples steps events sum_fx``; exits on ``quit``.
"""

from __future__ import annotations

import sys

import numpy as np

from storage import RunWriter, open_run
from storage.records import StepRecord

N_AI = 4
N_AO = 2
BLOCK = 1000
FS_HZ = 10_000.0


def expected_block(first_sample: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The deterministic samples of the test run: channel c at sample k is c + sin(k * (c+1)/97)."""
    k = np.arange(first_sample, first_sample + n, dtype=np.float64)
    ai = np.stack([c + np.sin(k * (c + 1) / 97.0) for c in range(N_AI)])
    ao = np.stack([-c - np.cos(k * (c + 1) / 89.0) for c in range(N_AO)])
    return ai, ao


def run_writer(path: str) -> None:
    w = RunWriter.create(
        path, "killed-run", "sweep", [f"c{i}" for i in range(N_AI)],
        [f"d{i}" for i in range(N_AO)], FS_HZ, flush_interval_s=0.05, chunk_samples=4096,
    )
    first = 0
    reported = -1
    while True:
        ai, ao = expected_block(first, BLOCK)
        w.on_block(first, ai, ao)
        first += BLOCK
        if first % (20 * BLOCK) == 0:
            w.on_step(StepRecord.from_wire({"index": first // (20 * BLOCK) - 1, "freq_hz": 10.0,
                       "first_sample": first - 20 * BLOCK, "last_sample": first}))
            # the I/O thread would write and flush the step soon; this unpaced writer flushes it
            # now, so that a flush report implies the steps before it and it cannot outrun the
            # disk (a paced acquisition never needs to)
            w.flush()
        if w.samples_flushed != reported:
            reported = w.samples_flushed
            print(f"flushed {reported}", flush=True)


def run_reader(path: str) -> None:
    with open_run(path) as run:
        for line in sys.stdin:
            cmd = line.strip()
            if cmd == "quit":
                break
            run.refresh()
            n = run.n_samples
            total = float(run.channel("c0").sum()) if n else 0.0
            print(f"{n} {len(run.steps)} {len(run.events)} {total!r}", flush=True)


if __name__ == "__main__":
    role, file_path = sys.argv[1], sys.argv[2]
    {"writer": run_writer, "reader": run_reader}[role](file_path)
