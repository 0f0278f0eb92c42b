"""The operator protocol: typed entries are checked for their unit and range, answers only go to
the question that is pending, and every answer and refusal is logged."""

from __future__ import annotations

import pytest

from control.run.programs.operator import Entry, EntryError, OperatorDesk, Question

GAUGE = Entry(name="gauge", label="dial gauge x", quantity="length", unit="in",
              min_si=-2.5e-3, max_si=2.5e-3)


@pytest.mark.parametrize(("text", "metres"), [
    ("0.0020 in", 50.8e-6), ("0.002", 50.8e-6), ("-50.8 um", -50.8e-6), ("2 mil", 50.8e-6),
    ("0.0508mm", 50.8e-6), ("+5.08e-5 m", 50.8e-6), (" 0.002 IN ", 50.8e-6),
])
def test_lengths_in_any_unit(text: str, metres: float) -> None:
    assert GAUGE.parse(text) == pytest.approx(metres, rel=1e-9)


@pytest.mark.parametrize(("text", "says"), [
    ("abc", "'abc' is not a number with a unit"),
    ("5 kg", "'kg' is not a unit of length (use m, mm, um"),
    ("0.5 in", "0.5 in is outside -0.0984252 in .. 0.0984252 in"),
    ("", "'' is not a number"),
    ("1,5 mm", "'1,5 mm' is not a number"),
    ("nan", "not a number"),
])
def test_wrong_entries_say_what_is_wrong(text: str, says: str) -> None:
    with pytest.raises(EntryError) as err:
        GAUGE.parse(text)
    assert str(err.value).startswith("dial gauge x: ")
    assert says in str(err.value)


def test_pressures_and_forces() -> None:
    p = Entry(name="p", label="supply pressure", quantity="pressure", unit="kPa", min_si=0,
              max_si=500e3)
    assert p.parse("15.5") == pytest.approx(15.5e3)
    assert p.parse("2.25 psi") == pytest.approx(15513.2, rel=1e-4)
    assert p.parse("0.155 bar") == pytest.approx(15.5e3)
    f = Entry(name="f", label="force gauge", quantity="force", unit="N", min_si=-500,
              max_si=500)
    assert f.parse("10 lbf") == pytest.approx(44.482, rel=1e-4)


def test_desk_accepts_only_the_pending_question_and_logs_everything() -> None:
    log: list[tuple[str, str]] = []
    desk = OperatorDesk(lambda kind, message: log.append((kind, message)))
    with pytest.raises(EntryError, match="not pending"):
        desk.submit(1, "ok", "")
    q = desk.post(Question(id=0, where="probe_calibration x 1/7", prompt="read the gauge",
                           entry=GAUGE))
    assert desk.pending() == q and q.id == 1
    with pytest.raises(EntryError, match="#2 is not pending"):
        desk.submit(2, "ok", "0.002")
    with pytest.raises(EntryError, match="'reject' is not a choice here"):
        desk.submit(1, "reject", "")
    with pytest.raises(EntryError, match="'kg' is not a unit"):
        desk.submit(1, "ok", "3 kg")
    assert desk.poll() is None and desk.pending() == q  # refusals change nothing
    answer = desk.submit(1, "ok", "0.0020 in")
    assert answer.value_si == pytest.approx(50.8e-6)
    assert desk.pending() is None
    assert desk.poll() == answer and desk.poll() is None
    messages = [m for _, m in log]
    assert messages[1] == "asked #1 (probe_calibration x 1/7): read the gauge"
    assert any("refused entry '3 kg': dial gauge x: 'kg' is not a unit" in m
               for m in messages)
    assert messages[-1] == "answer #1 (probe_calibration x 1/7): ok '0.0020 in' = 0.002 in"
