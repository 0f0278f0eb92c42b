"""The default diagnose of this rig's own run reads as sense: the lubricated X programme of
``examples/lubricated_x.toml`` (shortened: three levels, 20 record cycles), recorded by the real
sweep engine on the nominal simulated rig as the daemon records it.

The film makes the housing overdamped over 20-60 Hz (damping ratio 1.5-4 per level): no mode is
in the band, a one-mode fit's natural frequency is an extrapolation at the lowest level, and
the y probes only record their noise (the drive is X only)."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import pytest

from analysis.diagnose import load_run
from analysis.diagnose.amplitude import T_MIN, amplitude_dependence
from analysis.diagnose.data import RunRecord
from analysis.diagnose.effects import Context
from analysis.diagnose.modes import modal_dependence
from analysis.diagnose.residual_analysis import harmonics
from analysis.diagnose.residual_structure import Z_STRUCTURE
from rig_model import RigParams
from tests.analysis.recorded import record_sweep

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lubricated_x.toml"


@pytest.fixture(scope="module")
def lubricated_x(tmp_path_factory) -> RunRecord:
    spec = tomllib.loads(EXAMPLE.read_text())
    spec.update(amplitude_m=spec["amplitude_m"][::2], record_cycles=20, settle_cycles=5)
    path = tmp_path_factory.mktemp("sense") / "lubricated_x.h5"
    assert record_sweep(RigParams(), spec, path, seed=0) == "completed"
    rec = load_run(path)
    assert len(rec.segments) == 15
    return rec


def test_no_mode_reported_outside_the_swept_band(lubricated_x):
    """Every mode the text lists lies within the dwells' 20-60 Hz; a pole beyond them is
    reported as an extrapolation with its sd, never as a mode (it was "x: 1 mode (115.1 Hz
    (damping 70 %))")."""
    modes = modal_dependence([lubricated_x], lubricated_x.segments)
    lo, hi = 20.0, 60.0
    assert modes.levels, modes.text
    outside = 0
    for lv in modes.levels:
        assert lv.band_hz == pytest.approx((lo, hi))
        for m in lv.modes:
            assert lv.in_band(m) == (lo <= m.natural_hz <= hi)
            outside += not lv.in_band(m)
    assert outside >= 1  # the overdamped film puts a pole beyond the band at some level
    for tr in modes.tracks:
        assert tr.in_band == (lo <= tr.reference.natural_hz <= hi)
        if not tr.in_band:
            assert "extrapolated" in tr.extrapolation_text and "+-" in tr.extrapolation_text
    listed = re.match(r"x: (\d+) modes?(?: \((.*?)\))?(?:;|$)", modes.text)
    assert listed, modes.text
    assert int(listed[1]) == modes.per_axis()["x"] == sum(t.in_band for t in modes.tracks)
    for f in re.findall(r"(?:^|; |\()([\d.]+)(?: -> [\d.]+)* Hz \(damping", listed[2] or ""):
        assert lo <= float(f) <= hi, modes.text


def test_per_level_figures_only_where_determined(lubricated_x):
    """Each level's natural frequency is given only within its points' band and at
    ``T_MIN`` sd from zero; the trend says "not resolved" (with its sd) where the levels
    could not show the least change called one, never "level-independent"."""
    dep = amplitude_dependence([lubricated_x], lubricated_x.segments)
    assert len(dep.levels) == 3, dep.text
    for lv in dep.levels:
        inside = 20.0 <= lv.natural_hz <= 60.0
        assert lv.frequency_determined == (inside and lv.natural_hz_sd < lv.natural_hz / T_MIN)
        if not lv.frequency_determined:
            assert lv.text.startswith("natural frequency not determined (")
        if not lv.damping_determined:
            assert "damping ratio not determined (" in lv.text
    # the lowest level's one-mode fit is an extrapolation below the band, with an sd as large
    # as its value: not shown as a figure
    low = min(dep.levels, key=lambda lv: lv.level)
    assert low.natural_hz < 20.0 or low.natural_hz_sd > low.natural_hz / T_MIN
    assert not low.frequency_determined
    f = dep.frequency["x"]
    assert f.verdict == "none" and f.sd > f.min_change / T_MIN and not f.resolved
    assert "level-independent" not in dep.text
    assert dep.text.startswith("x: natural frequency not resolved by the levels (")


def test_no_gain_or_delay_candidate_on_an_undriven_channel(lubricated_x):
    """On the X-only run the y probes and the y accelerometer record their noise: their 1X
    stands under ``Z_STRUCTURE`` sd of it in every dwell, so they carry nothing of a gain or a
    delay and are no candidates (the best candidate was "sensor_gain (channel=y2,
    gain_ratio=0.2)", the fit's bound); the x channels stand hundreds of sd above."""
    rec = lubricated_x
    fs = rec.sample_rate_hz

    def z_sd(ch: str) -> float:  # the largest 1X over the dwells, in sd of its noise
        sig = rec.signal(ch)
        out = 0.0
        for s in rec.segments:
            z, _, rest = harmonics(sig[s.start:s.stop], s.start, fs, s.freq_hz, 1)
            out = max(out, abs(z[0]) / (rest * math.sqrt(2.0 / (s.stop - s.start))))
        return out

    for ch in ("y1", "y2", "ay"):
        assert z_sd(ch) < Z_STRUCTURE
    for ch in ("x1", "x2", "ax"):
        assert z_sd(ch) > 50 * Z_STRUCTURE
    ctx = Context(records=[rec], base=None, fitted_baseline=False,  # type: ignore[arg-type]
                  duration_s=0.0, x_rms_m=0.0, f_rms_n=0.0, f_typ_hz=40.0)
    assert ctx.redundant_channels() == ["x1", "x2", "ax"]
