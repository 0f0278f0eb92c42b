"""What `sfdrig sweep` prints at the end of a run (issue 21): the run's peak orbit and load, any
journal-housing contact, and, after a trip, a last line that says what tripped, at which step
and frequency, the peak, and what to do. From real runs on the simulated rig (in process)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from control.run.listener import RecordingListener
from control.run.sweep.engine import SweepEngine, SweepSpec
from control.wire.summary_lines import end_line, lateness_line, peak_line
from daq.channels import default_channel_map
from rig_model.params import RigParams
from sfdrig.commands import sweep as sweep_cmd
from simulated_hw.backend import SimulatedBackend
from storage.records import StepRecord
from tests.control.conftest import GainJump, make_backend
from tests.simulated_hw.fake_clock import FakeClock


def test_a_completed_run_prints_its_peaks_and_the_usual_last_line():
    out = SweepEngine(make_backend(), SweepSpec(motion="x", load_n=[400.0],
                                                freq_hz=[150.0])).run()
    assert out.status == "completed", out.reason
    line = peak_line(out.summary)
    # measured: 52.0 um at 400 N
    assert line.startswith("peak orbit 5")
    assert "um of the 63.5 um limit (step 1/1, 150.0 Hz)" in line
    assert "peak load 40" in line and "N of 448 N" in line
    assert line.endswith("; no journal-housing contact")
    assert end_line("R1", out.status, out.reason, 1, out.summary) == "run R1 completed (1 steps)"


def test_a_trip_says_what_where_the_peak_and_what_to_do():
    """The amplifier's gain x3 during a 40 N dwell at 60 Hz: the limit trips and the housing's
    momentum carries it to the journal after the cut."""
    be = GainJump(RigParams(), seed=8, factor=3.0, at_sample=30_028)
    be.configure(default_channel_map())
    out = SweepEngine(be, SweepSpec(motion="x", load_n=[40.0], freq_hz=[60.0],
                                    record_cycles=200)).run()
    assert out.status == "aborted"
    s = out.summary
    assert s["tripped_at"]["freq_hz"] == 60.0 and s["tripped_at"]["step_index"] == 0
    assert s["contact"].startswith("journal-housing contact")
    assert s["peak_displacement_m"] > 0.97 * 127e-6  # at the journal
    last = end_line("R2", out.status, out.reason, len(out.steps), s)
    assert last.startswith("run R2 aborted by a limit trip at step 1/1, 60.0 Hz (x 40 N): "
                           "displacement 6")
    assert "exceeds the 63.5 um limit; peak orbit 12" in last
    assert "journal-housing contact: orbit radius 12" in last
    assert "the drives were cut to 0 V" in last
    assert "What to do: check the journal and the housing for contact marks" in last
    assert "lower the target at that frequency" in last
    assert "\n" not in last
    assert peak_line(s).endswith(s["contact"])


class _Client:
    def __init__(self, last_run: dict) -> None:
        self.last_run = last_run

    def status(self) -> dict:
        return {"state": "idle", "last_run": self.last_run}


def test_the_summary_comes_from_the_daemons_last_run_of_this_run_only():
    summary = {"peak_displacement_m": 52e-6, "peak_displacement_at": {},
               "displacement_limit_m": 63.5e-6, "peak_load_n": 400.0, "peak_load_at": {},
               "max_load_n": 448.0, "contact": "", "tripped_at": None}
    client = _Client({"run_id": "R1", "status": "completed", "summary": summary})
    assert sweep_cmd.run_summary(client, "R1") == summary  # type: ignore[arg-type]
    assert sweep_cmd.run_summary(client, "R0") is None  # type: ignore[arg-type]
    assert sweep_cmd.run_summary(_Client({}), "R1") is None  # type: ignore[arg-type]
    buf = io.StringIO()
    print(peak_line(summary), file=buf)
    assert buf.getvalue() == ("peak orbit 52.0 um of the 63.5 um limit, peak load 400.0 N of "
                              "448 N; no journal-housing contact\n")


def test_an_underflow_says_what_to_do():
    last = end_line("R3", "failed", "DaqUnderflowError: AO generation ran past the samples "
                    "written (DAQmx code -200290)", 0, {"tripped_at": None})
    assert last.startswith("run R3 failed: DaqUnderflowError")
    assert "What to do: the AO stream ran dry" in last and "--priority high" in last


SPEC_20_80 = SweepSpec(motion="circular_forward", load_n=[40.0], freq_hz=[20.0, 80.0])


def test_the_orbit_of_a_drive_still_playing_after_its_step_belongs_to_that_step():
    """Issue 39: "peak orbit 45.0 um ... (step 2/2, 80.0 Hz)" while step 2 reached 16.3 um: the
    20 Hz drive, still playing through the AO lead and its fade after step 1's recording ended,
    was charged to step 2. Here the amplifier's gain rises 10 % 5 ms after that recording ends
    (seeded, the same run until then): the run's largest orbit comes while the 20 Hz drive still
    plays, and it is step 1's."""
    rec = RecordingListener()
    SweepEngine(make_backend(), SPEC_20_80, listener=rec).run()
    end = rec.wire_steps[0]["last_sample"]
    be = GainJump(RigParams(), seed=0, factor=1.1, at_sample=end + 50)
    be.configure(default_channel_map())
    rec = RecordingListener()
    out = SweepEngine(be, SPEC_20_80, listener=rec).run()
    assert out.status == "completed", out.reason
    at = out.summary["peak_displacement_at"]
    ao = rec.ao()[:, end:]
    playing = np.flatnonzero(np.any(ao != 0, axis=0))
    drive_20_ends = end + playing[np.flatnonzero(np.diff(playing) > 1)[0]] + 1  # then 0 V
    assert end < at["sample"] < drive_20_ends  # measured: 43611, the 20 Hz drive ends 43799
    assert out.summary["peak_displacement_m"] > 1.1 * 45e-6  # measured: 52.9 um (45.1 without)
    assert (at["step_index"], at["freq_hz"]) == (0, 20.0)
    assert "(step 1/2, 20.0 Hz)" in peak_line(out.summary)


