"""A sweep defined on the page: checked by the same model as a sweep's TOML (`SweepSpec`), each
problem named by its field, and summarised before the start.

The page builds its form from `SweepSpec`'s JSON schema (`schema`), so every field of a sweep is
there and a new field appears by itself. Each number field carries its unit (the spec's
`field_units`, the one table of them) and the unit the form shows it in (`SHOWN`: a length in um,
the rest as the spec has it), so the page has no unit of its own.

`check` validates what the form (or a loaded TOML file) gives and answers the problems by field
path (``freq_hz``, ``control.window_cycles``; "" for a rule between fields), or a summary: steps,
frequencies, targets, the time the sweep settles and records (a lower bound: each step's approach
adds to it), whether the pump must be on, the tolerances, the limits the daemon applies, and the
sweep as TOML (what `sfdrig sweep` reads). The daemon validates the spec again when it is
started.
"""

from __future__ import annotations

from typing import Any

from control.wire.heartbeat import SafetyEnvelope
from control.wire.sweep_spec import SweepSpec, field_units
from daq.config_files import to_toml

MAX_ERRORS = 30
#: The units an operator reads in other than the spec's SI: (the unit shown, the power of ten
#: the value is multiplied by). An orbit is tens of um; every other unit is shown as it is.
SHOWN = {"m": ("um", 6)}


def shown_unit(si: str) -> tuple[str, int]:
    """(unit shown, power of ten) of a field in the SI unit ``si``."""
    return SHOWN.get(si, (si, 0))


def schema() -> dict[str, Any]:
    """`SweepSpec`'s JSON schema (its fields, types, bounds, defaults and descriptions); each
    number field's property also holds ``unit`` (SI), ``shown_unit`` and ``shown_power``: the
    form shows value x 10^shown_power in shown_unit."""
    s = SweepSpec.model_json_schema()
    for path, si in field_units().items():
        prop = _property(s, path)
        prop["shown_unit"], prop["shown_power"] = shown_unit(si)
    return s


def _property(s: dict[str, Any], path: str) -> dict[str, Any]:
    """The JSON-schema property of the dotted field ``path`` (through ``$ref`` tables)."""
    node = s
    for name in path.split("."):
        if "$ref" in node:
            node = s["$defs"][node["$ref"].rsplit("/", 1)[-1]]
        node = node["properties"][name]
    return node


def check(spec: object, safety: SafetyEnvelope | None = None) -> dict[str, Any]:
    """``{"ok", "errors": [{"field", "message"}], "summary", "toml"}`` for a sweep's fields;
    ``safety``: the daemon's limits (its status's ``safety``) for the summary."""
    from pydantic import ValidationError

    if not isinstance(spec, dict):
        return {"ok": False, "errors": [{"field": "", "message": "a sweep is a table of fields"}],
                "summary": None, "toml": ""}
    try:
        s = SweepSpec.model_validate(spec)
    except ValidationError as err:
        errors = []
        for e in err.errors()[:MAX_ERRORS]:
            # a rule between fields (no field in its path) shows no input: it is the whole sweep
            shown = e["type"] != "missing" and e["loc"]
            got = f" (got {str(e.get('input'))[:60]})" if shown else ""
            message = str(e["msg"]).removeprefix("Value error, ")
            errors.append({"field": ".".join(str(p) for p in e["loc"]),
                           "message": message + got})
        return {"ok": False, "errors": errors, "summary": None, "toml": ""}
    return {"ok": True, "errors": [], "summary": summary(s, safety),
            "toml": to_toml(s.model_dump(mode="json", exclude_defaults=True))}


def summary(s: SweepSpec, safety: SafetyEnvelope | None) -> dict[str, Any]:
    """What the operator confirms before the start (``limits`` None before the first status)."""
    freqs = s.frequencies()
    unit, power = shown_unit(field_units()["amplitude_m" if s.target_kind == "displacement"
                                           else "load_n"])
    settle_record_s = len(s.targets) * sum((s.settle_cycles + s.record_cycles) / f
                                           for f in freqs)
    return {
        "name": s.name,
        "motion": s.motion,
        "target_kind": s.target_kind,
        "targets": [t * 10.0 ** power for t in s.targets],
        "target_unit": unit,
        "frequencies": len(freqs),
        "freq_first_hz": freqs[0],
        "freq_last_hz": freqs[-1],
        "freq_min_hz": min(freqs),
        "freq_max_hz": max(freqs),
        "steps": len(freqs) * len(s.targets),
        "settle_record_s": settle_record_s,
        "pump": "on" if s.lubricated else "off",
        "tolerance_amplitude_pct": s.tolerance_amplitude_pct,
        "tolerance_phase_deg": s.tolerance_phase_deg,
        "on_not_converged": s.on_not_converged,
        "limits": dict(safety) if safety is not None else dict.fromkeys(
            ("displacement_limit_m", "load_limit_n", "drive_limit_v", "radial_clearance_m")),
    }
