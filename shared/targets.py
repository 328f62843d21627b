"""Retargeting targets and body sides: the one place their names are defined.

A target is one robot frame the retargeter places and the solver tracks, named
``<side>_<part>`` (``left_wrist``, ...). Code asks this module for a target's side or
its arm's wrist instead of parsing the name.
"""

from __future__ import annotations

#: Body sides, in the order every per-side loop uses.
SIDES: tuple[str, ...] = ("left", "right")
#: Wrist targets (position + orientation), one per side, in ``SIDES`` order.
WRISTS: tuple[str, ...] = tuple(f"{s}_wrist" for s in SIDES)
#: Elbow targets (position only), one per side, in ``SIDES`` order.
ELBOWS: tuple[str, ...] = tuple(f"{s}_elbow" for s in SIDES)
#: Every retargeting target, in the robot base frame, in wire order.
TARGET_NAMES: tuple[str, ...] = WRISTS + ELBOWS

_SIDE_OF = {t: s for s, w, e in zip(SIDES, WRISTS, ELBOWS, strict=True) for t in (w, e)}


def side_of(target: str) -> str:
    """Side (``"left"``/``"right"``) of a target name.

    Raises:
        KeyError: not a target name.
    """
    try:
        return _SIDE_OF[target]
    except KeyError:
        raise KeyError(f"unknown target {target!r}; targets: {list(TARGET_NAMES)}") from None


def wrist_of(side_or_target: str) -> str:
    """Wrist target of a side or of any target on that side (``left_elbow`` -> ``left_wrist``)."""
    side = side_or_target if side_or_target in SIDES else side_of(side_or_target)
    return WRISTS[SIDES.index(side)]


def elbow_of(side_or_target: str) -> str:
    """Elbow target of a side or of any target on that side (``left_wrist`` -> ``left_elbow``)."""
    side = side_or_target if side_or_target in SIDES else side_of(side_or_target)
    return ELBOWS[SIDES.index(side)]
