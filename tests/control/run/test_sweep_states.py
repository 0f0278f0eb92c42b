"""The engine's state machine: only the transitions of the table."""

from __future__ import annotations

import pytest

from control.run.sweep.states import FINAL, TRANSITIONS, State, StateMachine


def test_transitions_follow_the_table_and_report_changes():
    seen = []
    sm = StateMachine(lambda old, new: seen.append((old.value, new.value)))
    for s in (State.CHECKING, State.RUNNING, State.PAUSED, State.RUNNING, State.STOPPING,
              State.COMPLETED):
        sm.to(s)
    assert seen[0] == ("idle", "checking") and seen[-1] == ("stopping", "completed")
    with pytest.raises(RuntimeError, match="illegal state transition completed -> running"):
        sm.to(State.RUNNING)


def _reachable(start: State) -> set[State]:
    """The states reachable from ``start`` through TRANSITIONS (``start`` included)."""
    seen, todo = {start}, [start]
    while todo:
        for nxt in TRANSITIONS[todo.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def test_every_state_ends_in_a_final_one():
    for state in State:
        assert state in TRANSITIONS
        if state in FINAL:
            assert not TRANSITIONS[state]
        else:  # no dead end and no closed loop: some final state can be reached from here
            assert _reachable(state) & FINAL, f"{state.value} cannot reach a final state"
    # and every state is one a run can get to (none is dead code of the table)
    unreachable = set(State) - _reachable(State.IDLE)
    assert not unreachable, f"never reached from idle: {sorted(s.value for s in unreachable)}"
    assert {s for s in State if not TRANSITIONS[s]} == FINAL
    # a run can always be stopped once output may have started
    for state in (State.PRIMING, State.RUNNING, State.PAUSED):
        assert State.STOPPING in TRANSITIONS[state]
    with pytest.raises(RuntimeError, match="idle -> running"):
        StateMachine().to(State.RUNNING)
