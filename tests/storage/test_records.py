"""The run's records (`storage.records`): a step from outside is checked field by field, the
wire's JSON and the file give back the record that was written."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from storage import RunWriter, open_run
from storage.records import BlockHeader, EventRecord, StepRecord

STEP = StepRecord(index=3, freq_hz=42.5, target_kind="load", target_value=120.0, motion="y",
                  first_sample=1000, last_sample=1800, updates=4, converged=False,
                  reason="limit", harmonics={"fx": (1 + 2j, 0.5 - 0.25j, 0j, 0j, 0.125j),
                                             "hammer": (3j,)},
                  drive_v={"shaker_y": 0.75 - 0.5j, "shaker_z": 1j},
                  extra={"stage": "drive y", "hit": 2})


@pytest.mark.parametrize("bad, says", [
    ({"freq_hz": "fast"}, "step 3: freq_hz must be a number, not 'fast'"),
    ({"first_sample": 1.5}, "step 3: first_sample must be a whole number, not 1.5"),
    ({"motion": 7}, "step 3: motion must be text, not 7"),
    ({"last_sample": True}, "step 3: last_sample must be a whole number, not True"),
    ({"harmonics": {"fx": [[1.0]]}}, "step 3: harmonics.fx must be [re, im], not [1.0]"),
    ({"drive_v": [1, 2]}, "step 3: drive_v must be a mapping of names, not [1, 2]"),
])
def test_a_step_from_outside_names_the_field_that_is_wrong(bad: dict, says: str) -> None:
    with pytest.raises(ValueError) as err:
        StepRecord.from_wire({**STEP.to_wire(), **bad})
    assert str(err.value) == says


def test_the_wire_gives_back_the_record_and_keeps_the_old_keys() -> None:
    wire = STEP.to_wire()
    assert list(wire)[:12] == ["index", "freq_hz", "target_kind", "target_value", "motion",
                               "first_sample", "last_sample", "updates", "converged", "reason",
                               "harmonics", "drive_v"]
    assert wire["harmonics"] == {"fx": [[1.0, 2.0], [0.5, -0.25], [0.0, 0.0], [0.0, 0.0],
                                        [0.0, 0.125]], "hammer": [[0.0, 3.0]]}
    assert (wire["stage"], wire["hit"]) == ("drive y", 2)  # further keys beside the columns
    assert StepRecord.from_wire(wire) == STEP
    # an old producer's minimal dict: the defaults of the writer before the records
    old = StepRecord.from_wire({"freq_hz": 20.0}, index=5)
    assert (old.index, old.first_sample, old.converged, old.target_kind) == (5, -1, False, "")
    assert math.isnan(old.target_value)


def test_the_file_gives_back_the_record_written(tmp_path: Path) -> None:
    with RunWriter(tmp_path / "r.h5", "r1", "sweep", ["fx", "x1"], ["shaker_y"], 1000.0,
                   flush_interval_s=0.0) as w:
        w.on_block(0, np.zeros((2, 2000)), np.zeros((1, 2000)))
        w.on_step(STEP)
        w.on_event("limit_trip", "fx over 448 N", 1500)
    with open_run(tmp_path / "r.h5") as run:
        (got,) = run.step_records
        # the file's channels in their columns; hammer and shaker_z (not in the file) and the
        # further keys through the extra column
        assert got == STEP
        assert run.steps == [STEP.to_wire()]
        assert [(e["kind"], e["message"], e["sample"]) for e in run.events] == [
            ("limit_trip", "fx over 448 N", 1500)]


def test_event_and_block_headers_from_the_wire() -> None:
    ev = EventRecord("fault", "probe x1 lost", 77)
    assert EventRecord.from_wire(ev.to_wire(12.5)) == ev
    assert ev.to_wire(12.5) == {"kind": "fault", "message": "probe x1 lost", "sample": 77,
                                "time": 12.5}
    head = BlockHeader(400, 200, 2, ("fx", "x1", "shaker_x"), 10_000.0, 3.25)
    assert head.to_wire()["shape"] == [3, 200]
    assert BlockHeader.from_wire(head.to_wire()) == head
    with pytest.raises(ValueError, match="n_ai must be a whole number, not 'two'"):
        BlockHeader.from_wire({**head.to_wire(), "n_ai": "two"})
