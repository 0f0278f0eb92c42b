"""The harmonics a client computes from the published blocks: the controller's own lock-in
(`control.signal.lockin.LockIn`), offered here so that clients import only `control.wire` and
what the page shows is what the controller measured."""

from __future__ import annotations

from control.signal.lockin import LockIn

__all__ = ["LockIn"]
