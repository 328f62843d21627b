"""Reading user map files (skeleton maps for BVH rigs, marker maps for C3D): TOML or JSON tables."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

from services.ingest.errors import ClipError


def read_map_file(path: Path, kind: str, error: type[ClipError]) -> dict[str, Any]:
    """The table in a map file (``.json`` as JSON, anything else as TOML).

    Args:
        kind: "skeleton map" or "marker map", for the error text.

    Raises:
        ``error``: the file cannot be read or parsed.
    """
    try:
        text = path.read_text()
        return json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, ValueError) as exc:
        raise error(f"{kind} {path}: cannot read ({exc})") from None


def name_list(value: Any, where: str, error: type[ClipError]) -> tuple[str, ...]:
    """A map entry as a tuple of names: one name, or a non-empty list of names.

    Args:
        where: "<kind> <path>: <key>" and what the names are, e.g. "... must be a joint name".

    Raises:
        ``error``: anything else.
    """
    if isinstance(value, str):
        return (value,)
    if isinstance(value, list) and value and all(isinstance(x, str) for x in value):
        return tuple(value)
    raise error(f"{where} or a list of names")
