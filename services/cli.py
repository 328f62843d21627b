"""The ``mimic`` console script: one subcommand per service or tool.

The subcommands are the ``mimic`` table of ``services/commands.toml``; their modules are
imported lazily (:mod:`services.commands`) so ``mimic --help`` is instant and a service only
loads the libraries it needs.
"""

from __future__ import annotations

import argparse
import sys

from services.commands import add_subcommands, command_table, run
from shared.bus import setup_logging


def build_parser(selected: str | None) -> argparse.ArgumentParser:
    """The ``mimic`` parser; only the ``selected`` command's module is imported for its flags."""
    parser = argparse.ArgumentParser(prog="mimic", description="Real-time human motion imitation over a Zenoh bus.")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING (also $MIMIC_LOG)")
    add_subcommands(parser, "mimic", "command", "COMMAND", flags_for=(selected,) if selected else ())
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    selected = next((a for a in argv if a in command_table("mimic")), None)
    parser = build_parser(selected)
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_help()
        return 2
    setup_logging(args.log_level, prefix=f"[{args.command}] ")
    return run("mimic", args.command, args)


if __name__ == "__main__":
    sys.exit(main())
