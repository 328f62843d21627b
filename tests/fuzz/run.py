"""Fuzz every decoder with N adversarial payloads per message type and print JSON.

    python -m tests.fuzz.run --examples 100000 --json runs/fuzz.json

One worker process per message type (``--jobs`` at a time). A crash is any
exception other than MessageError escaping a decoder, or an accepted message
that is not entirely valid (see :func:`tests.fuzz.fuzz_payloads.check_payload`).
Exit status 1 when there was any crash.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

from shared.messages import MESSAGE_TYPES
from shared.report import emit_json
from tests.fuzz.fuzz_payloads import adversarial_payload, check_payload, for_each_drawn


def fuzz_type(type_name: str, examples: int, rng_seed: int = 0) -> dict:
    """Run ``examples`` payloads through ``type_name``'s decoder; outcome counts and crash samples."""
    cls = MESSAGE_TYPES[type_name]
    outcomes: Counter[str] = Counter()
    crashes: list[str] = []

    def check(payload: bytes) -> None:
        try:
            outcomes[check_payload(cls, payload)] += 1
        except Exception as exc:  # counted, not raised: the run reports every crash
            outcomes["crash"] += 1
            if len(crashes) < 5:
                crashes.append(f"{type(exc).__name__}: {exc} | payload[:80]={payload[:80]!r}\n{traceback.format_exc()}")

    t0 = time.perf_counter()
    for_each_drawn(adversarial_payload(type_name), examples, check, rng_seed)
    elapsed = time.perf_counter() - t0
    rejected = {k.split(":", 1)[1]: v for k, v in sorted(outcomes.items()) if k.startswith("rejected:")}
    return {
        "type": type_name,
        "examples": sum(outcomes.values()),
        "accepted": outcomes["accepted"],
        "rejected": sum(rejected.values()),
        "rejected_by_reason": rejected,
        "crashes": outcomes["crash"],
        "crash_samples": crashes,
        "seconds": round(elapsed, 2),
        "us_per_example": round(1e6 * elapsed / max(1, sum(outcomes.values())), 1),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--examples", type=int, default=100_000, help="payloads per message type")
    p.add_argument("--types", nargs="*", default=sorted(MESSAGE_TYPES), help="message types to fuzz")
    p.add_argument("--jobs", type=int, default=2, help="worker processes")
    p.add_argument("--seed", type=int, default=0, help="hypothesis seed")
    p.add_argument("--json", default=None, help="also write the report here")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(
            pool.map(fuzz_type, args.types, [args.examples] * len(args.types), [args.seed] * len(args.types))
        )
    report = {
        "examples_per_type": args.examples,
        "total_examples": sum(r["examples"] for r in results),
        "total_crashes": sum(r["crashes"] for r in results),
        "wall_seconds": round(time.perf_counter() - t0, 1),
        "types": results,
    }
    emit_json(report, args.json, indent=1)
    return 1 if report["total_crashes"] else 0


if __name__ == "__main__":
    sys.exit(main())
