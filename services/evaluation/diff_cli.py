"""``mimic eval-diff BASE.json NEW.json [--algos ...] [--threshold 0.05] [--json OUT]``: two ``mimic eval`` runs
side by side (:mod:`.run_diff`)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from services.evaluation.run_diff import RunDiffError, diff_runs, format_diff

log = logging.getLogger("mimic.eval-diff")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("base", type=Path, help="the reference run's JSON (mimic eval --json)")
    p.add_argument("new", type=Path, help="the run to compare with it")
    p.add_argument("--algos", default=None, help="comma list of algorithms to compare (default: all both ran)")
    p.add_argument(
        "--threshold", type=float, default=0.05, help="share of a clip's base value past which a metric moved (0.05)"
    )
    p.add_argument("--json", type=Path, default=None, help="also write the whole comparison as JSON here")


def _load(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except OSError as e:
        raise RunDiffError(f"{path}: cannot read ({e.strerror or e})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RunDiffError(f"{path}: not JSON ({e})") from None


def main(args: argparse.Namespace) -> int:
    algos = [a.strip() for a in args.algos.split(",") if a.strip()] if args.algos else None
    try:
        if not args.threshold >= 0:
            raise RunDiffError(f"--threshold {args.threshold} must be >= 0")
        diff = diff_runs(_load(args.base), _load(args.new), algos, args.threshold)
    except RunDiffError as e:
        log.error("%s", e)
        return 2
    sys.stdout.write(format_diff(diff) + "\n")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(diff, indent=2))
        log.info("wrote %s", args.json)
    return 0
