"""Loading validated configuration files (TOML + pydantic) with errors that name the file, the
field and the value. Shared by the channel map, the rig parameters and the sweep description."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)


def describe_validation_error(err: ValidationError, what: str, source: str) -> str:
    """One line per problem: where (source and field path), what value, and why."""
    lines = [f"invalid {what} in {source}:"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(top level)"
        value = e.get("input")
        shown = repr(value) if not isinstance(value, dict) else "{...}"
        lines.append(f"  {loc} = {shown}: {e['msg']}")
    return "\n".join(lines)


def validate(model: type[M], data: dict[str, Any], what: str, source: str,
             error: type[Exception]) -> M:
    """``model.model_validate(data)``, raising ``error`` with every problem named."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise error(describe_validation_error(err, what, source)) from None


def read_toml(path: str | Path, error: type[Exception]) -> dict[str, Any]:
    """The TOML document at ``path``; ``error`` names the file when it is unreadable or bad."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise error(f"{path}: not valid TOML: {err}") from None
    except OSError as err:
        raise error(f"{path}: cannot read: {err.strerror}") from None
