"""Files of an export written whole or not at all: each to a hidden temporary name beside its
target, renamed into place only when every one is complete."""

from __future__ import annotations

import os
import uuid
from pathlib import Path
from types import TracebackType

from storage.errors import ExportError


class AtomicFiles:
    """Context manager: ``tmp(name)`` is where to write ``out_dir / name``; on a clean exit the
    temporary files are renamed into place, on an error they are removed (nothing half written
    is left). Existing targets are refused unless ``overwrite``."""

    def __init__(self, out_dir: Path, names: list[str], overwrite: bool = False) -> None:
        self.out_dir = out_dir
        self.paths = [out_dir / n for n in names]
        taken = [p for p in self.paths if p.exists()]
        if taken and not overwrite:
            raise ExportError(f"{taken[0]}: exists already (another --out, or --overwrite)")
        tag = uuid.uuid4().hex[:12]
        self._tmp = {n: out_dir / f".{n}.{tag}.tmp" for n in names}

    def tmp(self, name: str) -> Path:
        return self._tmp[name]

    def __enter__(self) -> AtomicFiles:
        return self

    def __exit__(self, kind: type[BaseException] | None, err: BaseException | None,
                 tb: TracebackType | None) -> None:
        if kind is None:
            for name, tmp in self._tmp.items():
                if tmp.exists():
                    os.replace(tmp, self.out_dir / name)
            return
        for tmp in self._tmp.values():
            tmp.unlink(missing_ok=True)
