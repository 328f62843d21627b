"""Embedded operator motions for the demo: a box lift and an ellipse drawn with a hand.

A human skeleton of adult proportions (1.75 m, CMU-style joint names, Y-up,
centimetres, facing +Z, T-pose at zero rotation) performs the two test
motions of seed 000. Wrist paths are designed in Cartesian space, the arms
solved with a two-link IK whose elbow swivel follows a hint direction (elbows
bent outward for the box), and everything is written with
:func:`~services.ingest.bvh.write_bvh` so the demo reads it back through the
same reader as real files.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from services.ingest.bvh import BvhData, BvhJoint, write_bvh
from services.ingest.rotations import matrix_to_euler
from shared.report import emit_json

log = logging.getLogger(__name__)

DEMO_FPS = 60.0
_ROOT_CH = ["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]
_ROT_CH = ["Zrotation", "Xrotation", "Yrotation"]

#: (name, parent, offset [cm], end site [cm] or None); Y up, +X = operator's left, +Z forward.
SKELETON: tuple[tuple[str, str | None, tuple[float, float, float], tuple[float, float, float] | None], ...] = (
    ("Hips", None, (0.0, 0.0, 0.0), None),
    ("Spine", "Hips", (0.0, 10.0, 0.0), None),
    ("Spine1", "Spine", (0.0, 15.0, 0.0), None),
    ("Neck", "Spine1", (0.0, 22.0, -1.0), None),
    ("Head", "Neck", (0.0, 10.0, 1.0), (0.0, 18.0, 0.0)),
    ("LeftShoulder", "Spine1", (2.0, 19.0, 0.0), None),
    ("LeftArm", "LeftShoulder", (16.0, 0.0, 0.0), None),
    ("LeftForeArm", "LeftArm", (29.0, 0.0, 0.0), None),
    ("LeftHand", "LeftForeArm", (26.0, 0.0, 0.0), (18.0, 0.0, 0.0)),
    ("RightShoulder", "Spine1", (-2.0, 19.0, 0.0), None),
    ("RightArm", "RightShoulder", (-16.0, 0.0, 0.0), None),
    ("RightForeArm", "RightArm", (-29.0, 0.0, 0.0), None),
    ("RightHand", "RightForeArm", (-26.0, 0.0, 0.0), (-18.0, 0.0, 0.0)),
    ("LeftUpLeg", "Hips", (9.0, -5.0, 0.0), None),
    ("LeftLeg", "LeftUpLeg", (0.0, -44.0, 0.0), None),
    ("LeftFoot", "LeftLeg", (0.0, -43.0, 0.0), (0.0, -7.0, 13.0)),
    ("RightUpLeg", "Hips", (-9.0, -5.0, 0.0), None),
    ("RightLeg", "RightUpLeg", (0.0, -44.0, 0.0), None),
    ("RightFoot", "RightLeg", (0.0, -43.0, 0.0), (0.0, -7.0, 13.0)),
)
HIP_HEIGHT = 100.0  # [cm]
#: Wrists [cm] of the arms hanging at the sides, where every demo motion starts and ends.
REST_WRIST = {"Left": np.array([21.0, 92.0, 6.0]), "Right": np.array([-21.0, 92.0, 6.0])}
#: Elbow direction hints there: the elbows a little out and behind, as arms hang.
REST_HINT = {"Left": np.array([0.3, 0.0, -1.0]), "Right": np.array([-0.3, 0.0, -1.0])}
_IDX = {name: i for i, (name, *_rest) in enumerate(SKELETON)}


def min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk blend 0 -> 1 for tau in [0, 1] (clipped outside)."""
    t = np.clip(tau, 0.0, 1.0)
    return t**3 * (10.0 - 15.0 * t + 6.0 * t**2)


