"""Retargeting figures over recorded clips, printed as JSON.

``mimic bench retarget [CLIP ...] [--modes paper bounded incremental] [--consistent-targets]``
(default: every ``.bvh`` in ``$MIMIC_MOCAP_DIR/bvh`` or ``../shared/data/mocap/bvh``).
Each clip is calibrated the way the live service does it (anthropometric, first frame)
and retargeted frame by frame; reported per mode: frames, targets outside the robot
box, frames where the bounded clamp acted, and ``Retargeter.step`` wall and CPU time percentiles.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from services.retarget.mapping import MODES
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.paths import mocap_dir
from shared.report import emit_json
from shared.targets import TARGET_NAMES

DEFAULT_DIR = mocap_dir()


def evaluate(paths: list[Path], modes: tuple[str, ...], consistent_targets: bool = False) -> dict:
    """Figures per mode over the clips (see module doc)."""
    from services.ingest.clip import load_clip

    clips = [load_clip(p) for p in paths]
    base = Retargeter(RetargetConfig())
    report: dict = {"clips": [c.name for c in clips], "workspace": base.workspace.summary(), "modes": {}}
    report["consistent_targets"] = consistent_targets
    for mode in modes:
        outside = dict.fromkeys(TARGET_NAMES, 0)
        clamped = dict.fromkeys(TARGET_NAMES, 0)
        step_us, cpu_us, frames = [], [], 0
        for clip in clips:
            cfg = RetargetConfig(mode=mode, consistent_targets=consistent_targets)
            r = Retargeter(cfg, workspace=base.workspace, robot=base.robot)
            for i in range(clip.n_frames):
                f = clip.frame(i, seq=i + 1)
                t0, c0 = time.perf_counter(), time.process_time()
                out = r.step(f)
                step_us.append((time.perf_counter() - t0) * 1e6)
                cpu_us.append((time.process_time() - c0) * 1e6)
                frames += 1
                for t in TARGET_NAMES:
                    outside[t] += int(out is not None and not base.workspace.contains(t, out.targets[t].p))
            for t in TARGET_NAMES:
                clamped[t] += r.counts.get(f"clamped_{t}", 0)
        report["modes"][mode] = {
            "frames": frames,
            "outside_box": outside,
            "clamped": clamped,
            "step_us": _percentiles(step_us),
            # CPU time of the step: on a loaded machine the wall time's tail is mostly waiting for a core
            "step_cpu_us": _percentiles(cpu_us) | {"mean": round(float(np.mean(cpu_us)), 1)},
        }
    return report


def _percentiles(us: list[float]) -> dict:
    return {q: round(float(np.percentile(us, int(q[1:]))), 1) for q in ("p50", "p95", "p99")}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Flags of ``mimic bench retarget``."""
    p.add_argument("clips", nargs="*", type=Path, help="clips (default: every BVH of the real set)")
    p.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES), help="mapping modes")
    p.add_argument(
        "--consistent-targets", action="store_true", help="with RetargetConfig.consistent_targets (the arm posture IK)"
    )


def main(args: argparse.Namespace) -> int:
    paths = args.clips or sorted((DEFAULT_DIR / "bvh").glob("*.bvh"))
    if not paths:
        emit_json({"error": f"no clips given and none in {DEFAULT_DIR / 'bvh'}"})
        return 2
    emit_json(evaluate(paths, tuple(args.modes), args.consistent_targets))
    return 0
