"""Subcommands backed by lazily imported modules: the tables of ``mimic`` and ``mimic bench``.

The tables are data (``commands.toml``: name -> module and one-line help). A command's module
provides ``add_arguments(parser)`` and ``main(args) -> int`` and is imported only when the
command is chosen.
"""

from __future__ import annotations

import argparse
import importlib
import tomllib
from collections.abc import Container
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import Any

TABLE_FILE = Path(__file__).with_name("commands.toml")


@cache
def command_table(section: str) -> dict[str, tuple[str, str]]:
    """Command name -> (module, one-line help) of one table of ``commands.toml`` (``mimic``, ``bench``)."""
    with TABLE_FILE.open("rb") as f:
        table = tomllib.load(f)[section]
    return {name: (entry["module"], entry["help"]) for name, entry in table.items()}


def load(section: str, name: str) -> ModuleType:
    """The module of command ``name`` of table ``section``."""
    return importlib.import_module(command_table(section)[name][0])


def add_subcommands(
    parser: argparse.ArgumentParser,
    section: str,
    dest: str,
    metavar: str,
    flags_for: Container[str] | None = None,
    **kw: Any,
) -> None:
    """One subparser per command of table ``section`` (choice stored in ``dest``).

    Args:
        flags_for: commands whose modules are imported to add their flags (None: every command).
        kw: passed to ``add_subparsers`` (e.g. ``required=True``).
    """
    sub = parser.add_subparsers(dest=dest, metavar=metavar, **kw)
    for name, (_, help_text) in command_table(section).items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        if flags_for is None or name in flags_for:
            load(section, name).add_arguments(sp)


def run(section: str, name: str, args: argparse.Namespace) -> int:
    """Run command ``name`` of table ``section``; its exit code (None counts as 0)."""
    return int(load(section, name).main(args) or 0)
