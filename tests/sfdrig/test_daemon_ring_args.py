"""`sfdrig daemon --ao-ring-s`: the ring by default, sized against the board's watchdog, refused
where nothing would stop a hung host's ring."""

from __future__ import annotations

import argparse

import pytest

from sfdrig.commands import daemon


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    daemon.add_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize(("argv", "ring"), [
    ((), 2.0),                                             # the simulated rig: 2 s
    (("--ao-ring-s", "0"), None),                          # the old stream
    (("--ao-ring-s", "1.5"), 1.5),
    (("--backend", "nidaqmx"), 2.0),                       # watchdog 1 s: 2 s >= 1.2 s
    (("--backend", "nidaqmx", "--watchdog-s", "2"), 3.0),  # whole seconds >= 2.2 s
    (("--backend", "nidaqmx", "--watchdog-s", "0"), None),  # no watchdog: no ring
])
def test_the_ring_the_arguments_ask_for(argv, ring):
    assert daemon.ao_ring_s(_args(*argv)) == ring


@pytest.mark.parametrize("argv", [
    ("--backend", "nidaqmx", "--ao-ring-s", "1", "--watchdog-s", "1"),
    ("--backend", "nidaqmx", "--ao-ring-s", "2", "--watchdog-s", "0"),
    ("--ao-ring-s", "0.1"),
])
def test_a_ring_without_a_short_enough_watchdog_is_refused(argv, capsys):
    assert daemon.run(_args(*argv)) == 2
    err = capsys.readouterr().err
    assert err.startswith("daemon: --ao-ring-s"), err


@pytest.mark.parametrize("value", ["-1", "7200", "nan"])
def test_a_film_drain_time_out_of_range_is_refused(value, capsys):
    assert daemon.run(_args("--film-drain-s", value)) == 2
    assert capsys.readouterr().err == \
        f"daemon: --film-drain-s {float(value):g} must be 0..3600 s\n"


@pytest.mark.parametrize("value", ["0.5", "61", "nan"])
def test_an_operator_lease_out_of_range_is_refused(value, capsys):
    assert daemon.run(_args("--operator-lease-s", value)) == 2
    assert capsys.readouterr().err == \
        f"daemon: --operator-lease-s {float(value):g} must be 1..60 s\n"
