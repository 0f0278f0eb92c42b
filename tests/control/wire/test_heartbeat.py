"""A status received is checked once, field by field, and read as its type (issue 42): the
client and the subscriber refuse one that is no daemon's status, naming the field."""

from __future__ import annotations

from typing import Any

import pytest

from control.wire.client import CommandClient, DaemonUnavailable, Subscriber
from control.wire.heartbeat import heartbeat_from_wire
from tests.fake_daemon import FakeDaemon, heartbeat


def test_a_whole_status_reads_as_sent_with_a_newer_daemons_keys_kept() -> None:
    sent = heartbeat(state="running", run_id="R1", pump_on=True, newer_field=[1, 2])
    got = heartbeat_from_wire(sent)
    assert got == sent and got["newer_field"] == [1, 2]  # type: ignore[typeddict-item]


@pytest.mark.parametrize(("change", "named"), [
    ({"pump_on": None}, "pump_on"),
    ({"safety": {"radial_clearance_m": 63.5e-6}}, "safety.displacement_limit_m"),
    ({"samples": "many"}, "samples"),
    ({"operator_lease": {"lease_s": 10.0}}, "operator_lease.silent_s"),
])
def test_a_status_missing_or_wrong_in_a_field_is_refused_naming_it(change: dict[str, Any],
                                                                   named: str) -> None:
    status = heartbeat(**change)
    if change.get("pump_on", 0) is None:
        del status["pump_on"]
    with pytest.raises(ValueError, match=rf"status from the daemon: {named}: "):
        heartbeat_from_wire(status)


class OldDaemon(FakeDaemon):
    """A daemon whose status lacks a field this client reads."""

    def status(self) -> dict[str, Any]:
        out = heartbeat()
        del out["film_drains_for_s"]
        return out


def test_the_client_and_the_subscriber_refuse_a_status_that_is_no_daemons() -> None:
    old = OldDaemon("old")
    try:
        with CommandClient(old.command, timeout_s=5) as c, pytest.raises(
                DaemonUnavailable, match="not a daemon's status: .*film_drains_for_s"):
            c.status()
        with Subscriber(old.data, topics=["status"]) as sub, pytest.raises(
                DaemonUnavailable, match=r"no status heartbeat .*film_drains_for_s"):
            sub.wait_connected(timeout_s=0.5)
    finally:
        old.stop()
