"""A clock a test moves: a paced simulated board's ``clock`` and ``sleep``."""

from __future__ import annotations


class FakeClock:
    def __init__(self) -> None:
        self.t = 50.0

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += max(dt, 0.0)
