"""What diagnose works on: measured runs (force in, responses out) and their segments.

A `RunRecord` holds one run's force on the housing (N, both axes; zeros for an absent axis), its
displacement response channels (m; each probe separately, so redundant probes can arbitrate a
sensor fault), the accelerometers and oil temperature when present, and its segments: the
recorded span of each dwell (sweep runs) or fixed-length blocks / user spans (other runs).
Training and held-out sets are lists of whole segments, never samples of one segment.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig_model.params import RigParams, rig_params_from_dict


class DiagnoseError(ValueError):
    """Bad input to diagnose: the message names the file, option or value at fault."""


@dataclass(frozen=True)
class Segment:
    """A half-open sample span ``[start, stop)`` of run ``run`` (index into the record list).

    ``freq_hz`` is the dwell frequency (None for non-periodic segments); ``label`` names it in
    tables and figures.
    """

    run: int
    start: int
    stop: int
    label: str
    freq_hz: float | None = None
    motion: str = ""

    @property
    def n(self) -> int:
        return self.stop - self.start


@dataclass
class RunRecord:
    """One measured run, in engineering units (SI).

    Attributes
    ----------
    name : str
        Run file name (or a label for array input).
    sample_rate_hz : float
    force_n : ndarray, shape (2, n)
        Force on the housing along x and y [N] (zeros for an axis not recorded).
    responses : dict of str -> ndarray (n,)
        Displacement channels [m] (probes x1, x2, y1, y2, or "x"/"y" of imported runs).
    response_axis : dict of str -> int
        0 for an x channel, 1 for y.
    accel : dict of str -> ndarray (n,)
        Accelerometers ax, ay [m/s^2] when present (in the fitted objective beside the
        displacement channels; see `objective_channels`).
    velocity : dict of str -> ndarray (n,)
        Velocity channels vx, vy [m/s] when present (in the objective too).
    derived_displacement : bool
        The displacement channels were rebuilt from velocity or acceleration at import (they
        hold no information of their own: the sources stay out of the objective).
    t_oil_c : ndarray or None
        Oil temperature [degC] when recorded.
    lubricated : bool
        Film on (fill 1) or dry (fill 0).
    kind : str
        Run kind ("sweep", "imported", ...).
    rig : RigParams or None
        The rig configuration the run was recorded with (None for real or imported data).
    segments : list of Segment
        Dwells (sweep runs) or blocks.
    """

    name: str
    sample_rate_hz: float
    force_n: np.ndarray
    responses: dict[str, np.ndarray]
    response_axis: dict[str, int]
    accel: dict[str, np.ndarray] = field(default_factory=dict)
    velocity: dict[str, np.ndarray] = field(default_factory=dict)
    derived_displacement: bool = False
    t_oil_c: np.ndarray | None = None
    lubricated: bool = False
    kind: str = "sweep"
    rig: RigParams | None = None
    segments: list[Segment] = field(default_factory=list)

    @property
    def n_samples(self) -> int:
        return int(self.force_n.shape[1])

    @property
    def axes(self) -> set[int]:
        return set(self.response_axis.values())

    def objective_channels(self) -> dict[str, tuple[int, str]]:
        """Every measured response the fit compares with the model: name -> (axis, quantity).

        Displacement channels (probes), then velocity and acceleration channels (one
        accelerometer per axis beside one probe is the pair that tells a sensor fault from
        the rig). Quantity is "displacement", "velocity" or "acceleration".
        """
        out = {ch: (ax, "displacement") for ch, ax in self.response_axis.items()}
        if not self.derived_displacement:
            for chans, q in ((self.velocity, "velocity"), (self.accel, "acceleration")):
                for ch in chans:
                    out[ch] = (0 if ch.endswith("x") else 1, q)
        return out

    def signal(self, ch: str) -> np.ndarray:
        """The samples of objective channel ``ch`` (its own SI units)."""
        for chans in (self.responses, self.velocity, self.accel):
            if ch in chans:
                return chans[ch]
        raise KeyError(f"{self.name}: no response channel {ch!r}")


_PROBE = re.compile(r"^([xy])\d+$")


def load_run(path: str | Path, run_index: int = 0) -> RunRecord:
    """Read one run file (contract B) into a `RunRecord`.

    Raises `DiagnoseError` naming the file when it lacks a force or a displacement signal.
    """
    from storage.errors import RunFileError
    from storage.reader import open_run

    path = Path(path)
    try:
        run = open_run(path)
    except RunFileError as err:
        raise DiagnoseError(str(err)) from None
    with run:
        names = list(run.channel_names)
        n = run.n_samples
        if n < 16:
            raise DiagnoseError(f"{path}: only {n} samples recorded; nothing to diagnose")
        force = np.zeros((2, n))
        have_force = False
        for axis, nm in enumerate(("fx", "fy")):
            if nm in names:
                force[axis] = run.channel(nm)
                have_force = True
        if not have_force:
            raise DiagnoseError(f"{path}: no force channel 'fx' or 'fy' (channels {names})")
        responses: dict[str, np.ndarray] = {}
        axis_of: dict[str, int] = {}
        for nm in names:
            m = _PROBE.match(nm)
            if m:
                responses[nm] = run.channel(nm)
                axis_of[nm] = 0 if m.group(1) == "x" else 1
        for axis, nm in enumerate(("x", "y")):
            if nm in names and not any(a == axis for a in axis_of.values()):
                responses[nm] = run.channel(nm)
                axis_of[nm] = axis
        if not responses:
            raise DiagnoseError(
                f"{path}: no displacement channel (x, y or probes x1, x2, y1, y2; channels {names})"
            )
        for nm in list(responses):
            if not np.all(np.isfinite(responses[nm])):
                raise DiagnoseError(f"{path}: channel {nm!r} holds NaN or infinite samples")
        if not np.all(np.isfinite(force)):
            raise DiagnoseError(f"{path}: the force channels hold NaN or infinite samples")
        accel: dict[str, np.ndarray] = {nm: run.channel(nm) for nm in ("ax", "ay")
                                        if nm in names}
        velocity: dict[str, np.ndarray] = {nm: run.channel(nm) for nm in ("vx", "vy")
                                           if nm in names}
        for nm, v in {**accel, **velocity}.items():
            if not np.all(np.isfinite(v)):
                raise DiagnoseError(f"{path}: channel {nm!r} holds NaN or infinite samples")
        derived = any("derived from" in str(run.channel_attrs(nm).get("sensor", ""))
                      for nm in responses)
        t_oil = run.channel("t_oil") if "t_oil" in names else None
        rig = None
        if run.rig_config:
            rig = rig_params_from_dict(run.rig_config, f"{path} (rig_config attribute)")
        segments = [
            Segment(run_index, int(s["first_sample"]), int(s["last_sample"]),
                    f"{path.stem}#{s['index']}", float(s["freq_hz"]), str(s.get("motion", "")))
            for s in run.steps
            if 0 <= int(s["first_sample"]) < int(s["last_sample"]) <= n
        ]
        return RunRecord(
            name=path.name, sample_rate_hz=run.sample_rate_hz, force_n=force,
            responses=responses, response_axis=axis_of, accel=accel, velocity=velocity,
            derived_displacement=derived, t_oil_c=t_oil,
            lubricated=bool(run.attrs.get("lubricated", False)), kind=run.kind, rig=rig,
            segments=segments,
        )


def parse_spans(text: str | None, what: str = "--train") -> list[tuple[int, int]] | None:
    """Parse ``"a:b,c:d"`` into half-open sample spans; None for None/empty.

    Raises `DiagnoseError` naming the option and the bad item.
    """
    if text is None or not text.strip():
        return None
    spans = []
    for item in text.split(","):
        item = item.strip()
        m = re.fullmatch(r"(\d+)\s*:\s*(\d+)", item)
        if not m:
            raise DiagnoseError(f"{what}: {item!r} is not a sample span 'start:stop'")
        a, b = int(m.group(1)), int(m.group(2))
        if b <= a:
            raise DiagnoseError(f"{what}: span {item!r} is empty (stop must exceed start)")
        spans.append((a, b))
    return spans


def blocks(run: int, start: int, stop: int, block: int, prefix: str) -> list[Segment]:
    """Cut ``[start, stop)`` into consecutive segments of about ``block`` samples."""
    k = max(1, int(round((stop - start) / block)))
    edges = np.linspace(start, stop, k + 1).astype(int)
    return [Segment(run, int(a), int(b), f"{prefix}[{a}:{b}]") for a, b in zip(edges[:-1],
                                                                              edges[1:],
                                                                              strict=True)]


def split_segments(
    records: list[RunRecord],
    train_spans: list[tuple[int, int]] | None = None,
    test_spans: list[tuple[int, int]] | None = None,
    test_every: int = 3,
    block_s: float = 2.0,
) -> tuple[list[Segment], list[Segment]]:
    """Training and held-out segments.

    With spans, they apply to every run (sample indices of each run): each span is cut into
    blocks of about ``block_s`` seconds, so the bootstrap has several held-out segments. Without
    spans, whole dwells are split: of the dwells of each motion (x, y, circular...), in step
    order, every ``test_every``-th is held out, starting with the second. Runs without dwells
    are cut into blocks, alternately assigned.
    Raises `DiagnoseError` for spans outside a run or overlapping between the two sets.
    """
    train: list[Segment] = []
    test: list[Segment] = []
    if (train_spans is None) != (test_spans is None):
        raise DiagnoseError("give both --train and --test spans, or neither")
    if train_spans is not None and test_spans is not None:
        for a, b in train_spans:
            for c, d in test_spans:
                if a < d and c < b:
                    raise DiagnoseError(
                        f"--train span {a}:{b} overlaps --test span {c}:{d}: held-out samples "
                        "must never be used for fitting"
                    )
        for ri, rec in enumerate(records):
            block = max(64, int(block_s * rec.sample_rate_hz))
            for spans, out, what in ((train_spans, train, "--train"), (test_spans, test, "--test")):
                for a, b in spans:
                    if b > rec.n_samples:
                        raise DiagnoseError(
                            f"{what} span {a}:{b} runs past the end of {rec.name} "
                            f"({rec.n_samples} samples)"
                        )
                    out.extend(blocks(ri, a, b, block, rec.name))
        return train, test
    for ri, rec in enumerate(records):
        if rec.segments:
            # stratified by motion, so that each motion (x, y, circular) is held out too
            count: dict[str, int] = {}
            for seg in rec.segments:
                j = count.get(seg.motion, 0)
                count[seg.motion] = j + 1
                (test if j % test_every == 1 else train).append(seg)
        else:
            block = max(64, int(block_s * rec.sample_rate_hz))
            for j, seg in enumerate(blocks(ri, 0, rec.n_samples, block, rec.name)):
                (test if j % 2 == 1 else train).append(seg)
    if not train or not test:
        raise DiagnoseError(
            f"cannot split the data into training and held-out sets ({len(train)} training, "
            f"{len(test)} held-out segments): record more dwells or give --train and --test"
        )
    return train, test


def records_from_arrays(
    force_n: np.ndarray,
    responses: dict[str, np.ndarray],
    sample_rate_hz: float,
    name: str = "arrays",
    kind: str = "imported",
    rig: RigParams | None = None,
    lubricated: bool = False,
    extra: dict[str, Any] | None = None,
) -> RunRecord:
    """A `RunRecord` from numpy arrays (force (2, n) or (n,) along x [N]; responses [m])."""
    f = np.atleast_2d(np.asarray(force_n, dtype=np.float64))
    if f.shape[0] == 1:
        f = np.vstack([f, np.zeros_like(f)])
    axis = {nm: (1 if nm.startswith("y") else 0) for nm in responses}
    return RunRecord(name=name, sample_rate_hz=float(sample_rate_hz), force_n=f,
                     responses={k: np.asarray(v, dtype=np.float64) for k, v in responses.items()},
                     response_axis=axis, kind=kind, rig=rig, lubricated=lubricated,
                     **(extra or {}))


def split_by_runs(records: list[RunRecord], train_runs: list[int],
                  block_s: float = 2.0) -> tuple[list[Segment], list[Segment]]:
    """Train on whole runs, judge on the others (``--train-runs`` / ``--test-runs``).

    Every dwell (or, for runs without dwells, every block of about ``block_s`` seconds) of a
    run in ``train_runs`` trains; every one of the other runs is held out. Raises
    `DiagnoseError` when one side is empty or a held-out run moves an axis (force and response
    on it) that no training run does: nothing fitted would describe that axis.
    """
    train: list[Segment] = []
    test: list[Segment] = []
    for ri, rec in enumerate(records):
        block = max(64, int(block_s * rec.sample_rate_hz))
        segs = rec.segments or blocks(ri, 0, rec.n_samples, block, rec.name)
        (train if ri in train_runs else test).extend(segs)
    if not train or not test:
        raise DiagnoseError("--train-runs and --test-runs must each name at least one run "
                            f"({len(train)} training, {len(test)} held-out segments)")

    trained = set().union(*(driven_axes(records[i]) for i in train_runs))
    for ri, rec in enumerate(records):
        if ri in train_runs:
            continue
        missing = driven_axes(rec) - trained
        if missing:
            names = ", ".join("xy"[a] for a in sorted(missing))
            raise DiagnoseError(
                f"--test-runs {rec.name} drives the {names} axis, which no training run "
                "drives: add a training run that moves it")
    return train, test


def driven_axes(rec: RunRecord, start: int = 0, stop: int | None = None) -> set[int]:
    """Axes with a response channel whose force over ``[start, stop)`` is at least 10 % (RMS)
    of the larger axis's: a load cell's noise on an axis nobody drives does not count."""
    f = rec.force_n[:, start:stop]
    rms = np.sqrt(np.mean((f - f.mean(axis=1, keepdims=True)) ** 2, axis=1))
    top = float(rms.max()) if rms.size else 0.0
    return {ax for ax in rec.axes if top > 0 and rms[ax] >= 0.1 * top}
