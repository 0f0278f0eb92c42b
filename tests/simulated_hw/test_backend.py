"""SimulatedBackend: the DaqBackend protocol, paced timing errors with DAQmx codes, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from daq import (
    DaqBackend,
    DaqBufferOverflowError,
    DaqTimeoutError,
    DaqUnderflowError,
    default_channel_map,
)
from daq.errors import INVALID_ATTRIBUTE_VALUE, DaqError
from rig_model import RigParams, load_rig_params
from rig_model.params import RigParamsError, rig_params_from_dict
from simulated_hw import SimulatedBackend

CM = default_channel_map()


class FakeClock:
    """Simulated wall clock: sleep advances it, so paced tests run instantly and exactly."""

    def __init__(self) -> None:
        self.now = 100.0
        self.slept: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.now += s


def paced(clock: FakeClock, buffer_s: float = 1.0) -> SimulatedBackend:
    be = SimulatedBackend(seed=1, realtime=True, buffer_s=buffer_s, clock=clock, sleep=clock.sleep)
    be.configure(CM)
    return be


def test_is_a_daq_backend():
    be = SimulatedBackend()
    be.configure(CM)
    assert isinstance(be, DaqBackend)


def test_paced_read_waits_for_the_samples():
    clock = FakeClock()
    be = paced(clock)
    be.write_ao(np.zeros((2, 5000)))
    be.start()
    block = be.read_ai(1000, timeout_s=1.0)
    assert block.shape == (14, 1000)
    assert clock.now - 100.0 == pytest.approx(0.1)  # 1000 samples at 10 kS/s


def test_paced_read_timeout_is_daqmx_200284():
    clock = FakeClock()
    be = paced(clock)
    be.write_ao(np.zeros((2, 50_000)))
    be.start()
    with pytest.raises(DaqTimeoutError) as err:
        be.read_ai(20_000, timeout_s=0.5)  # 2 s of data cannot come in 0.5 s
    assert err.value.code == -200284
    assert isinstance(err.value, TimeoutError)


def test_reader_falling_behind_the_buffer_is_daqmx_200279():
    clock = FakeClock()
    be = paced(clock, buffer_s=1.0)
    be.write_ao(np.zeros((2, 50_000)))
    be.start()
    clock.now += 2.5  # the application stalls for 2.5 s with a 1 s buffer
    with pytest.raises(DaqBufferOverflowError) as err:
        be.read_ai(1000)
    assert err.value.code == -200279


def test_ao_underflow_is_daqmx_200290():
    be = SimulatedBackend(seed=1)
    be.configure(CM)
    be.write_ao(np.zeros((2, 500)))
    be.start()
    with pytest.raises(DaqUnderflowError) as err:
        be.read_ai(1000)
    assert err.value.code == -200290


def test_ao_outside_range_and_bad_shapes_refused():
    be = SimulatedBackend(seed=1)
    be.configure(CM)
    with pytest.raises(DaqError, match="shaker_x: AO sample outside the channel range"):
        be.write_ao(np.full((2, 10), 11.0))
    with pytest.raises(ValueError, match=r"AO block must have shape \(2, n\)"):
        be.write_ao(np.zeros((3, 10)))
    with pytest.raises(KeyError, match="no relay named 'heater'"):
        be.set_do("heater", True)


@pytest.mark.parametrize("config", ["rse", "nrse", "pseudo_differential"])
def test_a_terminal_configuration_the_board_lacks_is_refused_in_process_too(config):
    """The in-process rig refuses what the PXIe-6358 (differential only) and the sim-server
    refuse: DAQmx -200077 naming the channel, its terminal and the property, at configure; a
    map rehearsed here never first fails on the board. The default and differential pass."""
    data = CM.model_dump(mode="json")
    data["ai"][4]["terminal_config"] = config
    be = SimulatedBackend(seed=1)
    with pytest.raises(DaqError) as err:
        be.configure(type(CM).model_validate(data))
    assert err.value.code == INVALID_ATTRIBUTE_VALUE
    name = data["ai"][4]["name"]
    assert str(err.value).startswith(f"creating AI channel {name}: Requested value is not a "
                                     "supported value for this property. Property: AI.TermCfg")
    assert f"possible values: differential (physical channel {data['ai'][4]['physical_channel']})" \
        in str(err.value)
    for accepted in ("default", "differential"):
        data["ai"][4]["terminal_config"] = accepted
        be.configure(type(CM).model_validate(data))


def test_use_before_configure_names_the_problem():
    with pytest.raises(DaqError, match="not configured"):
        SimulatedBackend().read_ai(10)


def test_block_partition_does_not_change_the_physics():
    """The rig's response to the same drive is the same whatever the read block size (noise
    differs with the partition; the truth does not)."""
    params = RigParams()
    t = np.arange(4000) / 1e4
    ao = np.vstack([4 * np.sin(2 * np.pi * 50 * t), 4 * np.cos(2 * np.pi * 50 * t)])
    truths = []
    for blk in (4000, 250):
        be = SimulatedBackend(params, seed=3)
        be.configure(CM)
        be.write_ao(ao)
        be.start()
        xs = []
        for _ in range(4000 // blk):
            be.read_ai(blk)
            assert be.rig is not None and be.rig.last_truth is not None
            xs.append(be.rig.last_truth.x_m.copy())
        truths.append(np.concatenate(xs))
    np.testing.assert_allclose(truths[0], truths[1], rtol=0, atol=1e-15)


def test_rig_params_toml_round_trip_and_errors(tmp_path):
    p = RigParams()
    p.effects.cubic_stiffness.enabled = True
    p.effects.cubic_stiffness.k3_n_per_m3 = 2.5e13
    f = tmp_path / "rig.toml"
    f.write_text(p.to_toml())
    q = load_rig_params(f)
    assert q == p
    with pytest.raises(RigParamsError, match=r"structure.mass_kg = -1.0"):
        rig_params_from_dict({"structure": {"mass_kg": -1.0}}, "x.toml")
    with pytest.raises(RigParamsError, match=r"seal.frction_force_n"):
        rig_params_from_dict({"seal": {"frction_force_n": 20}}, "x.toml")


def test_the_cross_stiffness_loads_from_a_rig_file_and_must_be_a_rod_set(tmp_path):
    f = tmp_path / "rig.toml"
    f.write_text("[structure]\nstiffness_xy_n_per_m = -1.2e5\n")
    assert load_rig_params(f).structure.stiffness_xy_n_per_m == -1.2e5
    p = RigParams()
    p.structure.stiffness_xy_n_per_m = 9.5e4
    f.write_text(p.to_toml())
    assert load_rig_params(f) == p
    # |k_xy| >= sqrt(K_x K_y) = 805.3 kN/m: no rod set, a stiffness matrix that is not positive
    with pytest.raises(RigParamsError, match=r"structure.stiffness_xy_n_per_m = -810000.0"):
        rig_params_from_dict({"structure": {"stiffness_xy_n_per_m": -8.1e5}}, "x.toml")


def test_a_stopping_cut_drops_what_the_paced_generation_has_not_reached():
    clock = FakeClock()
    be = paced(clock)
    be.write_ao(np.vstack([np.full(3000, 1.0), np.zeros(3000)]))
    be.start()
    be.read_ai(1000)
    clock.now += 0.00555  # 55 more samples generated while the program looked at the block
    cut = be.cut_ao()
    assert (cut.at, cut.resumes) == (1055, False)
    assert be.ao_backlog() == 0  # written and not generated: nothing left to play
    be.write_ao(np.ones((2, 100)))  # a stopped generation plays nothing written now
    be.read_ai(3000, timeout_s=1.0)  # the drives at 0 V: no underflow however long AI runs
    be.stop()
    be.write_ao(np.zeros((2, 1000)))  # a new run primes it again
    be.start()
    be.read_ai(1000, timeout_s=1.0)
    with pytest.raises(DaqUnderflowError):
        be.read_ai(1000, timeout_s=1.0)


def test_a_resuming_cut_continues_the_stream_at_the_first_sample_dropped():
    clock = FakeClock()
    be = SimulatedBackend(seed=1, realtime=True, buffer_s=1.0, clock=clock, sleep=clock.sleep,
                          cut_stops=False)
    be.configure(CM)
    be.write_ao(np.zeros((2, 3000)))
    be.start()
    be.read_ai(1000)
    clock.now += 0.00555
    cut = be.cut_ao()
    assert (cut.at, cut.resumes) == (1075, True)  # 55 generated + the 2 ms margin
    be.write_ao(np.zeros((2, 500)))  # samples 1075..1574
    be.read_ai(500, timeout_s=1.0)
    with pytest.raises(DaqUnderflowError):
        be.read_ai(500, timeout_s=1.0)


def test_a_second_run_starts_counting_from_zero_and_waits_only_for_its_own_samples():
    """Issue 21's blocker: the paced read count survived `start()`, so run n waited for the
    samples of runs 1..n-1 first and the eleventh read of a day timed out (-200284)."""
    clock = FakeClock()
    be = paced(clock)
    for run in range(12):
        be.write_ao(np.full((2, 5000), 0.01 * run))
        be.start()
        t0 = clock.now
        be.read_ai(2000, timeout_s=1.0)
        be.read_ai(2000, timeout_s=1.0)
        assert clock.now - t0 == pytest.approx(0.4), f"run {run}"  # 4000 samples at 10 kS/s
        be.stop()
        assert be.ao_backlog() == 0, f"run {run}: the old queue outlived stop()"


def test_stop_drops_the_queue_the_next_run_plays_only_its_own_prefill():
    be = SimulatedBackend(seed=1)
    be.configure(CM)
    be.write_ao(np.full((2, 3000), 0.5))
    be.start()
    be.read_ai(1000)
    be.stop()  # 2000 samples of 0.5 V were queued and never generated
    be.write_ao(np.zeros((2, 1000)))
    be.start()
    be.read_ai(1000)  # only the new prefill: no underflow, nothing of the old run left
    with pytest.raises(DaqUnderflowError):
        be.read_ai(1)


def test_ring_mode_plays_position_k_mod_b_and_a_late_writer_hears_it_repeat():
    """ao_ring_s: writes land at absolute samples; what the (paced) clock has generated is
    fixed, so a write after the generation passed a sample changes only the next ring."""
    clock = FakeClock()
    be = SimulatedBackend(seed=1, realtime=True, clock=clock, sleep=clock.sleep, ao_ring_s=0.1)
    be.configure(CM)
    assert be.ao_ring_samples == 1000 and be.ao_min_lead == 0
    ring = np.vstack([np.arange(1000) * 1e-3, -np.arange(1000) * 1e-3])
    be.write_ao(ring, at=0)
    be.start()
    played = []
    orig = be._take_played

    def take(n):
        out = orig(n)
        played.append(out.copy())
        return out

    be._take_played = take  # type: ignore[method-assign]
    be.read_ai(500)
    clock.now += 0.1  # late: the generation is at 1,500, nothing was written past 1,000
    assert be.ao_generated() == 1500 and be.ao_backlog() == -500
    be.write_ao(np.full((2, 200), 5.0), at=1400)  # 1,400..1,499 played already: next ring
    be.read_ai(2500)
    ao = np.concatenate(played, axis=1)
    np.testing.assert_array_equal(ao[:, :1500], ring[:, np.arange(1500) % 1000])
    np.testing.assert_array_equal(ao[:, 1500:1600], 5.0)  # written in time
    np.testing.assert_array_equal(ao[:, 1600:2400], ring[:, np.arange(1600, 2400) % 1000])
    np.testing.assert_array_equal(ao[:, 2400:2600], 5.0)  # the write at 1,400 a ring on
    cut = be.cut_ao()
    assert cut.at == 3000 and not cut.resumes
    be.read_ai(500)
    np.testing.assert_array_equal(played[-1], 0.0)  # stopped: 0 V from the cut
    be.stop()


def test_ring_writes_are_checked():
    be = SimulatedBackend(seed=1, ao_ring_s=0.1)
    be.configure(CM)
    with pytest.raises(ValueError, match="longer than"):
        be.write_ao(np.zeros((2, 1001)), at=0)
    with pytest.raises(DaqError) as err:
        be.write_ao(np.full((2, 10), 11.0), at=0)
    assert err.value.code == -200561
    with pytest.raises(ValueError, match="ao_ring_s"):
        SimulatedBackend(ao_ring_s=0.0)
