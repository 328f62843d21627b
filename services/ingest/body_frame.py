"""Units, up axis and pelvis-frame axes of a recording: one implementation for every file reader.

The BVH and C3D readers (and the Xsens stream for its units) turn a file's own
conventions into the canonical ones of :mod:`services.ingest.clip` through
these functions, so a file's units, its vertical axis and the left direction of
its pelvis frame are decided the same way whatever the format.
"""

from __future__ import annotations

import numpy as np

from services.ingest.errors import ClipError
from services.ingest.rotations import Y_UP_TO_Z_UP

#: Metres per file unit.
UNIT_SCALES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: Shoulder -> elbow -> wrist lengths [m] a unit must give to be taken for the file's: people from a child to a tall
#: adult (0.45-0.65 m for adults).
PLAUSIBLE_ARM = (0.25, 1.0)
#: The arm length [m] a file in none of the units is scaled to (``"scaled"``): the CMU database's BVH conversions use
#: 1/0.45 inch (an arm of 7.5 units), game rigs their own.
NOMINAL_ARM = 0.55
#: Canonical bones above the pelvis, highest first: the first one mapped gives the trunk direction.
TRUNK_TOPS = ("head", "neck", "chest", "spine")


def unit_scale(
    units: str, arm_length: float | None = None, where: str = "units", error: type[ClipError] = ClipError
) -> tuple[str, float]:
    """The file's length unit and its size in metres.

    Args:
        units: "m", "cm", "mm", "in", or "auto" (needs ``arm_length``): the first of m, cm, mm, in that makes the arm
            :data:`PLAUSIBLE_ARM`, else ``"scaled"``, the arm at :data:`NOMINAL_ARM` (the retargeting maps the
            operator's reach onto the robot's, so a rig's own unit only sets the speeds the checks see).
        arm_length: shoulder -> elbow -> wrist length [file units]; adults have 0.45-0.65 m.
        where: what the unit came from, for the error text.

    Returns:
        (unit, metres per unit).
    """
    if units == "auto" and arm_length is not None and arm_length > 0.0:
        lo, hi = PLAUSIBLE_ARM
        units = next((u for u, s in UNIT_SCALES.items() if lo <= arm_length * s <= hi), "scaled")
        if units == "scaled":
            return units, NOMINAL_ARM / arm_length
    if units not in UNIT_SCALES:
        raise error(f"{where} {units!r}; choose auto or one of {list(UNIT_SCALES)}")
    return units, UNIT_SCALES[units]


def arm_length(points: dict[str, np.ndarray], frame: int = 0) -> float:
    """Mean over both sides of shoulder -> elbow + elbow -> wrist at ``frame`` [file units].

    Args:
        points: canonical bone -> (T, 3) joint centre in the file's axes and units.
    """
    return float(
        np.mean(
            [
                np.linalg.norm(points[f"{s}_shoulder"][frame] - points[f"{s}_elbow"][frame])
                + np.linalg.norm(points[f"{s}_elbow"][frame] - points[f"{s}_wrist"][frame])
                for s in ("left", "right")
            ]
        )
    )


def trunk_top(points: dict[str, np.ndarray]) -> str | None:
    """The highest canonical trunk bone present in ``points`` (``TRUNK_TOPS`` order), or None."""
    return next((b for b in TRUNK_TOPS if b in points), None)


def up_axis(
    up: str, trunk: np.ndarray | None, where: str, error: type[ClipError] = ClipError
) -> tuple[str, np.ndarray]:
    """The file's vertical axis and the rotation that makes it our +Z.

    Args:
        up: "y", "z", or "auto": the axis along the median lower -> upper trunk direction.
        trunk: (T, 3) lower -> upper trunk vectors in the file's axes (NaN rows ignored), or None.
        where: file name for the error text.

    Returns:
        (up, A) with ``A`` (3, 3): ``p_zup = A @ p_file``.

    Raises:
        ClipError (or ``error``): no trunk to detect from, a body along +-X or upside down, a bad ``up``.
    """
    if up == "auto":
        if trunk is None:
            raise error(f"{where}: cannot detect the up axis (no spine/neck/head mapped); pass up='y' or 'z'")
        v = np.nanmedian(trunk, axis=0)
        k = int(np.argmax(np.abs(v)))
        if k == 0 or v[k] < 0:
            raise error(f"{where}: the body points along {'-+'[v[k] > 0]}{'XYZ'[k]}; pass up='y' or 'z'")
        up = "xyz"[k]
    if up not in ("y", "z"):
        raise ClipError(f"up {up!r}; choose auto, y or z")
    return up, (Y_UP_TO_Z_UP if up == "y" else np.eye(3))


def left_axis(pairs: list[tuple[str, np.ndarray | None, np.ndarray | None]]) -> tuple[np.ndarray, str] | None:
    """Right -> left direction of the pelvis frame from the first complete left/right pair.

    Args:
        pairs: (name, left point, right point) candidates in order of preference, e.g. hips (or
            front pelvis markers) before shoulders; points are (T, 3) or None when not in the file.

    Returns:
        ((T, 3) left - right, name of the pair used), or None when no pair is complete.
    """
    for name, left, right in pairs:
        if left is not None and right is not None:
            return left - right, name
    return None
