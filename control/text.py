"""Text that crosses a boundary (a request, a reply, a run file): what is refused, what is
made safe. JSON can carry NULs and lone UTF-16 surrogates; UTF-8, HDF5 strings and C strings
cannot, so requests refuse them and anything echoed back is made safe."""

from __future__ import annotations

import math
import re
from typing import Annotated, Any

from pydantic import AfterValidator

_SURROGATE = re.compile("[\ud800-\udfff]")


def safe_text(text: Any, max_chars: int | None = None) -> str:
    """``text`` as a string that every encoder takes: lone UTF-16 surrogates (which JSON can
    carry but UTF-8 cannot) become U+FFFD; cut to ``max_chars``."""
    out = _SURROGATE.sub("\ufffd", text if isinstance(text, str) else str(text))
    return out if max_chars is None or len(out) <= max_chars else out[:max_chars]


def safe_json(value: Any, depth: int = 0) -> Any:
    """A copy of ``value`` that serialises as JSON by construction: strings made `safe_text`,
    non-finite floats as None, anything else as its text, nesting cut at 32 levels."""
    if value is None or isinstance(value, bool | int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, str):
        return safe_text(value)
    if depth >= 32:
        return "..."
    if isinstance(value, dict):
        return {safe_text(k): safe_json(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [safe_json(v, depth + 1) for v in value]
    return safe_text(value)


def _printable(text: str) -> str:
    """Refuse text a run file or a log cannot hold faithfully: NULs and lone surrogates."""
    if "\x00" in text:
        raise ValueError("must not contain NUL characters (\\u0000)")
    if _SURROGATE.search(text):
        raise ValueError("must not contain lone UTF-16 surrogates (\\ud800-\\udfff)")
    return text


#: A request string: no NULs, no lone surrogates (refused as `invalid`, naming the field).
Text = Annotated[str, AfterValidator(_printable)]
