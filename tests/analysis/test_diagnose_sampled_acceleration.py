"""The replayed accelerometer of data from elsewhere: what a sampled instrument behind its
anti-alias filter reads, also where dry friction makes the acceleration jump.

The kernel reports the acceleration at each sample's instant. Where the seal's friction switches
or sticks, that acceleration jumps, and its samples alias the jumps: on a 20 Hz dwell with 10 N
of friction at 5 kS/s, the 1X of the kernel's acceleration samples stands 1.4 % off minus
w^2 times the 1X of its own displacement, where an instrument's anti-aliased samples (the HB
generator's) are the derivative's. A run of this rig keeps the kernel's samples: the simulator
recorded its accelerometers from them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.diagnose.data import RunRecord, Segment
from analysis.diagnose.model import Evaluator, Model, sampled_acceleration
from analysis.diagnose.residual_analysis import harmonics
from rig_model.params import RigParams

FS_HZ = 5000.0
FREQ_HZ = 20.0


@pytest.mark.parametrize("freq_hz", [60.0, 300.0])
def test_second_difference_gain_is_the_fourth_order_error(freq_hz: float) -> None:
    t = np.arange(2000) / FS_HZ
    w = 2 * math.pi * freq_hz
    z = np.sin(w * t)
    at_instants = np.full(t.size, 7.0)
    acc = sampled_acceleration(z, at_instants, FS_HZ)
    error = np.max(np.abs(acc[2:-2] + w * w * z[2:-2])) / (w * w)
    # 60 Hz: 3.6e-7; 300 Hz (60 Hz's 5X): 2.2e-4
    assert error == pytest.approx((w / FS_HZ) ** 4 / 90, rel=0.05)
    # the two samples at each end have no neighbours on one side: the instants' values stand
    assert list(acc[:2]) == list(acc[-2:]) == [7.0, 7.0]


def _dwell(rig: RigParams | None) -> tuple[RunRecord, Segment]:
    n = int(2 * FS_HZ)
    t = np.arange(n) / FS_HZ
    force = np.vstack([22.0 * np.sin(2 * math.pi * FREQ_HZ * t), np.zeros(n)])
    zeros = np.zeros(n)
    # the second second: a replay from rest has settled there as the steady state has
    seg = Segment(0, n // 2, n, "20 Hz", FREQ_HZ)
    rec = RunRecord(name="dwell", sample_rate_hz=FS_HZ, force_n=force,
                    responses={"x": zeros, "y": zeros}, response_axis={"x": 0, "y": 1},
                    accel={"ax": zeros, "ay": zeros}, kind="imported", rig=rig, segments=[seg])
    return rec, seg


def _friction_rig() -> RigParams:
    rig = RigParams()
    return rig.model_copy(update={"seal": rig.seal.model_copy(
        update={"enabled": True, "friction_force_n": 10.0})})


def _one_x(sig: np.ndarray, seg: Segment) -> complex:
    return complex(harmonics(sig, seg.start, FS_HZ, FREQ_HZ, 1)[0][0])


def test_data_from_elsewhere_read_the_anti_aliased_acceleration_of_the_replay() -> None:
    rec, seg = _dwell(None)
    ev = Evaluator([rec], warmup_s=0.5, steady_state_dwells=True)
    pred = ev.predict(Model(rig=_friction_rig()), [seg])[seg]
    x1, a1 = _one_x(pred["x"], seg), _one_x(pred["ax"], seg)
    w = 2 * math.pi * FREQ_HZ
    assert 13e-6 < abs(x1) < 50e-6, f"the dwell moves {abs(x1) * 1e6:.1f} um"
    # the kernel's instants' samples: 1.4 % off; the derivative's: 1.6e-8 (the difference's
    # gain at 20 Hz) plus what the displacement's samples alias
    assert abs(a1 / (-w * w * x1) - 1) < 1e-4


def test_a_run_of_this_rig_keeps_the_simulators_acceleration_samples() -> None:
    rig = _friction_rig()
    rec, seg = _dwell(rig)
    ev = Evaluator([rec], warmup_s=0.5, steady_state_dwells=True)
    pred = ev.predict(Model(rig=rig), [seg])[seg]
    x1, a1 = _one_x(pred["x"], seg), _one_x(pred["ax"], seg)
    w = 2 * math.pi * FREQ_HZ
    # the samples the simulator recorded its accelerometers from: the jumps aliased
    assert abs(a1 / (-w * w * x1) - 1) > 2e-3