class _StallAfterFirstStep(RecordingListener):
    """The host stalls 0.6 s once, at the first block after the first step (the clock jumps)."""

    def __init__(self, clock: FakeClock) -> None:
        super().__init__(keep_blocks=False)
        self.clock, self.armed = clock, False

    def on_step(self, step: StepRecord) -> None:
        super().on_step(step)
        self.armed = step.index == 0 or self.armed

    def on_block(self, first: int, ai: np.ndarray, ao: np.ndarray) -> None:
        super().on_block(first, ai, ao)
        if self.armed:
            self.armed, self.clock.t = False, self.clock.t + 0.6


def test_the_end_says_what_the_hosts_lateness_cost():
    """Issue 39: only the run file's last event said "host late 137 times ... 10.460 s played
    from the ring"; `sfdrig sweep` printed nothing of it. A paced rig with a 2 s AO ring on an
    injected clock; the host stalls 0.6 s once."""
    clock = FakeClock()
    be = SimulatedBackend(RigParams(), seed=5, realtime=True, clock=clock, sleep=clock.sleep,
                          ao_ring_s=2.0)
    be.configure(default_channel_map())
    out = SweepEngine(be, SPEC_20_80, listener=_StallAfterFirstStep(clock)).run()
    assert out.status == "completed", out.reason
    late = out.summary["host_late"]
    assert late["events"] == 1 and late["played_from_ring_s"] == pytest.approx(0.58)
    assert lateness_line(out.summary) == (
        "the computer fell behind the drive 1 times (at worst 580.0 ms late): 0.580 s of drive "
        "played from the AO ring meanwhile, time the controller waited for the drive it asked "
        "for. What to do: ease the machine's load, or start the daemon with --priority high.")
    on_time = SweepEngine(make_backend(), SweepSpec(motion="x", load_n=[40.0],
                                                    freq_hz=[60.0])).run()
    assert on_time.summary["host_late"]["events"] == 0 and lateness_line(on_time.summary) == ""
