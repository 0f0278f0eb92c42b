"""`sfdrig web` keeps its threads on one glibc malloc arena (`limit_arenas`): counted by glibc's
own `malloc_stats` in a child process whose threads allocate at once."""

from __future__ import annotations

import subprocess
import sys

import pytest

CHILD = """
import ctypes, ctypes.util, sys, threading
from sfdrig.commands._native_memory import limit_arenas
if sys.argv[1] == "limit":
    print(limit_arenas(1))
libc = ctypes.CDLL(ctypes.util.find_library("c"))
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
go = threading.Barrier(4)
def work():
    go.wait()  # all four allocate together: glibc gives a contending thread an arena of its own
    blocks = [libc.malloc(4096) for _ in range(20000)]
    for b in blocks:
        libc.free(b)
threads = [threading.Thread(target=work) for _ in range(4)]
for t in threads: t.start()
for t in threads: t.join()
libc.malloc_stats()
"""


def _arenas(mode: str) -> tuple[int, str]:
    out = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True,
                         timeout=60, check=True, env={"PATH": "/usr/bin:/bin"})
    return out.stderr.count("Arena "), out.stdout.strip()


def test_limit_arenas_keeps_every_thread_on_one_arena() -> None:
    if sys.platform != "linux":
        pytest.skip("glibc's malloc arenas: Linux only")
    free, _ = _arenas("none")
    one, said = _arenas("limit")
    assert said == "malloc: at most 1 arena(s)"
    assert one == 1
    assert free >= 2  # without it the four threads spread over arenas of their own


TRIM_CHILD = """
import ctypes, ctypes.util, sys
from sfdrig.commands._native_memory import limit_arenas, pin_mmap_threshold, trim_heap
pin_mmap_threshold(), limit_arenas(1)  # as sfdrig web
libc = ctypes.CDLL(ctypes.util.find_library("c"))
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
def anon_kb():
    for line in open("/proc/self/status"):
        if line.startswith("RssAnon:"):
            return int(line.split()[1])
# 40 MiB in 64 KiB blocks (under the mmap threshold: from the heap), written to, each followed
# by a small block that stays in use: freed, they are holes between live blocks, as a request's
# reads leave the heap beside what the frames and the interpreter keep
blocks, kept = [], []
for _ in range(640):
    blocks.append(libc.malloc(64 * 1024))
    kept.append(libc.malloc(16 * 1024))
    ctypes.memset(blocks[-1], 1, 64 * 1024)
for b in blocks:
    libc.free(b)
freed = anon_kb()
print(trim_heap(), freed, anon_kb())
"""


def test_trim_heap_gives_back_the_free_space_between_blocks_in_use() -> None:
    if sys.platform != "linux":
        pytest.skip("glibc's malloc_trim: Linux only")
    out = subprocess.run([sys.executable, "-c", TRIM_CHILD], capture_output=True, text=True,
                         timeout=60, check=True, env={"PATH": "/usr/bin:/bin"})
    said, freed_kb, trimmed_kb = out.stdout.split()
    assert said == "True"
    # glibc keeps the 40 MiB freed between blocks in use resident; the trim gives them back
    assert int(freed_kb) - int(trimmed_kb) > 0.9 * 40 * 1024, out.stdout
