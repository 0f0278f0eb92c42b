"""The run file and the wire, field by field, against descriptions written down from the writer
and the publisher as they were before the run's records were typed (issue 42): a reader of old
files and an old subscriber must see the same objects, attributes, rows and JSON keys.

``golden/run_file.json`` is every object of a small run (its kind, dtype, shape and attributes)
and every row of its tables; ``golden/wire.json`` the JSON keys of every live-data header. Times
(stamped at write) and the software version are the only values not compared.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import zmq

from control.run.sweep.step_result import StepResult
from control.wire.publisher import Publisher
from control.wire.step_plan import StepPlan
from storage import RunWriter

GOLDEN = Path(__file__).parent / "golden"
_UNCOMPARED_ATTRS = {"start_time", "stop_time", "software_version", "writer_pid"}


def _value(v: Any) -> Any:
    """An HDF5 attribute or cell as plain JSON (NaN as the string "nan")."""
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.ndarray):
        return [_value(x) for x in v.tolist()]
    if isinstance(v, list):
        return [_value(x) for x in v]
    if isinstance(v, complex | np.complexfloating):
        return [_value(float(v.real)), _value(float(v.imag))]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    return v


def _describe(path: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}

    def visit(name: str, obj: Any) -> None:
        attrs = {k: _value(obj.attrs[k]) for k in sorted(obj.attrs) if k not in _UNCOMPARED_ATTRS}
        if isinstance(obj, h5py.Group):
            out[name] = {"group": True, "attrs": attrs}
            return
        data = obj[()]
        rows: Any
        if data.dtype.names:
            rows = [{k: _value(r[k]) for k in data.dtype.names if k != "time"} for r in data]
        else:
            rows = _value(np.asarray(data)) if data.size <= 64 else None
        out[name] = {"dtype": str(data.dtype), "shape": list(data.shape),
                     "compression": obj.compression, "attrs": attrs, "rows": rows}

    with h5py.File(path, "r") as f:
        out["/"] = {"attrs": {k: _value(f.attrs[k]) for k in sorted(f.attrs)
                              if k not in _UNCOMPARED_ATTRS}}
        f.visititems(visit)
    return out


#: A structure test's step: no excitation, keys beyond the table's columns, a channel the file
#: does not have.
IMPACT_STEP: dict[str, Any] = {
    "index": 2, "freq_hz": 0.0, "target_kind": "load", "target_value": 812.5, "motion": "x",
    "first_sample": 250, "last_sample": 300, "updates": 0, "converged": True, "reason": "",
    "harmonics": {"hammer": [[1.0, 2.0]]}, "drive_v": {},
    "trigger_sample": 260, "hit": 1, "pulse_ms": 0.512, "accepted": True, "rejection": "",
}


def _sweep_step(index: int) -> StepResult:
    plan = StepPlan(index=index, freq_hz=40.0 + index, target_kind="displacement",
                    target_value=2e-5, motion="x", shape=np.array([2e-5, 0j]))
    harm = np.arange(2 * 5, dtype=float).reshape(2, 5) * (1 + 0.5j) * (index + 1)
    return StepResult(plan=plan, first_sample=100 * index, last_sample=100 * index + 80,
                      updates=3, converged=index == 0, reason="" if index == 0 else "limit",
                      harmonics=harm, drive_v=np.array([0.25 - 0.125j]),
                      ai_names=["fx", "x1"], ao_names=["drive_x"], start_sample=100 * index)


def _writer_with_a_block(path: Path) -> RunWriter:
    w = RunWriter(path, "golden-1", "sweep",
                  [{"name": "fx", "units": "N", "kind": "load_cell", "sensor": "PCB 208",
                    "gain_v_per_unit": 0.01, "offset_v": 0.0, "physical_channel": "Dev1/ai0"},
                   "x1"],
                  ["drive_x"], 2000.0, operator="ana", notes="golden", software_version="x",
                  rig_config={"m": 1.0}, test_spec={"freqs": [40, 41]}, lubricated=True,
                  start_time="2026-01-01T00:00:00.000+00:00", flush_interval_s=0.0,
                  board={"backend": "simulated", "device": "Dev1", "description": "sim"})
    rng = np.random.default_rng(7)
    w.on_block(0, rng.normal(size=(2, 300)), rng.normal(size=(1, 300)))
    return w


def _write_run(path: Path) -> None:
    from storage.records import StepRecord
    w = _writer_with_a_block(path)
    w.on_step(_sweep_step(0).to_record())
    w.on_event("limit_trip", "x1 over the limit", 120)
    w.on_step(_sweep_step(1).to_record())
    w.on_event("operator", "a note", 250)
    w.on_step(StepRecord.from_wire(IMPACT_STEP))
    w.close("aborted", "operator abort")


def _write_run_before_records(path: Path) -> None:
    """The same run through the dict the writer took before the typed records."""
    w = _writer_with_a_block(path)
    w.on_step(_sweep_step(0).to_dict())  # type: ignore[arg-type]
    w.on_event("limit_trip", "x1 over the limit", 120)
    w.on_step(_sweep_step(1).to_dict())  # type: ignore[arg-type]
    w.on_event("operator", "a note", 250)
    w.on_step(dict(IMPACT_STEP))  # type: ignore[arg-type]
    w.close("aborted", "operator abort")


def _write(path: Path) -> None:
    try:
        import storage.records  # noqa: F401
    except ImportError:
        _write_run_before_records(path)
    else:
        _write_run(path)


def test_run_file_is_the_golden_layout(tmp_path: Path) -> None:
    path = tmp_path / "golden.h5"
    _write(path)
    got = _describe(path)
    want = json.loads((GOLDEN / "run_file.json").read_text())
    assert sorted(got) == sorted(want)
    for name in want:
        assert got[name] == want[name], name


def _wire_headers() -> dict[str, Any]:
    ctx = zmq.Context.instance()
    pub_sock, sub = ctx.socket(zmq.PUB), ctx.socket(zmq.SUB)
    port = pub_sock.bind_to_random_port("tcp://127.0.0.1")
    sub.connect(f"tcp://127.0.0.1:{port}")
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    pub = Publisher(pub_sock, ["fx", "x1", "drive_x"], 2, 2000.0, block_when_full=True)
    got: dict[str, Any] = {}
    try:
        while not got:  # a PUB drops until the subscription arrives: wait for a first status
            pub.publish_status({"state": "idle"})
            if sub.poll(50):
                topic, header, _ = sub.recv_multipart()
                got[topic.decode()] = json.loads(header)
        pub.set_run("golden-1")
        step: Any = (_sweep_step(1).to_record() if hasattr(StepResult, "to_record")
                     else _sweep_step(1).to_dict())
        pub.on_block(0, np.zeros((2, 4)), np.zeros((1, 4)))
        pub.on_step(step)
        pub.on_event("limit_trip", "x1 over the limit", 120)
        deadline = time.monotonic() + 10
        while len(got) < 4 and time.monotonic() < deadline:
            if sub.poll(100):
                topic, header, _ = sub.recv_multipart()
                got[topic.decode()] = json.loads(header)
    finally:
        pub.close()
        pub_sock.close(0)
        sub.close(0)
    return got


def test_wire_headers_keep_their_keys_and_step_values() -> None:
    got = _wire_headers()
    want = json.loads((GOLDEN / "wire.json").read_text())
    assert {t: list(h) for t, h in got.items()} == want["keys"]
    assert got["step"]["step"] == want["step"]
    assert {k: got["block"][k] for k in want["block"]} == want["block"]


if __name__ == "__main__":  # writes the golden descriptions (once, from the old writer)
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "golden.h5"
        _write_run_before_records(p)
        (GOLDEN / "run_file.json").write_text(json.dumps(_describe(p), indent=1) + "\n")
    h = _wire_headers()
    (GOLDEN / "wire.json").write_text(json.dumps(
        {"keys": {t: list(v) for t, v in h.items()}, "step": h["step"]["step"],
         "block": {k: h["block"][k] for k in ("first_sample", "n_samples", "shape", "dtype",
                                             "n_ai", "channels", "sample_rate_hz", "topic",
                                             "run_id", "seq")}},
        indent=1) + "\n")
