"""The pump relay and its interlock with the shakers."""

from __future__ import annotations

import numpy as np
import pytest

from control.run.errors import InterlockError
from control.run.listener import RecordingListener
from control.run.pump import PumpRelay
from control.run.sweep.engine import SweepEngine
from control.wire.errors import TargetError
from daq.channels import default_channel_map
from rig_model.params import RigParams
from simulated_hw.backend import SimulatedBackend
from tests.control.conftest import make_backend

LUB = {"motion": "x", "lubricated": True, "amplitude_m": [13e-6], "freq_hz": [30.0]}


def test_relay_switches_the_rig_pump():
    be = make_backend()
    changes = []
    pump = PumpRelay(be, on_change=lambda on, msg: changes.append((on, msg)))
    pump.set(True)
    assert pump.is_on and be.rig.pump_on
    pump.set(False)
    assert not be.rig.pump_on
    assert changes == [(True, "pump 'pump' switched on"), (False, "pump 'pump' switched off")]
    with pytest.raises(KeyError, match="no relay named 'oil'"):
        PumpRelay(be, name="oil")


def test_lubricated_sweep_refused_with_the_pump_off():
    be = make_backend()
    pump = PumpRelay(be)
    with pytest.raises(InterlockError, match="the pump is off"):
        SweepEngine(be, LUB, pump=pump).run()
    with pytest.raises(InterlockError, match="no pump relay"):
        SweepEngine(be, LUB).run()
    assert be.written == [] and be.samples_read == 0


def test_no_pressure_aborts_with_zero_drive():
    params = RigParams.model_validate({"oil": {"supply_pressure_pa": 5000.0}})  # clogged filter
    be = make_backend(params)
    pump = PumpRelay(be)
    pump.set(True)
    rec = RecordingListener(keep_blocks=False)
    out = SweepEngine(be, LUB, pump=pump, listener=rec).run()
    assert out.status == "aborted"
    assert "inlet pressure p_in = " in out.reason and "below 10.00 kPa after 10 s" in out.reason
    assert np.all(be.ao_written() == 0)
    assert 10 * 10_000 <= out.samples <= 10 * 10_000 + 1000


def test_pump_cannot_be_switched_off_while_the_shakers_run():
    be = make_backend(seed=3)
    pump = PumpRelay(be)
    pump.set(True)
    refusals = []

    class Operator(RecordingListener):
        def on_step(self, step):  # the shakers are still at the step's drive
            super().on_step(step)
            try:
                pump.set(False)
            except InterlockError as err:
                refusals.append(str(err))

    # the relay's one owner holds it for the run (the daemon does); the engine only asks it
    with pump.shakers_running():
        out = SweepEngine(be, LUB, pump=pump, listener=Operator(keep_blocks=False)).run()
    assert out.status == "completed"
    assert refusals and "cannot be switched off while the shakers run" in refusals[0]
    assert pump.is_on and be.rig.pump_on
    pump.set(False)  # allowed once the run is over
    assert not pump.is_on


def test_the_sweep_engine_asks_the_pump_and_never_holds_it():
    """One owner holds the relay (the daemon); a sweep run alone leaves it free."""
    be = make_backend(seed=3)
    pump = PumpRelay(be)
    pump.set(True)
    held = []

    class Watch(RecordingListener):
        def on_step(self, step):
            super().on_step(step)
            held.append(pump.shakers_active)

    out = SweepEngine(be, LUB, pump=pump, listener=Watch(keep_blocks=False)).run()
    assert out.status == "completed" and held == [False]


def test_a_dry_run_refuses_pump_on_and_a_lubricated_one_pump_off():
    be = make_backend()
    pump = PumpRelay(be)
    with pump.shakers_running("the dry sweep R1"):
        with pytest.raises(InterlockError, match="cannot be switched on during the dry sweep "
                                                 "R1: its dwells are recorded as dry"):
            pump.set(True)
        pump.set(False)  # what it is already: allowed
        assert not pump.is_on and not be.rig.pump_on
    pump.set(True)
    refused = pytest.raises(InterlockError, match=r"switched off while the shakers run \(a "
                                                  r"lubricated run\): a squeeze film")
    with pump.shakers_running(), refused:  # unnamed: named by the pump's state at the start
        pump.set(False)
    pump.set(False)
    assert not pump.shakers_active and not be.rig.pump_on


