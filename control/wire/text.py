"""Text that crosses a boundary (a request, a reply, a run file): what is refused, what is
made safe. JSON can carry NULs and lone UTF-16 surrogates; UTF-8, HDF5 strings and C strings
cannot, so requests refuse them and anything echoed back is made safe. The one exception is the
reason of an abort (`SafeReason`): an abort is never refused for its text, which is replaced
instead, with a note saying so. A request id is only echoed (`RequestId`): a reply carries it
back exactly, NULs and control characters included; only lone surrogates are refused (an
abort's are replaced, `SafeRequestId`)."""

from __future__ import annotations

import math
import re
from typing import Annotated, Any

from pydantic import AfterValidator, BeforeValidator

_SURROGATE = re.compile("[\ud800-\udfff]")
_NUL = re.compile("\x00")


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


def _echoable(text: str) -> str:
    """Refuse what a reply cannot carry back exactly: lone surrogates (UTF-8 has none)."""
    if _SURROGATE.search(text):
        raise ValueError("must not contain lone UTF-16 surrogates (\\ud800-\\udfff): a reply "
                         "cannot carry them back")
    return text


#: A request id: only echoed in the reply, never written to a file or a log, so any text a
#: reply carries back exactly is taken as it is (NULs, CR, LF, TAB included); lone surrogates
#: are refused, as `invalid`.
RequestId = Annotated[str, AfterValidator(_echoable)]


def sanitised_reason(value: Any, default: str = "operator abort", max_chars: int = 500) -> str:
    """A reason that every encoder and a run file take, whatever was sent: NULs and lone
    surrogates become U+FFFD, text longer than ``max_chars`` is cut, a value that is not text
    (or is blank) becomes ``default``; each replacement is noted at the end, e.g.
    ``"stop\ufffdnow [reason sanitised: 1 NUL replaced by U+FFFD]"``."""
    if value is None or isinstance(value, str) and not value.strip():
        return default
    if not isinstance(value, str):
        kind = {bool: "boolean", int: "number", float: "number", list: "list",
                dict: "object"}.get(type(value), type(value).__name__)
        return f"{default} [reason sanitised: a JSON {kind} was sent, not text]"
    notes = []
    text, nuls = _NUL.subn("\ufffd", value)
    if nuls:
        notes.append(f"{nuls} NUL{'s' if nuls > 1 else ''} replaced by U+FFFD")
    text, lone = _SURROGATE.subn("\ufffd", text)
    if lone:
        notes.append(f"{lone} lone surrogate{'s' if lone > 1 else ''} replaced by U+FFFD")
    if len(text) > max_chars:
        notes.append(f"cut from {len(text)} to {max_chars} characters")
        text = text[:max_chars]
    return f"{text} [reason sanitised: {'; '.join(notes)}]" if notes else text


def _lenient_id(value: Any) -> str:
    return safe_text(value, 128) if isinstance(value, str) else ""


#: A reason that is replaced, never refused (`sanitised_reason`): an abort must always happen.
SafeReason = Annotated[str, BeforeValidator(sanitised_reason)]
#: A request id that is never refused (for the requests that must always act): echoed exactly
#: (NULs, CR, LF, TAB included) but for what a reply cannot carry: lone surrogates become
#: U+FFFD, and it is cut to 128 characters; not text, it becomes "".
SafeRequestId = Annotated[str, BeforeValidator(_lenient_id)]
