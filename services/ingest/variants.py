"""Held-out variants of a recorded clip: its mirror image and the same motion played faster or slower.

Issue 12's goals are to hold on motion nobody tuned for (other performers, other motion types). A
mirrored clip is the same motion performed by a mirror-image operator (a left-handed wave from a
right-handed one), and a clip played at ``speed`` 1.25 is the same performer 25 % faster: both are real
motion, and neither was seen by anyone who set a default. ``mimic eval --mirror --speed S`` evaluates
them (``services/evaluation/README.md``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from services.ingest.clip import Clip
from shared.mirror import mirror_points, mirror_quats, swap_side


def mirrored(clip: Clip) -> Clip:
    """The clip performed by the operator's mirror image.

    Every bone is reflected through the sagittal plane (the pelvis frame's x-z plane; the root through the
    world's x-z plane) and each side's bones become the other side's: the left hand's wave becomes a right
    hand's. Positions ``p' = M p``, orientations ``R' = M R M`` (:mod:`shared.mirror`); validity follows its
    bone. Mirroring twice gives the clip back.
    """

    def swap(d: dict[str, np.ndarray], f) -> dict[str, np.ndarray]:
        return {swap_side(b): f(v) for b, v in d.items()}

    return replace(
        clip,
        positions=swap(clip.positions, mirror_points),
        quats=swap(clip.quats, mirror_quats),
        valid=swap(clip.valid, np.copy),
        root_p=mirror_points(clip.root_p),
        root_q=mirror_quats(clip.root_q),
        meta={**clip.meta, "mirrored": not clip.meta.get("mirrored", False)},
    )


def played_at(clip: Clip, speed: float) -> Clip:
    """The same frames played ``speed`` times as fast: clip time and frame rate scaled, poses unchanged.

    Raises:
        ValueError: ``speed`` is not a finite number > 0.
    """
    if isinstance(speed, bool) or not isinstance(speed, int | float) or not (math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be a finite number > 0, got {speed!r}")
    return replace(
        clip,
        fps=clip.fps * float(speed),
        times=clip.times / float(speed),
        meta={**clip.meta, "speed": clip.meta.get("speed", 1.0) * float(speed)},
    )