def test_a_run_that_owns_the_relay_alone_switches_it():
    """The flow test switches the pump itself: while it holds the relay as its owner, its own
    switches go through and every other one is refused, on or off, even to the same state."""
    be = make_backend()
    pump = PumpRelay(be)
    token = object()
    refused = pytest.raises(InterlockError, match="cannot be switched by hand during the flow "
                                                  "test F1: the test switches it itself")
    with pump.shakers_running("the flow test F1", owner=token):
        pump.set(True, owner=token)
        assert pump.is_on and be.rig.pump_on
        with refused:
            pump.set(False)
        with refused:
            pump.set(True)
        with refused:
            pump.set(False, owner=object())  # another run's token is not the owner's
        assert pump.is_on and be.rig.pump_on
        pump.set(False, owner=token)
        with refused:
            pump.set(True)
        assert not pump.is_on and not be.rig.pump_on
    pump.set(True)  # the run is over: the operator's again
    assert pump.is_on and not pump.shakers_active


def test_pressure_lost_while_running_trips():
    """A pump failure mid-run (the relay drops out behind the software's back)."""
    be = make_backend(seed=5)
    pump = PumpRelay(be)
    pump.set(True)

    class Failure(RecordingListener):
        def on_step(self, step):
            super().on_step(step)
            be.rig.set_relay("pump", False)  # the hardware, not the interlocked relay object

    rec = Failure(keep_blocks=True)
    spec = {**LUB, "freq_hz": [30.0, 40.0, 50.0]}
    out = SweepEngine(be, spec, pump=pump, listener=rec).run()
    assert out.status == "aborted" and out.reason.startswith("inlet pressure lost")
    trip = rec.events_of("limit_trip")[0]
    ao = rec.ao()
    assert np.all(ao[:, trip[2] + 1000:] == 0)
    assert len(out.steps) == 1


def test_unconfigured_backend_is_refused():
    from simulated_hw.backend import SimulatedBackend

    with pytest.raises(TargetError, match="not configured"):
        SweepEngine(SimulatedBackend(), {"motion": "x", "load_n": [5.0],
                                         "freq_hz": [30.0]}).run()


def test_the_film_drains_for_drain_s_after_the_pump_goes_off():
    now = [0.0]
    pump = PumpRelay(make_backend(), drain_s=30.0, clock=lambda: now[0])
    assert pump.drains_for_s() == 0.0  # never on
    pump.set(True)
    now[0] = 50.0
    assert pump.drains_for_s() == 0.0  # on: the film is full, not draining
    pump.set(False)
    now[0] = 60.0
    assert pump.drains_for_s() == pytest.approx(20.0)
    pump.set(False)  # off again: the drain does not start over
    assert pump.drains_for_s() == pytest.approx(20.0)
    now[0] = 90.0
    assert pump.drains_for_s() == 0.0
    with pytest.raises(ValueError, match="drain_s must be >= 0 s, got -1"):
        PumpRelay(make_backend(), drain_s=-1)


def test_the_simulated_film_drains_between_runs_as_the_wall_clock_passes():
    """Issue 21: the in-process rig only moved while a run read it, so a film filled by a
    lubricated run was still full whenever the next run started, however long after."""
    now = [0.0]
    be = SimulatedBackend(RigParams(), seed=1, realtime=False, clock=lambda: now[0])
    be.configure(default_channel_map())
    pump = PumpRelay(be)
    pump.set(True)
    now[0] = 10.0  # idle, pump on: pressurised and filled
    be.start()
    be.stop()
    assert be.rig.film_fill > 0.999
    pump.set(False)
    tau = RigParams().oil.drain_time_constant_s
    now[0] += 10 * tau
    be.start()
    assert be.rig.film_fill < np.exp(-8)  # drained (less the inlet's venting time)
    be.stop()
