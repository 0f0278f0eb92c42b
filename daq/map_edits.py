"""Corrections to a channel map, proposed by commissioning or a calibration, applied to the map
and to its TOML file: the file's own text is edited field by field where it can be (its comments
and order kept), else the map is written out whole (`ChannelMap.to_toml`). The change is shown
as a unified diff of the file."""

from __future__ import annotations

import difflib
import re
import tomllib
from dataclasses import dataclass
from typing import Any

from daq.channels import ChannelMap, channel_map_from_dict
from daq.config_files import toml_value


@dataclass(frozen=True)
class Correction:
    """A proposed change of the channel map: ``group`` "ai" or "ao", the channel ``name``, the
    ``field`` and its new ``value``, and why."""

    group: str
    name: str
    field: str
    value: Any
    why: str

    def line(self) -> str:
        return f"{self.group} {self.name}: {self.field} = {toml_value(self.value)} ({self.why})"


def apply_corrections(cm: ChannelMap, corrections: list[Correction],
                      source: str = "<proposed>") -> ChannelMap:
    """``cm`` with ``corrections`` applied (validated as any map)."""
    data = cm.model_dump(mode="json", exclude_none=True)
    for c in corrections:
        for entry in data[c.group]:
            if entry["name"] == c.name:
                entry[c.field] = c.value
    return channel_map_from_dict(data, source)


_HEADER = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_.]+)\s*\]?\]\s*(#.*)?$")
_NAME = re.compile(r'^\s*name\s*=\s*"([^"]*)"')


def edit_map_text(text: str, cm: ChannelMap, corrections: list[Correction]) -> str:
    """``text`` (the TOML of ``cm``) with ``corrections`` made in place, comments kept; the
    whole corrected map as TOML where the file's layout defeats that (inline tables, say)."""
    wanted = apply_corrections(cm, corrections)
    lines = text.splitlines(keepends=True)
    starts = [i for i, line in enumerate(lines) if _HEADER.match(line)] + [len(lines)]
    out = lines[:starts[0]]
    for a, b in zip(starts, starts[1:], strict=False):
        block = lines[a:b]
        header = _HEADER.match(block[0])
        assert header is not None
        group = header.group(1)
        name = next((m.group(1) for line in block if (m := _NAME.match(line))), None)
        for c in corrections:
            if c.group == group and c.name == name:
                block = _set(block, c.field, toml_value(c.value))
        out += block
    edited = "".join(out)
    try:
        if channel_map_from_dict(tomllib.loads(edited)) == wanted:
            return edited
    except (tomllib.TOMLDecodeError, ValueError):
        pass
    return wanted.to_toml()


def _set(block: list[str], field: str, value: str) -> list[str]:
    key = re.compile(rf"^(\s*){re.escape(field)}\s*=\s*[^#\n]*?(\s*#.*)?$")
    for i, line in enumerate(block):
        m = key.match(line.rstrip("\n"))
        if m:
            block = block.copy()
            block[i] = f"{m.group(1)}{field} = {value}{m.group(2) or ''}\n"
            return block
    at = next((i + 1 for i, line in enumerate(block) if _NAME.match(line)), 1)
    return block[:at] + [f"{field} = {value}\n"] + block[at:]


def text_diff(old: str, new: str, old_name: str, new_name: str) -> str:
    """A unified diff of two map files; empty when equal."""
    return "".join(difflib.unified_diff(old.splitlines(keepends=True),
                                        new.splitlines(keepends=True), old_name, new_name, n=3))
