"""The operator's lease on a test that waits for a person.

A structure test holds the rig for a person: the shakers hold a static load (or the pump runs)
while a question waits for an answer. If the front end that started it is lost (its terminal
hung up, its process killed, the page's browser gone), nobody is left to answer, abort or
notice; the rig must not stay loaded until someone runs `sfdrig abort`. So the client that
starts a test gets a lease (a token from the ``start_test`` reply) and renews it with ``alive``
requests (`control.wire.protocol.renew_every_s`); the daemon's command loop aborts the test
the safe way (drives ramped to zero, the run file closed "aborted" with the reason) once the
lease has gone unrenewed for its length.

A sweep has no lease: it runs to its plan under the daemon's own safety limits and ends with the
drives ramped to zero whether or not anyone follows it (`sfdrig sweep --no-follow` is the same
run). The lease is the daemon's safety setting (`sfdrig daemon --operator-lease-s`), never the
client's: a client cannot ask for a test that outlives it for an hour.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable

#: The lease lengths a daemon may be given [s]: below 1 s a loaded PC's client misses renewals;
#: above 60 s a lost operator leaves the rig loaded for a minute.
LEASE_RANGE_S = (1.0, 60.0)

class OperatorLease:
    """One test's lease: its token, its length and when it was last renewed."""

    def __init__(self, seconds: float, clock: Callable[[], float] = time.monotonic) -> None:
        low, high = LEASE_RANGE_S
        if not low <= seconds <= high:
            raise ValueError(f"operator lease {seconds:g} s is outside {low:g} .. {high:g} s")
        self.token = secrets.token_hex(8)
        self.seconds = seconds
        self._clock = clock
        self._renewed = clock()

    def renew(self) -> None:
        self._renewed = self._clock()

    def silent_s(self) -> float:
        """Seconds since the last renewal (or the start)."""
        return self._clock() - self._renewed

    def lapsed(self) -> bool:
        return self.silent_s() > self.seconds

    def reason(self) -> str:
        """Why the test is aborted when the lease lapses (the run file's and status's reason)."""
        return (f"operator lost: no heartbeat for {self.silent_s():.1f} s (the lease is "
                f"{self.seconds:g} s: the client that started the test hung up or was killed)")


__all__ = ["LEASE_RANGE_S", "OperatorLease"]
