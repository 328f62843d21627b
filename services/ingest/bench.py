"""Ingest figures as JSON: clips loaded, parse speed, the error a broken file gives.

Run: ``mimic bench ingest [--mocap-dir DIR] [--repeat N]``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from services.ingest.clip import ClipError, load_clip
from services.ingest.demo_motion import generate_demo_clips
from shared.paths import mocap_dir
from shared.report import emit_json

DEFAULT_MOCAP = mocap_dir()


def _speed(path: Path, repeat: int) -> tuple[int, float]:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        clip = load_clip(path)
        times.append(time.perf_counter() - t)
    return clip.n_frames, statistics.median(times)


def broken_file_errors(workdir: Path, source: Path | None) -> dict[str, str]:
    """Exact error texts for a few broken files built from a real one (or the demo)."""
    text = source.read_text() if source else ""
    lines = text.splitlines()
    cases = {
        "truncated_hierarchy": "\n".join(lines[: len(lines) // 8]),
        "truncated_motion": "\n".join([*lines[:-3], " ".join(lines[-1].split()[:10])]),
        "bad_number": text.replace(lines[-1], lines[-1].replace(lines[-1].split()[5], "abc", 1)),
        "unknown_rig": text.replace("Hips", "Bassin").replace("LeftArm", "BrasG").replace("Hand_L", "MainG")
        .replace("UpperArm_L", "BrasG"),
    }  # fmt: skip
    out = {}
    for name, body in cases.items():
        p = workdir / f"{name}.bvh"
        p.write_text(body)
        try:
            load_clip(p)
            out[name] = "(loaded without error)"
        except ClipError as exc:
            out[name] = str(exc)
    return out


def run(mocap_dir: Path, repeat: int) -> dict:
    res: dict = {"mocap_dir": str(mocap_dir)}
    files = sorted((mocap_dir / "bvh").glob("*.bvh")) + sorted((mocap_dir / "c3d").glob("*.c3d"))
    loaded, failed, frames, seconds = [], {}, 0, 0.0
    per_format: dict[str, list[float]] = {}
    for f in files:
        try:
            n, s = _speed(f, repeat)
        except ClipError as exc:
            failed[f.name] = str(exc)
            continue
        loaded.append(f.name)
        frames += n
        seconds += s
        per_format.setdefault(f.suffix.lower(), []).append(n / s)
    with tempfile.TemporaryDirectory() as tmp:
        demo = generate_demo_clips(Path(tmp) / "demo")
        for p in demo:
            n, s = _speed(p, repeat)
            per_format.setdefault("demo_bvh", []).append(n / s)
        source = next((f for f in files if f.suffix == ".bvh"), demo[0])
        res["broken_file_errors"] = broken_file_errors(Path(tmp), source)
    res.update(
        {
            "clips_found": len(files),
            "clips_loaded": len(loaded),
            "load_failures": failed,
            "frames_total": frames,
            "parse_frames_per_s_overall": round(frames / seconds, 1) if seconds else None,
            "parse_frames_per_s_median": {k: round(statistics.median(v), 1) for k, v in per_format.items()},
            "repeat": repeat,
        }
    )
    return res


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Flags of ``mimic bench ingest``."""
    p.add_argument("--mocap-dir", type=Path, default=DEFAULT_MOCAP, help="real clips (bvh/, c3d/)")
    p.add_argument("--repeat", type=int, default=3, help="loads per file (median time)")


def main(args: argparse.Namespace) -> int:
    emit_json(run(args.mocap_dir, args.repeat))
    return 0
