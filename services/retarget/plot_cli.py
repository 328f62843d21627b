"""``mimic retarget-plot CLIP --out DIR``: seed 000 Fig. 6 and Fig. 7 for a recorded clip.

Retargets every frame of the clip offline (same :class:`Retargeter` as the service) and
writes ``fig6_workspace.png``, ``fig7_left.png`` and ``fig7_right.png``; with
``--write-calibration FILE`` it also saves the operator calibration it used, which is
how a calibration recording becomes a file for ``mimic retarget --calibration``. Prints a JSON
report to stdout: files, calibration, per-target fraction of frames inside the robot
box and clamped, step time percentiles.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from services.retarget.cli import add_retarget_options, config_from_args
from shared.report import emit_json

log = logging.getLogger("mimic.retarget")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("clip", type=Path, help="motion clip (.bvh or .c3d)")
    p.add_argument("--out", type=Path, required=True, help="output folder for the PNG files")
    p.add_argument(
        "--calibrate",
        choices=("first-frame", "clip"),
        default="first-frame",
        help="without --calibration: anthropometric from the first frame (what the live service does) or "
        "extents from the whole clip",
    )
    p.add_argument(
        "--write-calibration",
        type=Path,
        default=None,
        help="save the calibration used (e.g. from a calibration recording with --calibrate clip) for "
        "`mimic retarget --calibration FILE`",
    )
    p.add_argument(
        "--skeleton-map", default=None, help="BVH skeleton map / C3D marker map file (TOML/JSON), as mimic publish"
    )
    add_retarget_options(p)


def main(args: argparse.Namespace) -> int:
    from services.ingest.clip import ClipError, load_clip
    from services.retarget.calibration import Calibration, CalibrationError, anthropometric, from_recording
    from services.retarget.plots import plot_trajectories, plot_workspaces
    from services.retarget.retargeter import Retargeter
    from shared.targets import SIDES, TARGET_NAMES

    try:
        clip = load_clip(args.clip, skeleton_map=args.skeleton_map)
        frames = [clip.frame(i, seq=i + 1) for i in range(clip.n_frames)]
        config = config_from_args(args)
        r = Retargeter(config)
        if args.calibration:
            cal = Calibration.load(args.calibration)
        elif args.calibrate == "clip":
            cal = from_recording(frames, bone_of=r.bone_of, name=clip.name)
        else:
            cal = anthropometric(frames[0], r.bone_of)
        r.set_calibration(cal)
        if args.write_calibration:
            cal.save(args.write_calibration)
    except (ClipError, CalibrationError, ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2

    T = len(frames)
    H = {t: np.full((T, 3), np.nan) for t in TARGET_NAMES}
    U = {t: np.full((T, 3), np.nan) for t in TARGET_NAMES}
    step_us = []
    for i, f in enumerate(frames):
        t0 = time.perf_counter()
        out = r.step(f)
        step_us.append((time.perf_counter() - t0) * 1e6)
        if out is None:
            continue
        for t in TARGET_NAMES:
            bone = f.bones.get(r.bone_of[t])
            if bone is not None and bone.valid and out.targets[t].valid:
                H[t][i] = bone.p
                U[t][i] = out.targets[t].p

    ws = r.workspace
    shoulders = {s: frames[0].bones[f"{s}_shoulder"].p for s in SIDES if f"{s}_shoulder" in frames[0].bones}
    out_dir = args.out
    files = [
        plot_workspaces(ws, cal, shoulders, out_dir / "fig6_workspace.png", operator_paths=H),
        *(
            plot_trajectories(
                clip.times, H, U, side, out_dir / f"fig7_{side}.png",
                title=f"Fig. 7: {clip.name}, {side} arm, {config.mode} mapping: operator (dashed) vs robot (solid)",
            )
            for side in SIDES
        ),
    ]  # fmt: skip
    report = {
        "clip": str(args.clip),
        "frames": T,
        "mode": config.mode,
        "calibration": cal.source,
        "workspace": ws.summary(),
        "files": [str(p) for p in files],
        "step_us": {
            "p50": round(float(np.percentile(step_us, 50)), 1),
            "p99": round(float(np.percentile(step_us, 99)), 1),
        },
        "targets": {},
        "rejects": dict(r.rejects),
    }
    for t in TARGET_NAMES:
        ok = np.all(np.isfinite(U[t]), axis=1)
        inside = np.all((U[t][ok] >= ws.lower[t] - 1e-9) & (U[t][ok] <= ws.upper[t] + 1e-9), axis=1)
        report["targets"][t] = {
            "valid_frames": int(ok.sum()),
            "inside_box": round(float(inside.mean()) if ok.any() else 0.0, 4),
            "clamped_frames": int(r.counts.get(f"clamped_{t}", 0)),
            "operator_range_m": np.round(np.nanmax(H[t], 0) - np.nanmin(H[t], 0), 3).tolist() if ok.any() else None,
            "robot_range_m": np.round(np.nanmax(U[t], 0) - np.nanmin(U[t], 0), 3).tolist() if ok.any() else None,
        }
    emit_json(report)
    return 0
