"""``mimic bench sim-track``: measure servo tracking of a sine and print JSON.

Example: ``mimic bench sim-track`` (1 Hz, 30 degree sine on the 14 arm joints, commands at
100 Hz, 5 s) prints ``max_error_deg`` and the servo settings; ``--waist`` moves the
waist too, ``--command-rate 30`` mimics a 30 fps mocap source.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from services.sim.cli import add_sim_options, sim_config

log = logging.getLogger("mimic.sim")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_sim_options(p)
    g = p.add_argument_group("sine")
    g.add_argument("--amplitude-deg", type=float, default=30.0, help="sine amplitude [deg]")
    g.add_argument("--frequency", type=float, default=1.0, help="sine frequency [Hz]")
    g.add_argument("--duration", type=float, default=5.0, help="simulated time [s]")
    g.add_argument("--settle", type=float, default=0.5, help="error ignored before this time [s]")
    g.add_argument("--command-rate", type=float, nargs="+", default=[100.0], help="command rate(s) [Hz]")
    g.add_argument("--waist", action="store_true", help="move the waist joints too")
    g.add_argument("--limit-deg", type=float, default=2.0, help="pass/fail threshold on max_error_deg")


def main(args: argparse.Namespace) -> int:
    from services.sim.tracking import measure_tracking

    results = []
    for rate in args.command_rate:
        try:
            r = measure_tracking(
                amplitude_deg=args.amplitude_deg,
                frequency_hz=args.frequency,
                duration=args.duration,
                settle=args.settle,
                command_rate=rate,
                include_waist=args.waist,
                config=sim_config(args),
                profile=args.robot,
            )
        except (ValueError, RuntimeError) as exc:
            log.error("%s", exc)
            return 2
        r["pass"] = r["max_error_deg"] < args.limit_deg
        results.append(r)
    out = results[0] if len(results) == 1 else {"runs": results}
    json.dump(out, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0 if all(r["pass"] for r in results) else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    logging.basicConfig(level=logging.INFO)
    sys.exit(main(parser.parse_args()))