def _rot_x(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((len(a), 3, 3))
    R[:, 0, 0] = 1.0
    R[:, 1, 1], R[:, 1, 2], R[:, 2, 1], R[:, 2, 2] = c, -s, s, c
    return R


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def two_link_ik(S: np.ndarray, W: np.ndarray, a: float, b: float, hint: np.ndarray) -> np.ndarray:
    """Elbow position for shoulder S, wrist target W, link lengths a, b [cm].

    The elbow lies in the plane of (W - S) and ``hint``, on the ``hint`` side.
    Targets out of reach are pulled back onto the reachable shell.

    Args:
        S, W: (T, 3) points. hint: (T, 3) or (3,) elbow direction hint.

    Returns:
        (T, 3) elbow positions.
    """
    d_vec = W - S
    d = np.clip(np.linalg.norm(d_vec, axis=1), abs(a - b) + 1e-3, a + b - 1e-3)
    u = _unit(d_vec)
    x = (a * a - b * b + d * d) / (2.0 * d)
    r = np.sqrt(np.maximum(a * a - x * x, 0.0))
    h = np.broadcast_to(hint, S.shape)
    v = h - np.sum(h * u, axis=1, keepdims=True) * u
    # hint parallel to the reach: any perpendicular keeps the lengths right
    alt = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    v = _unit(np.where(np.linalg.norm(v, axis=1, keepdims=True) > 1e-9, v, alt))
    return S + x[:, None] * u + r[:, None] * v


def _segment_R(d: np.ndarray, n: np.ndarray, sign: float) -> np.ndarray:
    """Segment frame with x along ``sign * d`` and z along ``n`` (orthogonalised)."""
    x = sign * _unit(d)
    z = _unit(n - np.sum(n * x, axis=1, keepdims=True) * x)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def synthesize(
    T: int,
    fps: float,
    lean: np.ndarray,
    wrists: dict[str, np.ndarray],
    hints: dict[str, np.ndarray],
) -> BvhData:
    """Build a BVH motion from trunk lean and wrist paths.

    Args:
        T: frames. fps: [Hz].
        lean: (T,) forward trunk lean [rad] (split over Spine and Spine1).
        wrists: "Left"/"Right" -> (T, 3) wrist targets in the world [cm] (Y up).
        hints: "Left"/"Right" -> (3,) or (T, 3) elbow direction hints.
    """
    J = len(SKELETON)
    Rg = np.tile(np.eye(3), (T, J, 1, 1))
    pg = np.zeros((T, J, 3))
    pg[:, 0] = (0.0, HIP_HEIGHT, 0.0)
    half = _rot_x(lean / 2.0)
    Rg[:, _IDX["Spine"]] = half
    Rg[:, _IDX["Spine1"]] = half @ half
    # head stays level: Neck/Head global identity
    for ji, (name, parent, off, _end) in enumerate(SKELETON):
        if parent is None:
            continue
        pi = _IDX[parent]
        pg[:, ji] = pg[:, pi] + Rg[:, pi] @ np.asarray(off)
        if name in ("LeftShoulder", "RightShoulder"):
            Rg[:, ji] = Rg[:, pi]
        if name in ("LeftArm", "RightArm"):
            side = name[:-3]
            sign = 1.0 if side == "Left" else -1.0
            a = abs(SKELETON[_IDX[f"{side}ForeArm"]][2][0])
            b = abs(SKELETON[_IDX[f"{side}Hand"]][2][0])
            S, W = pg[:, ji], wrists[side]
            E = two_link_ik(S, W, a, b, hints[side])
            n = np.cross(E - S, W - E)
            # elbow flexion axis; sign keeps z of the segment frames near rest (+Z for the left arm)
            n = sign * n
            n = np.where(np.linalg.norm(n, axis=1, keepdims=True) > 1e-6, n, (0.0, 0.0, 1.0))
            Rg[:, ji] = _segment_R(E - S, n, sign)
            fa, hd = _IDX[f"{side}ForeArm"], _IDX[f"{side}Hand"]
            Rg[:, fa] = _segment_R(W - E, n, sign)
            Rg[:, hd] = Rg[:, fa]
    # local rotations -> ZXY Euler channels
    cols = [pg[:, 0], matrix_to_euler("ZXY", Rg[:, 0])]
    for ji, (_name, parent, _off, _end) in enumerate(SKELETON[1:], start=1):
        Rl = np.swapaxes(Rg[:, _IDX[parent]], 1, 2) @ Rg[:, ji]
        cols.append(matrix_to_euler("ZXY", Rl))
    motion = np.concatenate(cols, axis=1)
    joints, ch = [], 0
    for name, parent, off, end in SKELETON:
        chans = _ROOT_CH if parent is None else _ROT_CH
        joints.append(
            BvhJoint(
                name,
                -1 if parent is None else _IDX[parent],
                np.asarray(off, float),
                list(chans),
                None if end is None else np.asarray(end, float),
                ch,
            )
        )
        ch += len(chans)
    return BvhData(joints, 1.0 / fps, motion)


def _away_from_rest(t: np.ndarray, duration: float) -> np.ndarray:
    """(T,) 0 at rest, 1 in the motion: a minimum-jerk second out of rest at the start, back in at the end."""
    return min_jerk(t / 1.0) - min_jerk((t - (duration - 1.0)) / 1.0)


def _from_rest(
    t: np.ndarray, duration: float, wrists: dict[str, np.ndarray], hints: dict[str, np.ndarray]
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Wrist paths and elbow hints that leave the rest pose in the first second and are back at it in the last.

    Why: the demo plays its motions one after another in a loop; a motion that started or ended away from rest
    made the operator's hands jump (13 cm from the box held low to the hanging arms of the ellipse), and the
    robot race across the gap by its own route, past its torso. Every motion here starts and ends at
    ``REST_WRIST`` with the elbows towards ``REST_HINT``, so the loop is continuous.

    Args:
        t: (T,) frame times [s]. duration: [s].
        wrists: "Left"/"Right" -> (T, 3) the motion's wrist paths [cm].
        hints: "Left"/"Right" -> (3,) or (T, 3) the motion's elbow direction hints.
    """
    w = _away_from_rest(t, duration)[:, None]
    return (
        {side: REST_WRIST[side] + w * (p - REST_WRIST[side]) for side, p in wrists.items()},
        {side: REST_HINT[side] + w * (np.asarray(h) - REST_HINT[side]) for side, h in hints.items()},
    )


def box_lift(fps: float = DEMO_FPS, duration: float = 7.6) -> BvhData:
    """Both hands hold a 34 cm box by its sides, elbows bent outward, lift it from hip to chest height and back.

    Phases [s]: reach from rest to the box 0-1, hold low 1-1.4, lift 1.4-3.4, hold high 3.4-4.2, lower 4.2-6.0,
    hold low, let go and back to rest in the last second.
    """
    t = np.arange(round(duration * fps)) / fps
    s = min_jerk((t - 1.4) / 2.0) - min_jerk((t - 4.2) / 1.8)
    low, high = np.array([0.0, 106.0, 30.0]), np.array([0.0, 134.0, 36.0])
    center = low + s[:, None] * (high - low)
    half_w = 17.0
    offset = np.array([half_w, 0.0, 0.0])
    wrists, hints = _from_rest(
        t,
        duration,
        {"Left": center + offset, "Right": center - offset},
        {"Left": np.array([1.0, -0.35, 0.0]), "Right": np.array([-1.0, -0.35, 0.0])},
    )
    lean = np.radians(8.0) * (1.0 - s) * _away_from_rest(t, duration)  # leaning over the box held low
    return synthesize(len(t), fps, lean, wrists, hints)


def ellipse(fps: float = DEMO_FPS, duration: float = 7.0, laps: float = 2.0) -> BvhData:
    """The right hand draws a vertical ellipse (30 x 20 cm) in front of the chest; the left arm hangs.

    The hand moves from rest to the ellipse (0-1 s), traces ``laps`` laps, and returns (last second).
    """
    t = np.arange(round(duration * fps)) / fps
    c = np.array([-20.0, 128.0, 38.0])
    a, b = 15.0, 10.0
    trace = duration - 2.0
    phase = 2.0 * np.pi * laps * min_jerk((t - 1.0) / trace)
    path = c + np.stack([a * np.cos(phase), b * np.sin(phase), np.zeros_like(phase)], axis=1)
    left = np.tile(REST_WRIST["Left"], (len(t), 1))
    wrists, hints = _from_rest(
        t, duration, {"Left": left, "Right": path}, {"Left": REST_HINT["Left"], "Right": np.array([-0.6, -1.0, -0.2])}
    )
    return synthesize(len(t), fps, np.zeros(len(t)), wrists, hints)


DEMO_MOTIONS: dict[str, Callable[..., BvhData]] = {"box_lift": box_lift, "ellipse": ellipse}


def generate_demo_clips(outdir: str | Path, fps: float = DEMO_FPS) -> list[Path]:
    """Write the demo motions as BVH files (``box_lift.bvh``, ``ellipse.bvh``) into ``outdir``.

    Returns:
        The written paths, in :data:`DEMO_MOTIONS` order.
    """
    outdir = Path(outdir)
    paths = [write_bvh(outdir / f"{name}.bvh", make(fps=fps)) for name, make in DEMO_MOTIONS.items()]
    log.info("wrote demo motions %s", [str(p) for p in paths])
    return paths


def demo_clip_paths(names: list[str], outdir: str | Path | None = None) -> list[Path]:
    """BVH files of the demo motions ``names`` (keys of :data:`DEMO_MOTIONS`), generated into ``outdir``
    (None: a fresh temporary folder: the motions are generated, not shipped, so they go where nothing else lives).

    Raises:
        ValueError: an unknown name (one line, naming the known ones).
    """
    unknown = [n for n in names if n not in DEMO_MOTIONS]
    if unknown:
        raise ValueError(f"unknown demo motion(s) {unknown}; known: {sorted(DEMO_MOTIONS)}")
    if not names:
        return []
    paths = dict(zip(DEMO_MOTIONS, generate_demo_clips(outdir or tempfile.mkdtemp(prefix="mimic-demo-"))))
    return [paths[n] for n in names]


# --------------------------------------------------------------------------- CLI (mimic demo-motion)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("outdir", type=Path, help="output folder (the demo uses runs/demo_motion)")
    parser.add_argument("--fps", type=float, default=DEMO_FPS, help="frame rate [Hz] (default 60)")


def main(args: argparse.Namespace) -> int:
    """Generate the demo clips, read them back, print a JSON summary."""
    from services.ingest.clip import load_clip

    out = []
    for p in generate_demo_clips(args.outdir, args.fps):
        clip = load_clip(p)
        out.append(
            {
                "path": str(p),
                "frames": clip.n_frames,
                "fps": clip.fps,
                "duration_s": round(clip.duration, 3),
                "skeleton_map": clip.meta["skeleton_map"],
                "bones": clip.bones,
            }
        )
    emit_json({"demo_motion": out})
    return 0
