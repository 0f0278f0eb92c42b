"""The daemon's incident log (`storage.incident_log`): what it appends reads back in order with
its time; a torn or foreign line is skipped and counted, never a failure of the whole log."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from storage.incident_log import (
    LOG_NAME,
    MAX_LINE_CHARS,
    append_incident,
    log_path,
    read_incidents,
)


def test_appended_incidents_read_back_in_order(tmp_path):
    assert read_incidents(tmp_path) == ([], 0)  # no log yet
    t0 = datetime(2026, 1, 2, 8, 0, 0, 123000, tzinfo=UTC)
    append_incident(tmp_path, "e-stop", "emergency stop pressed while idle", when=t0)
    append_incident(tmp_path, "watchdog", "the board's watchdog expired while idle")
    records, skipped = read_incidents(tmp_path)
    assert skipped == 0 and log_path(tmp_path).name == LOG_NAME
    assert [(r["incident"], r["what"]) for r in records] == [
        ("e-stop", "emergency stop pressed while idle"),
        ("watchdog", "the board's watchdog expired while idle")]
    assert records[0]["time"] == "2026-01-02T08:00:00.123+00:00"
    assert datetime.fromisoformat(records[1]["time"]) > t0


def test_an_unknown_incident_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="'trip' is not one of e-stop, watchdog"):
        append_incident(tmp_path, "trip", "x")
    assert not log_path(tmp_path).exists()


def test_torn_foreign_and_runaway_lines_are_skipped_and_counted(tmp_path):
    append_incident(tmp_path, "e-stop", "first")
    with open(log_path(tmp_path), "a") as f:
        f.write('{"time": "2026-11-26T08:00:00+00:00", "incident": "e-st')  # torn (power cut)
        f.write("\n[1, 2]\n")  # not a record
        f.write('{"time": 5, "incident": "e-stop", "what": "x"}\n')  # a wrong type
        f.write("x" * (3 * MAX_LINE_CHARS) + "\n")  # runaway
        f.write("\n")  # blank: nothing
    append_incident(tmp_path, "e-stop", "after")
    records, skipped = read_incidents(tmp_path)
    assert [r["what"] for r in records] == ["first", "after"]
    assert skipped == 4
