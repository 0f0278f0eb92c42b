"""One lane of NI's examples: ``python nidaqmx_example_lane.py JOBS.json [--timeout S]`` runs
the commands of JOBS.json (a list of ``{"name", "argv", "cwd"}``) one after the other, each to
its end, and prints one JSON line per command when it ends: ``{"name", "returncode",
"stdout", "stderr"}`` (``returncode`` None: killed after ``--timeout`` seconds).

`test_nidaqmx_examples_e2e.py` runs several lanes at once, each against a sim-server of its
own: the examples mostly wait on a paced board, so lanes overlap their waits. The examples
are this process's children, not the test process's: the suite's guard against leaked child
processes sees the lane, started with the module, not an example started while a test runs.
"""

from __future__ import annotations

import json
import subprocess
import sys


def main(argv: list[str]) -> int:
    timeout_s = float(argv[argv.index("--timeout") + 1]) if "--timeout" in argv else 120.0
    with open(argv[0]) as f:
        jobs = json.load(f)
    for job in jobs:
        with subprocess.Popen(job["argv"], cwd=job["cwd"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) as proc:
            try:
                out, err = proc.communicate(timeout=timeout_s)
                code: int | None = proc.returncode
            except subprocess.TimeoutExpired:
                proc.kill()
                out, err = proc.communicate()
                code = None
        print(json.dumps({"name": job["name"], "returncode": code, "stdout": out,
                          "stderr": err}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
