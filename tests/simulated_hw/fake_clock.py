"""A clock a test moves: a paced simulated board's ``clock`` and ``sleep``."""

from __future__ import annotations


class FakeClock:
    """Time ``t`` [s] that passes only when a test (or a paced backend's ``sleep``) moves it;
    calling it, or ``now()``, reads it."""

    def __init__(self, t: float = 50.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += max(dt, 0.0)
