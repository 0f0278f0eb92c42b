"""The samples of a run into their HDF5 datasets, chunk by chunk: what `RunWriter` hands over
becomes whole chunks (gzip chunks shuffled and deflated in a thread pool, then written directly
as HDF5's filter pipeline would have stored them) and, at a flush, the partly filled last chunk.
The file's layout is `storage.layout`; the threads, locks and flushing are `storage.runfile`."""

from __future__ import annotations

import os
import zlib
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np


class ChunkWriter:
    """Appends blocks of samples (one row per dataset) to equally long 1-D datasets.

    Not thread-safe: its owner calls it under its I/O lock.

    Parameters
    ----------
    datasets : sequence of h5py.Dataset
        One resizable dataset per row, chunked by ``chunk_samples``.
    chunk_samples : int
        Samples per chunk.
    compression : {"gzip", "lzf"}
        The datasets' filter; gzip chunks are compressed here, lzf by HDF5.
    pool : ThreadPoolExecutor or None
        Where gzip chunks are compressed (None: in the calling thread).
    """

    def __init__(self, datasets: Sequence[h5py.Dataset], chunk_samples: int, compression: str,
                 pool: ThreadPoolExecutor | None) -> None:
        self._dsets = list(datasets)
        self.chunk_samples = int(chunk_samples)
        self._gzip = compression == "gzip"
        self._pool = pool
        # samples after the last chunk boundary: whole chunks leave it compressed and written
        # directly; a flush writes the rest plainly and rewrites it once its chunk is whole
        self._tail = np.empty((len(self._dsets), 0))
        self._tail_start = 0  # sample index of _tail[:, 0], a multiple of chunk_samples
        self._tail_written = 0  # leading samples of _tail already in the datasets (flushes)

    @property
    def written(self) -> int:
        """Samples in the datasets."""
        return self._tail_start + self._tail_written

    @property
    def holds_unwritten(self) -> bool:
        """Whether samples wait for their chunk to fill (a flush would write them)."""
        return self._tail.shape[1] > self._tail_written

    def write(self, blocks: Sequence[np.ndarray], whole_chunks_only: bool = False) -> None:
        """Append ``blocks`` (each (n_datasets, n)): every completed chunk into the datasets,
        and with ``whole_chunks_only=False`` also the partly filled last chunk (for a flush)."""
        if blocks:
            self._tail = np.concatenate([self._tail, *blocks], axis=1)
        chunk = self.chunk_samples
        n_full = (self._tail.shape[1] // chunk) * chunk
        if n_full:
            self._write_chunks(self._tail_start, self._tail[:, :n_full])
            self._tail = self._tail[:, n_full:].copy()
            self._tail_start += n_full
            self._tail_written = 0
        n_tail = self._tail.shape[1]
        if not whole_chunks_only and n_tail > self._tail_written:
            a, b = self._tail_start + self._tail_written, self._tail_start + n_tail
            for row, ds in enumerate(self._dsets):
                ds.resize((b,))
                ds[a:b] = self._tail[row, self._tail_written:]
            self._tail_written = n_tail

    def _write_chunks(self, start: int, data: np.ndarray) -> None:
        """Write whole chunks ``data`` (n_datasets, k * chunk_samples) at sample ``start``."""
        stop = start + data.shape[1]
        if not self._gzip:
            for row, ds in enumerate(self._dsets):
                ds.resize((stop,))
                ds[start:stop] = data[row]
            return
        chunk = self.chunk_samples
        jobs = [(row, k) for row in range(data.shape[0]) for k in range(0, data.shape[1], chunk)]

        def compress(job: tuple[int, int]) -> bytes:
            row, k = job
            return shuffle_deflate(data[row, k:k + chunk])

        blobs = list(self._pool.map(compress, jobs) if self._pool else map(compress, jobs))
        for ds in self._dsets:
            ds.resize((stop,))
        for (row, k), blob in zip(jobs, blobs, strict=True):
            self._dsets[row].id.write_direct_chunk((start + k,), blob, 0)


def deflate_pool(name: str = "RunWriter-deflate") -> ThreadPoolExecutor | None:
    """A thread pool for `RunWriter`'s gzip chunks (zlib releases the GIL), or None on one
    core (then each writer compresses on its I/O thread)."""
    n = min(4, os.cpu_count() or 1)
    return ThreadPoolExecutor(max_workers=n, thread_name_prefix=name) if n > 1 else None


def shuffle_deflate(x: np.ndarray) -> bytes:
    """One chunk as HDF5's filter pipeline (shuffle, then deflate level 1) would store it."""
    shuffled = np.ascontiguousarray(
        np.ascontiguousarray(x, dtype="<f8").view(np.uint8).reshape(-1, 8).T
    )
    return zlib.compress(shuffled.data, 1)
