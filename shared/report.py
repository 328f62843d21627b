"""JSON reports of the benchmark and evaluation commands: one format, on stdout and in a file."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any


def emit_json(report: Any, path: str | Path | None = None, indent: int = 2) -> str:
    """Write ``report`` as JSON to stdout and, when ``path`` is given, to that file (parents created).

    Returns the JSON text. Non-JSON numbers (numpy scalars) are written as floats.
    """
    text = json.dumps(report, indent=indent, default=float)
    if path:
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")
    sys.stdout.write(text + "\n")
    sys.stdout.flush()
    return text
