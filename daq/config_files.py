"""Loading validated configuration files (TOML + pydantic) with errors that name the file, the
field and the value, and writing them back (`to_toml`). Shared by the channel map, the rig
parameters and the sweep description."""

from __future__ import annotations

import difflib
import json
import tomllib
import typing
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from daq.errors import ConfigFileError

M = TypeVar("M", bound=BaseModel)


def validation_problems(err: ValidationError, model: type[BaseModel] | None = None) -> list[str]:
    """One line per problem: the field path, the value and why. A model-wide check (no field
    path) names its own places, one problem a line. Given the ``model``, a field it does not
    have is answered with the one it probably means (`unknown_field_hint`)."""
    lines = []
    for e in err.errors():
        msg = e["msg"].removeprefix("Value error, ")
        if not e["loc"]:
            lines.extend(msg.splitlines())
            continue
        loc = ".".join(str(p) for p in e["loc"])
        value = e.get("input")
        shown = repr(value) if not isinstance(value, dict) else "{...}"
        hint = unknown_field_hint(model, e["loc"]) if e["type"] == "extra_forbidden" else ""
        lines.append(f"{loc} = {shown}: {msg}{hint}")
    return lines


def unknown_field_hint(model: type[BaseModel] | None, loc: tuple[int | str, ...]) -> str:
    """For a field ``model`` has no place for at ``loc`` (a pydantic error's path): "; did you
    mean 'record_cycles'?" when one of the fields there is close (difflib), else ""."""
    fields = _fields_at(model, loc[:-1]) if model is not None else None
    close = difflib.get_close_matches(str(loc[-1]), fields or [], n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def _fields_at(model: type[BaseModel], path: tuple[int | str, ...]) -> list[str] | None:
    """The field names of the model found at ``path`` below ``model`` (list indices and the
    tables of nested models followed), or None."""
    for part in path:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(str(part))
        nested = _model_in(field.annotation) if field is not None else None
        if nested is None:
            return None
        model = nested
    return list(model.model_fields)


def _model_in(annotation: Any) -> type[BaseModel] | None:
    """The pydantic model an annotation holds (``Settings``, ``Settings | None``,
    ``list[Entry]``, ``dict[str, Entry]``), or None."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def describe_validation_error(err: ValidationError, what: str, source: str,
                              model: type[BaseModel] | None = None) -> str:
    """One line per problem: where (source and field path), what value, and why."""
    return "\n".join([f"invalid {what} in {source}:"]
                     + [f"  {line}" for line in validation_problems(err, model)])


def validate(model: type[M], data: dict[str, Any], what: str, source: str,
             error: type[Exception]) -> M:
    """``model.model_validate(data)``, raising ``error`` with every problem named (and, for a
    `ConfigFileError`, itemised in its ``problems``, each line led by ``source``)."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        exc = error(describe_validation_error(err, what, source, model))
        if isinstance(exc, ConfigFileError):
            exc.problems = tuple(f"{source}: {line}" for line in validation_problems(err, model))
        raise exc from None


def read_toml(path: str | Path, error: type[Exception]) -> dict[str, Any]:
    """The TOML document at ``path``; ``error`` names the file when it is unreadable or bad."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise error(f"{path}: not valid TOML: {err}") from None
    except OSError as err:
        raise error(f"{path}: cannot read: {err.strerror}") from None


def to_toml(data: dict[str, Any]) -> str:
    """A TOML document for ``data`` (a ``model_dump(mode="json")``): scalars, lists of scalars,
    tables and arrays of tables; None values are left out (a model's default fills them back).
    ``tomllib.loads(to_toml(d))`` gives ``d`` back without its None values."""
    return _table(data, "")


def _table(data: dict[str, Any], prefix: str) -> str:
    def is_tables(v: Any) -> bool:
        return isinstance(v, list | tuple) and bool(v) and all(isinstance(x, dict) for x in v)

    items = {k: v for k, v in data.items() if v is not None}
    lines = [f"{_key(k)} = {_value(v)}" for k, v in items.items()
             if not isinstance(v, dict) and not is_tables(v)]
    text = "\n".join(lines) + ("\n" if lines else "")
    for k, v in items.items():
        name = f"{prefix}.{_key(k)}" if prefix else _key(k)
        if isinstance(v, dict):
            text += ("\n" if text else "") + f"[{name}]\n" + _table(v, name)
        elif is_tables(v):
            for entry in v:
                text += ("\n" if text else "") + f"[[{name}]]\n" + _table(entry, name)
    return text


def _key(k: str) -> str:
    return k if k.replace("_", "a").replace("-", "a").isalnum() and k.isascii() else _value(k)


def toml_value(v: Any) -> str:
    """One TOML value (a scalar or a list of scalars), as `to_toml` writes it."""
    return _value(v)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v) if v == v else "nan"
    if isinstance(v, str):
        # JSON's escapes are TOML's (\\, \", \n, \uXXXX); DEL needs one too
        return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007F")
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")
