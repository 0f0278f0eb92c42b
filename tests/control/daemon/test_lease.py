"""The operator's lease on its own: its length is the daemon's to set, within bounds, and it
lapses only after that long without a renewal."""

from __future__ import annotations

import pytest

from control.daemon.lease import OperatorLease
from control.wire.protocol import renew_every_s


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_the_lease_lapses_only_after_its_length_without_a_renewal() -> None:
    clock = Clock()
    lease = OperatorLease(4.0, clock)
    clock.t += 3.9
    assert not lease.lapsed()
    lease.renew()
    clock.t += 4.0
    assert not lease.lapsed() and lease.silent_s() == pytest.approx(4.0)
    clock.t += 0.01
    assert lease.lapsed()
    assert lease.reason() == ("operator lost: no heartbeat for 4.0 s (the lease is 4 s: the "
                              "client that started the test hung up or was killed)")
    assert renew_every_s(4.0) == 1.0  # three renewals may be lost before it lapses
    assert OperatorLease(1.0).token != OperatorLease(1.0).token  # each test its own


@pytest.mark.parametrize("seconds", [0.5, 61.0, float("nan")])
def test_a_lease_outside_1_to_60_s_is_refused(seconds: float) -> None:
    with pytest.raises(ValueError, match=r"operator lease .* s is outside 1 \.\. 60 s"):
        OperatorLease(seconds)
