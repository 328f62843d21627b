"""Which real clip reaches forward: measured from the clips at run time (no clip named in a test)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: A reach counts when the hand stays ahead for this long [s] (a wave passes through quickly).
HOLD_S = 0.5


def sustained_forward_reach(clip_path: Path, bone: str = "right_wrist", hold_s: float = HOLD_S) -> float:
    """Largest forward displacement [m] (pelvis-frame x) of ``bone`` from its first frame that it keeps
    for ``hold_s`` seconds (the maximum over the clip of the running minimum over ``hold_s``)."""
    from services.ingest.clip import load_clip

    c = load_clip(clip_path)
    x = c.positions[bone][:, 0]
    dx = x - x[0]
    n = max(1, round(hold_s * c.fps))
    if len(dx) < n:
        return float("-inf")
    windows = np.lib.stride_tricks.sliding_window_view(dx, n)
    return float(np.nanmax(np.nanmin(windows, axis=1)))


def forward_reach_clip(clips: list[Path], bone: str = "right_wrist") -> tuple[Path, float]:
    """(clip, reach [m]) of the clip whose ``bone`` reaches forward the furthest, held ``HOLD_S``."""
    reach = {c: sustained_forward_reach(c, bone) for c in clips}
    best = max(reach, key=reach.get)
    return best, reach[best]
