"""The simulator's samples for a seed: what a speed-up may not change.

A change that only makes the simulator faster leaves every sample as it was (at most a
floating-point rounding apart, which the 16-bit ADC's step hides but for a rare sample that
moves by one step). The fingerprints below were recorded from the code at 6e8ff6f, before the
block path and the kernel were made faster; a deliberate change of the physics or the noise
records them again (`python -m tests.simulated_hw.test_seeded_samples` prints them).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from daq import default_channel_map
from rig_model import RigParams
from simulated_hw import SimulatedBackend

CM = default_channel_map()
LSB_V = 2 * CM.device.ai_range_v / 2**CM.device.ai_bits  # the ADC's step [V]
#: read sizes of unequal lengths (one sample, one over a block of the bench, a long one) and the
#: pump switched off half way: the board's chunks, the noise draws and the oil all move
BLOCKS = (1000, 137, 1000, 250, 2500, 1000, 1)

#: one rig per compiled kernel the suite uses anyway (no compile for this test alone)
RIGS: dict[str, dict[str, Any]] = {
    "lubricated": {"oil": {"initially_filled": True}},
    "frame_mode": {"oil": {"initially_filled": True},
                   "effects": {"second_mode": {"enabled": True}}},
    "compliant_seal": {"seal": {"contact_stiffness_n_per_m": 2e6}},
    "sensor_effects": {
        "film": {"eccentricity_law": False},
        "effects": {
            "joint_microslip": {"enabled": True, "stiffness_n_per_m": 1e6, "slip_force_n": 5.0},
            "relaxing_stiffness": {"enabled": True, "stiffness_x_n_per_m": 1e5},
            "channel_delay": {"enabled": True, "channel": "x1", "delay_s": 0.00037},
            "probe_gain_error": {"enabled": True, "channel": "y1", "gain_ratio": 1.1},
            "reversed_polarity": {"enabled": True, "channels": ["ax"]},
            "viscosity_drift": {"enabled": True, "warming_c_per_s": 0.5},
        },
    },
}

#: per rig: each AI channel's sum of samples and its sum weighted by the sample's place in
#: the run (k / n), in ADC steps, as the code at 6e8ff6f gave them
FINGERPRINTS: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "lubricated": (
        (-19824.000, -3600.000, 11011.000, 10542.000, 84653.000, 82898.000, 4401.000, 546.000,
         20712640.000, 19815710.000, 2072297.000, 2072812.000, 4630474.000, -13.000),
        (-23933.567, -234571.066, -35525.704, -34303.649, 8921.612, 8776.221, 4382.979, 515.497,
         10399631.849, 9922735.229, 1101730.298, 1102230.778, 2314834.823, -4.227),
    ),
    "frame_mode": (
        (-19824.000, -3600.000, 30122.000, 29014.000, 105177.000, 103020.000, 1555.000,
         -6829.000, 20712640.000, 19815710.000, 2072297.000, 2072812.000, 4630474.000, -13.000),
        (-23933.567, -234571.066, -15315.558, -14770.370, 16704.737, 16386.845, 1566.631,
         -6844.352, 10399631.849, 9922735.229, 1101730.298, 1102230.778, 2314834.823, -4.227),
    ),
    "compliant_seal": (
        (-19824.000, -3600.000, 57391.000, 55350.000, -2047.000, -2117.000, -11257.000,
         -990.000, 20712640.000, 19815710.000, 2072297.000, 2072812.000, 4630474.000, -13.000),
        (-23933.567, -234571.066, -21101.850, -20357.118, -94240.879, -92381.175, -3403.072,
         -663.780, 10399631.849, 9922735.229, 1101730.298, 1102230.778, 2314834.823, -4.227),
    ),
    "sensor_effects": (
        (-19824.000, -3600.000, 60159.000, 68152.000, 21659.000, 19202.000, 12562.000,
         -4802.000, 20712640.000, 19815710.000, 2077727.000, 2078174.000, 4658879.000, -13.000),
        (-23933.567, -234571.066, -29723.865, -18581.222, -92910.969, -82799.727, 3165.171,
         -1836.314, 10399631.849, 9922735.229, 1105211.477, 1105669.432, 2333777.093, -4.227),
    ),
}


def run(rig: dict, realtime: bool = False) -> np.ndarray:
    """The 14 AI channels of the default map over `BLOCKS`, seed 3, both shakers driven at
    45 Hz (X 3 V, Y 2.5 V), written one block ahead of each read; ``realtime``: the paced
    board on a clock that the reads move."""
    clock = [100.0]

    def sleep(s: float) -> None:
        clock[0] += s

    be = SimulatedBackend(RigParams.model_validate(rig), seed=3, realtime=realtime,
                          clock=lambda: clock[0], sleep=sleep)
    be.configure(CM)
    be.set_do("pump", True)
    fs = CM.sample_rate_hz
    out, k = [], 0
    be.write_ao(np.zeros((2, BLOCKS[0])))
    be.start()
    for i, n in enumerate(BLOCKS):
        t = (k + np.arange(n)) / fs
        be.write_ao(np.vstack([3.0 * np.cos(2 * np.pi * 45 * t),
                               2.5 * np.sin(2 * np.pi * 45 * t + 0.3)]))
        out.append(be.read_ai(n))
        if i == len(BLOCKS) // 2:
            be.set_do("pump", False)
        k += n
    be.stop()
    return np.concatenate(out, axis=1)


def fingerprint(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    steps = samples / LSB_V
    place = np.arange(samples.shape[1]) / samples.shape[1]
    return steps.sum(axis=1), (steps * place).sum(axis=1)


@pytest.mark.parametrize("name", list(RIGS))
def test_the_samples_of_a_seed_are_those_recorded(name: str):
    """Each channel's sum over the run, plainly and weighted by time, within two ADC steps of
    the recorded (two samples moved by a step at most); any change of the physics, the noise
    or the board's blocks moves them by hundreds."""
    total, weighted = fingerprint(run(RIGS[name]))
    want_total, want_weighted = (np.array(v) for v in FINGERPRINTS[name])
    np.testing.assert_allclose(total, want_total, rtol=0, atol=2.0)
    np.testing.assert_allclose(weighted, want_weighted, rtol=0, atol=2.0)


def test_fast_reads_are_the_paced_boards_samples():
    """Fast mode hands a read its block straight from the rig; paced, the board puts it in its
    AI buffer and the read takes it from there: the same samples, bit for bit."""
    rig = RIGS["lubricated"]
    np.testing.assert_array_equal(run(rig), run(rig, realtime=True))


if __name__ == "__main__":  # the fingerprints of the code as it is, to paste above
    import textwrap

    for key, rig_dict in RIGS.items():
        rows = [", ".join(f"{float(v):.3f}" for v in f) for f in fingerprint(run(rig_dict))]
        print(f'    "{key}": (')
        for row in rows:
            print(textwrap.fill(f"({row}),", width=96, initial_indent=" " * 8,
                                subsequent_indent=" " * 9))
        print("    ),")
