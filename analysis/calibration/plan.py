"""The reference report's test plan, as data: which tests, at which loads, amplitudes and
frequencies (sections IV.1-IV.3 and VI.1, Table 5). The composition root runs it on the
simulated rig (`sfdrig.report_plan`); the calibration only says what it needs."""

from __future__ import annotations

from dataclasses import dataclass, replace

# Near the dry resonance a 40 N orbit moves the simulated default rig past the clearance (the
# journal stops it: a fault), so the dry orbits keep to 20 Hz and 70-200 Hz, as the demo does.
DRY_FREQS_HZ = (20.0, *(float(f) for f in range(70, 201, 10)))


@dataclass(frozen=True)
class ReportPlan:
    """Static and impact tests (no journal), dry circular load orbits, lubricated dwells."""

    structure: tuple[str, ...] = ("static", "impact")
    dry_loads_n: tuple[float, ...] = (40.0, 33.0)
    dry_freqs_hz: tuple[float, ...] = DRY_FREQS_HZ
    lub_amplitudes_m: tuple[float, ...] = (13e-6, 19e-6, 25e-6, 32e-6, 38e-6)
    lub_freqs_hz: tuple[float, ...] = (20.0, 30.0, 40.0, 50.0, 60.0)
    lub_axes: tuple[str, ...] = ("x", "y")

    @classmethod
    def reduced(cls) -> ReportPlan:
        """For CI: the amplitude ends and centre, three frequencies, fewer dry frequencies."""
        return cls(dry_freqs_hz=(20.0, 70.0, 100.0, 150.0, 200.0),
                   lub_amplitudes_m=(13e-6, 25e-6, 38e-6), lub_freqs_hz=(20.0, 40.0, 60.0))

    def only_lubricated(self, amplitudes_m: tuple[float, ...] | None = None,
                        axes: tuple[str, ...] | None = None) -> ReportPlan:
        return replace(self, structure=(), dry_loads_n=(),
                       lub_amplitudes_m=amplitudes_m or self.lub_amplitudes_m,
                       lub_axes=axes or self.lub_axes)

    def only_structure(self) -> ReportPlan:
        return replace(self, dry_loads_n=(), lub_axes=())
