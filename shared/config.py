"""Command-line flags built from config dataclasses: one source of defaults.

A service's settings live in one dataclass (``SimConfig``, ``SolverConfig``,
``RetargetConfig``, ...) whose docstring ``Attributes:`` section documents each
field with its unit. :func:`add_dataclass_arguments` turns the fields into flags
(default, type and help read from the class) and :func:`config_from_args` builds
the dataclass back from the parsed flags, so its ``__post_init__`` validates them.

Per field, ``overrides`` (or the field's ``metadata["cli"]``) may give argparse
keywords and, in addition:

* ``flag``: the flag name (default ``--field-name``; booleans that default to True
  become ``--no-field-name``);
* ``dest``: the attribute of the parsed namespace (default the field name; needed when the
  field name is taken, e.g. ``mode`` by the bus flags): pass the same overrides to
  :func:`config_from_args`;
* ``type``: a parser for the text (e.g. a class's ``parse``).

Example::

    add_dataclass_arguments(parser, SimConfig, {"solver_id": {"flag": "--follow"}})
    config = config_from_args(SimConfig, parser.parse_args())
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import types
import typing
from collections.abc import Iterable
from typing import Any

_BLOCK = re.compile(r"\n\s*Attributes:\s*\n(.*?)(?:\n\s*\n|\Z)", re.S)


def attribute_docs(cls: type) -> dict[str, str]:
    """Field name -> first sentence of its entry in the class docstring's ``Attributes:`` section."""
    m = _BLOCK.search(cls.__doc__ or "")
    if not m:
        return {}
    text = " ".join(m.group(1).split())
    names = [f.name for f in dataclasses.fields(cls)]
    marks = sorted(
        (hit.start(), hit.end(), name)
        for name in names
        for hit in re.finditer(rf"(?:^|(?<=[\s.]))({re.escape(name)}): ", text)
    )
    out: dict[str, str] = {}
    for i, (_start, end, name) in enumerate(marks):
        stop = marks[i + 1][0] if i + 1 < len(marks) else len(text)
        entry = text[end:stop].strip()
        # First sentence: a period before a capital letter ("eqs. 1-3" stays whole).
        first = re.split(r"(?<=\.)\s+(?=[A-Z])", entry, maxsplit=1)[0].rstrip(".")
        out.setdefault(name, first)
    return out


def _base_type(tp: Any) -> Any:
    """``float | None`` -> float; other types unchanged."""
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    raise TypeError(f"field {f.name} has no default: it cannot be a flag")


def add_dataclass_arguments(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    overrides: dict[str, dict[str, Any]] | None = None,
    skip: Iterable[str] = (),
    only: Iterable[str] | None = None,
) -> None:
    """Add one flag per field of dataclass ``cls`` (``dest`` = field name).

    Args:
        parser: parser or argument group.
        cls: the config dataclass; every field needs a default.
        overrides: field -> argparse keywords (plus ``flag``) replacing what is read from the class.
        skip: fields that get no flag (set by the program, or not meant for the command line).
        only: if given, flags for these fields only.
    """
    hints = typing.get_type_hints(cls)
    docs = attribute_docs(cls)
    skip = set(skip)
    only = None if only is None else set(only)
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init or (only is not None and f.name not in only):
            continue
        spec = {**f.metadata.get("cli", {}), **(overrides or {}).get(f.name, {})}
        default = _default(f)
        tp = _base_type(hints[f.name])
        custom_help = "help" in spec
        # argparse formats help with %; reST literals read badly in a terminal.
        text = spec.pop("help", docs.get(f.name, "")).replace("%", "%%").replace("``", "")
        dashed = f.name.replace("_", "-")
        dest = spec.pop("dest", f.name)
        if tp is bool:
            flag = spec.pop("flag", f"--no-{dashed}" if default else f"--{dashed}")
            action = "store_false" if default else "store_true"
            text = f"turn off: {text}" if default and not custom_help else text
            parser.add_argument(flag, dest=dest, action=action, default=default, help=text, **spec)
            continue
        flag = spec.pop("flag", f"--{dashed}")
        spec.setdefault("type", tp if tp in (int, float, str) else None)
        if spec["type"] is None:
            raise TypeError(f"{cls.__name__}.{f.name}: give a 'type' parser for {tp!r} in overrides")
        shown = spec.pop("shown_default", default)
        parser.add_argument(flag, dest=dest, default=default, help=f"{text} (default: {shown})", **spec)


def config_from_args(
    cls: type, args: argparse.Namespace, overrides: dict[str, dict[str, Any]] | None = None, **values: Any
):
    """``cls`` from the parsed flags of its fields (absent ones keep their default) and ``values``.

    Args:
        overrides: the ones given to :func:`add_dataclass_arguments` (for their ``dest``).

    Raises:
        ValueError: from ``cls.__post_init__`` when a value is invalid (a one-line message).
    """
    fields = [f for f in dataclasses.fields(cls) if f.init]
    dests = {f.name: (overrides or {}).get(f.name, {}).get("dest", f.name) for f in fields}
    kw = {name: getattr(args, dest) for name, dest in dests.items() if hasattr(args, dest)}
    kw.update(values)
    return cls(**kw)
