"""Test conditions of imported data: what the file cannot say, given by the user or inferred.

Conditions come from the command line or from a TOML file beside the data (``DATA.conditions.toml``
or ``conditions.toml`` in the same folder, for batch imports)::

    lubricated = true             # or false (dry)
    motion = "x"                  # x, y, circular_forward, circular_backward, elliptical
    seal = "none"                 # "none", "unknown" (fit or take F_mu from a dry run), or F_mu [N]
    rig = "rig-no-seal.toml"      # the rig description, stored as the run's rig_config

A ``[run]`` table (what `sfdrig export` writes: kind, times, sample rate...) is a record for the
reader; the importer does not read it.

Every condition is stored with where it came from (``given``, ``conditions file``, ``inferred``,
``not stated``); nothing is guessed silently.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from storage.errors import ImportDataError

MOTIONS = ("x", "y", "circular_forward", "circular_backward", "elliptical")
KEYS = ("lubricated", "motion", "seal", "rig")
#: A table of what the run was (kind, times, sample rate...), which `sfdrig export` writes for
#: the reader and the importer does not read: the run file keeps its own.
RECORD_TABLE = "run"


@dataclass
class Conditions:
    """The run's test conditions and the source of each.

    Attributes
    ----------
    lubricated : bool or None
        None: not stated.
    motion : str or None
        One motion for every dwell; None: inferred per dwell from the x/y phase.
    seal : str
        "none", "unknown", "" (not stated) or F_mu in newtons as text.
    rig_file : Path or None
        Rig description (TOML) to store as the run's rig_config.
    sources : dict
        Condition -> "given", "conditions file FILE", "inferred", "not stated".
    """

    lubricated: bool | None = None
    motion: str | None = None
    seal: str = ""
    rig_file: Path | None = None
    sources: dict[str, str] = field(default_factory=dict)

    @property
    def seal_friction_n(self) -> float | None:
        """F_mu [N] when stated as a number (0 for "none"), else None."""
        if self.seal == "none":
            return 0.0
        try:
            return float(self.seal)
        except ValueError:
            return None

    def to_json(self) -> dict[str, Any]:
        return {"lubricated": self.lubricated, "motion": self.motion, "seal": self.seal,
                "seal_friction_N": self.seal_friction_n,
                "rig_file": str(self.rig_file) if self.rig_file else None,
                "sources": dict(self.sources)}


def check_motion(motion: str, where: str) -> str:
    if motion not in MOTIONS:
        raise ImportDataError(f"{where}: motion {motion!r} is not one of {', '.join(MOTIONS)}")
    return motion


def check_seal(seal: str | float, where: str) -> str:
    """``none``, ``unknown`` or a friction force [N] >= 0, as text."""
    if isinstance(seal, bool):
        raise ImportDataError(f"{where}: seal {seal!r}: say none, unknown or F_mu in N")
    if isinstance(seal, int | float):
        value = float(seal)
    elif seal in ("none", "unknown"):
        return str(seal)
    else:
        try:
            value = float(seal)
        except ValueError:
            raise ImportDataError(f"{where}: seal {seal!r}: say none, unknown or F_mu in N "
                                  "(e.g. 26)") from None
    if not (math.isfinite(value) and value >= 0):
        raise ImportDataError(f"{where}: seal {seal!r}: F_mu must be a finite force >= 0 [N]")
    return "none" if value == 0 else repr(value)


def conditions_file_for(data_path: Path) -> Path | None:
    """The conditions file beside ``data_path``, if any (its own first, then the folder's)."""
    for candidate in (data_path.with_name(data_path.name + ".conditions.toml"),
                      data_path.with_suffix(".conditions.toml"),
                      data_path.parent / "conditions.toml"):
        if candidate.is_file():
            return candidate
    return None


def read_conditions_file(path: Path) -> dict[str, Any]:
    """The conditions in a TOML file, checked; errors name the file and the key."""
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise ImportDataError(f"{path}: cannot read: {err.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ImportDataError(f"{path}: not valid TOML: {err}") from None
    unknown = sorted(set(doc) - set(KEYS) - {RECORD_TABLE})
    if unknown:
        raise ImportDataError(f"{path}: unknown key(s) {unknown} (known: {', '.join(KEYS)}, "
                              f"and the table [{RECORD_TABLE}], not read)")
    out: dict[str, Any] = {}
    where = str(path)
    if "lubricated" in doc:
        if not isinstance(doc["lubricated"], bool):
            raise ImportDataError(f"{where}: lubricated = {doc['lubricated']!r}: true or false")
        out["lubricated"] = doc["lubricated"]
    if "motion" in doc:
        out["motion"] = check_motion(str(doc["motion"]), f"{where}: motion")
    if "seal" in doc:
        out["seal"] = check_seal(doc["seal"], f"{where}: seal")
    if "rig" in doc:
        rig = Path(str(doc["rig"]))
        rig = rig if rig.is_absolute() else path.parent / rig
        if not rig.is_file():
            raise ImportDataError(f"{where}: rig = {doc['rig']!r}: no such file ({rig})")
        out["rig"] = rig
    return out


def resolve_conditions(data_path: Path, *, lubricated: bool | None = None,
                       motion: str | None = None, seal: str | None = None,
                       rig_file: Path | None = None,
                       conditions_file: Path | None = None) -> Conditions:
    """Command-line conditions over the conditions file's (``conditions_file`` or the one beside
    the data); what neither states is marked "not stated"."""
    cond = Conditions()
    file = conditions_file or conditions_file_for(data_path)
    from_file = read_conditions_file(file) if file is not None else {}
    label = f"conditions file {file}"

    def pick(name: str, given: Any) -> Any:
        if given is not None:
            cond.sources[name] = "given"
            return given
        if name in from_file:
            cond.sources[name] = label
            return from_file[name]
        cond.sources[name] = "not stated"
        return None

    cond.lubricated = pick("lubricated", lubricated)
    m = pick("motion", check_motion(motion, "--motion") if motion is not None else None)
    cond.motion = m
    s = pick("seal", check_seal(seal, "--seal") if seal is not None else None)
    cond.seal = s or ""
    cond.rig_file = pick("rig", rig_file)
    if cond.rig_file is not None and not Path(cond.rig_file).is_file():
        raise ImportDataError(f"--rig {cond.rig_file}: no such file")
    return cond
