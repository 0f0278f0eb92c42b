"""The C heap of the daemon and of `sfdrig web`: a fixed glibc mmap threshold, so that the
resident size of a process running day-long does not climb with what it has freed.

glibc serves an allocation of at least ``M_MMAP_THRESHOLD`` bytes (128 KiB at start) with its
own ``mmap`` and gives it back to the kernel when it is freed. By default the threshold is
dynamic: each time such a block is freed, the threshold rises to its size (up to 32 MiB), and
the heap trim threshold to twice that. In the daemon the first run frees arrays of samples of a
few MB, so from then on every array of a run is carved from the malloc arenas instead, and the
run's new threads (run writer, I/O thread, compression pool) each take over some arena: freed
space stayed scattered over the arenas, which grew run after run. Measured (fast mode, a 4 s
one-step sweep, 14 channels at 10 kS/s, 200 runs on one daemon; mallinfo2): 28-32 MB in use
throughout but 5 -> 34 MB held free, RSS 253 MB after run 1, 270 after run 15, 279 after run
100. With the threshold fixed at its starting value (and one compression pool for all runs,
`Daemon.deflate_pool`): 243, 248, 252 MB, 255 MB after run 200; in a second daemon 259 MB
after run 100, 260 after 200, 262 after 400 (12 kB a run over runs 200-400, 8 over 300-400).
``malloc_trim(0)`` after each run instead did not help (267 MB after run 200).

`sfdrig web` had the same growth: a transfer-function request (`web.history`) frees segment
arrays of 800 kB, and the default executor's threads, which also make the frames, then carved
such arrays from their arenas. Over a 30-min sweep with a request at each new step (benchmarks,
`bench_web --transfer`) its thread arenas grew 8.8 -> 31.1 MB (RSS 104 -> 129 MB); with the
threshold fixed, 3.0 -> 7.1 MB (RSS 100 -> 106 MB, +0.18 MB/min). What still grew were the
arenas of the executor's threads: `sfdrig web` also keeps all its threads on glibc's main arena
(`limit_arenas`): with ``MALLOC_ARENA_MAX=1`` the same 30 min gave 99 -> 103 MB (+0.07 MB/min),
as flat as the live frames alone. A web server's few threads do not contend for it.

What glibc still keeps is free space inside the heap: it gives back only the free space at the
heap's top, by itself, never holes under blocks still in use. In a 30-min sweep with transfer
requests (`bench_web --transfer`, resident memory by mapping every 10 s) the heap went 15.0 ->
66.8 MB within 10 s about 9.5 min in, while 14.5-17.6 MB of it was in use for the rest of the
run: 50 MB free and resident for 20 min. (What allocated them at once is not known: no Python
objects, HDF5's free lists unchanged; replaying the same steps' transfers on the same file in
one process did not do it.) So `sfdrig web` calls `trim_heap` (``malloc_trim(0)``, which also
hands back the pages inside free chunks) after each transfer request: once a step, 5-13 ms
(40 MB in 640 holes, loaded machine).

The cost: arrays of 128 KiB or more are mmapped and unmapped each time (page faults). At 1 MS/s
(16 AI x 62.5 kS/s, `benchmarks/bench_e2e.py --seconds 15` at ``--priority realtime``, load
12-18) the daemon used 22 and 24 % of a core, against 23 and 22 % with the threshold fixed at
32 MiB (where the dynamic one ends up), 0 blocks lost in all four.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os

log = logging.getLogger("sfdrig.daemon")

M_MMAP_THRESHOLD = -3  # glibc <malloc.h>
M_ARENA_MAX = -8
DEFAULT_MMAP_THRESHOLD = 128 * 1024  # glibc's own starting value [bytes]


def _mallopt(param: int, value: int) -> bool | None:
    """glibc's ``mallopt(param, value)``: True if taken, False if refused, None without glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(param, value) == 1)


def pin_mmap_threshold(nbytes: int = DEFAULT_MMAP_THRESHOLD) -> str:
    """Fix glibc's mmap threshold at ``nbytes`` for this process (which also stops the dynamic
    heap trim threshold); returns what was done, for the log. Does nothing when the C library
    is not glibc, or when ``MALLOC_MMAP_THRESHOLD_`` is set in the environment (the operator's
    choice wins)."""
    env = os.environ.get("MALLOC_MMAP_THRESHOLD_")
    if env is not None:
        return f"malloc: MALLOC_MMAP_THRESHOLD_={env} (environment)"
    taken = _mallopt(M_MMAP_THRESHOLD, int(nbytes))
    if taken is None:
        return "malloc: not glibc, mmap threshold left as it is"
    if not taken:
        log.warning("mallopt(M_MMAP_THRESHOLD, %d) refused", nbytes)
        return "malloc: mmap threshold could not be fixed"
    return f"malloc: mmap threshold fixed at {nbytes // 1024} KiB"


def limit_arenas(n: int = 1) -> str:
    """Keep this process's threads on at most ``n`` glibc malloc arenas (call it before the
    threads start); returns what was done, for the log. Does nothing when the C library is not
    glibc, or when ``MALLOC_ARENA_MAX`` is set in the environment (the operator's choice)."""
    env = os.environ.get("MALLOC_ARENA_MAX")
    if env is not None:
        return f"malloc: MALLOC_ARENA_MAX={env} (environment)"
    taken = _mallopt(M_ARENA_MAX, int(n))
    if taken is None:
        return "malloc: not glibc, arenas left as they are"
    if not taken:
        log.warning("mallopt(M_ARENA_MAX, %d) refused", n)
        return "malloc: arena count could not be limited"
    return f"malloc: at most {n} arena(s)"


def trim_heap() -> bool | None:
    """glibc's ``malloc_trim(0)``: hand the free pages inside the malloc heap back to the kernel
    (not only those at its top, which glibc gives back by itself). True if some were, False if
    none, None without glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        malloc_trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    malloc_trim.argtypes = [ctypes.c_size_t]
    malloc_trim.restype = ctypes.c_int
    return bool(malloc_trim(0))
