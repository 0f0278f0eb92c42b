"""Phase-continuous synthesis: no step at any change, exact phasors at steady state."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from control.signal.lockin import LockIn
from control.signal.synthesis import SineSynthesizer

FS = 10_000.0


def _max_jump_bound(freq_hz: float, amp_v: float, ramp_v_per_s: float) -> float:
    """Largest sample-to-sample change of a sine of this frequency and amplitude, plus the
    envelope's own change per sample [V]."""
    return 2 * math.pi * freq_hz * amp_v / FS + ramp_v_per_s / FS


def test_changes_while_running_never_step():
    syn = SineSynthesizer(2, FS)
    syn.ramp_to(np.array([1.0, 1.0j]), 20.0, 0.0)
    blocks = [syn.next_block(137)]
    # amplitude, relative phase and frequency change together, mid-block and mid-ramp
    syn.ramp_to(np.array([2.0 + 0.5j, -1.5]), 80.0, 0.05)
    blocks.append(syn.next_block(211))
    syn.ramp_to(np.array([0.3, 0.3j]), 45.0, 0.03)  # interrupts the running ramp
    blocks += [syn.next_block(100) for _ in range(8)]
    syn.fade_out(0.02)
    blocks += [syn.next_block(100) for _ in range(4)]
    out = np.concatenate(blocks, axis=1)
    jump = np.abs(np.diff(out, axis=1)).max()
    # worst case: 80 Hz at |P| <= |2 + 0.5j| V; no envelope moves faster than the largest
    # phasor distance (< 2 x 2.1 V) over the shortest ramp (0.02 s)
    a_max = abs(2.0 + 0.5j)
    bound = _max_jump_bound(80.0, a_max, 2 * 2.1 / 0.02)
    assert jump <= bound
    assert np.all(out[:, -100:] == 0.0)  # faded out completely


def test_unramped_amplitude_change_does_step():
    """The same measure detects a step: an amplitude change with no ramp jumps the output."""
    syn = SineSynthesizer(1, FS)
    syn.ramp_to(np.array([1.0]), 20.0, 0.0)
    a = syn.next_block(250)  # ends at a peak of the cosine (a quarter period is 125 samples)
    syn.ramp_to(np.array([3.0]), None, 0.0)
    b = syn.next_block(10)
    jump = abs(b[0, 0] - a[0, -1])
    assert jump > 10 * _max_jump_bound(20.0, 3.0, 0.0)


def test_frequency_ramp_keeps_phase_continuous():
    syn = SineSynthesizer(1, FS)
    syn.ramp_to(np.array([1.0]), 30.0, 0.0)
    first = syn.next_block(333)
    syn.ramp_to(None, 150.0, 0.1)
    rest = syn.next_block(3000)
    out = np.concatenate([first, rest], axis=1)[0]
    assert np.abs(np.diff(out)).max() <= _max_jump_bound(150.0, 1.0, 0.0) * 1.0001
    assert syn.freq_hz == 150.0


def test_absolute_frame_matches_lockin_after_changes():
    syn = SineSynthesizer(2, FS)
    li = LockIn(FS)
    syn.ramp_to(np.array([0.7, 0.2j]), 25.0, 0.0)
    syn.next_block(1234)
    syn.ramp_to(np.array([1.1 - 0.4j, 0.9j]), 57.3, 0.07)
    syn.next_block(1500)
    first = syn.sample
    block = syn.next_block(2000)
    measured = li.fundamental(block, first, 57.3)
    np.testing.assert_allclose(measured, syn.to_absolute(syn.phasors), atol=1e-9)
    np.testing.assert_allclose(
        syn.from_absolute(syn.to_absolute(syn.phasors)), syn.phasors, atol=1e-12
    )


def test_bad_arguments():
    with pytest.raises(ValueError, match="n_channels"):
        SineSynthesizer(0, FS)
    syn = SineSynthesizer(2, FS)
    with pytest.raises(ValueError, match="shape"):
        syn.ramp_to(np.array([1.0]), None, 0.0)
    with pytest.raises(ValueError, match="freq_hz"):
        syn.ramp_to(None, -1.0, 0.0)


@settings(max_examples=60)
@given(
    commands=st.lists(
        st.tuples(
            st.floats(0.0, 3.0), st.floats(-np.pi, np.pi),  # channel 0 amplitude, phase
            st.floats(0.0, 3.0), st.floats(-np.pi, np.pi),  # channel 1
            st.floats(5.0, 200.0),  # frequency
            st.floats(0.01, 0.2),  # ramp [s]
            st.integers(1, 700),  # samples until the next command
        ),
        min_size=1, max_size=8,
    )
)
def test_no_command_sequence_makes_a_step(commands):
    """Whatever arrives, whenever: the output moves at most as fast as the fastest sine plus
    the fastest envelope change allows."""
    syn = SineSynthesizer(2, FS)
    out = [syn.next_block(50)]
    rate = 0.0
    for a0, p0, a1, p1, f, ramp, n in commands:
        before = syn.phasors
        target = np.array([a0 * np.exp(1j * p0), a1 * np.exp(1j * p1)])
        syn.ramp_to(target, f, ramp)
        rate = max(rate, float(np.max(np.abs(target - before))) / ramp)
        out.append(syn.next_block(n))
    v = np.concatenate(out, axis=1)
    bound = 2 * np.pi * 200.0 * 3.0 / FS + rate / FS
    assert np.abs(np.diff(v, axis=1)).max() <= bound * (1 + 1e-9)


@pytest.mark.parametrize("ramp_s", [0.0, 0.025, 0.3])
def test_many_blocks_at_once_are_the_blocks_one_by_one_bit_for_bit(ramp_s):
    """`next_blocks` (the AO ring's prediction, tens of blocks in one piece) makes exactly the
    samples of that many `next_block` calls: the ring plays them and the record holds the
    synthesiser's blocks, so they must be the same numbers, not nearly (a 30-block sine in
    one `next_block` differs by 1e-12 V)."""
    one, many = SineSynthesizer(2, FS), SineSynthesizer(2, FS)
    for s in (one, many):
        s.ramp_to(np.array([0.6, 0.3j]), 37.3, 0.0)
        s.next_block(100)
        s.ramp_to(np.array([0.2, 0.1 + 0.1j]), 70.0, ramp_s)
    blocks = np.concatenate([one.next_block(100) for _ in range(30)], axis=1)
    np.testing.assert_array_equal(many.next_blocks(30, 100), blocks)
    assert (many.sample, many.freq_hz) == (one.sample, one.freq_hz)
    np.testing.assert_array_equal(many.next_block(100), one.next_block(100))  # goes on alike
    with pytest.raises(ValueError, match="count must be positive"):
        many.next_blocks(0, 100)
