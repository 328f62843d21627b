"""Wrist-only sources: what a VR headset's controllers or hand tracking give (one pose per hand).

:func:`wrists_only` reduces a full HumanFrame to its hand bones, so a recorded clip can stand
in for such a device (``mimic publish --wrist-only``, ``mimic eval --wrist-only``).
"""

from __future__ import annotations

from shared.messages import HumanFrame

#: Bones a hand-only device provides (canonical names; ``*_hand`` when the rig has them).
HAND_BONES: tuple[str, ...] = ("left_wrist", "right_wrist", "left_hand", "right_hand")


def wrists_only(frame: HumanFrame) -> HumanFrame:
    """The same frame with every bone but the hands removed (header, source and root kept)."""
    bones = {n: b for n, b in frame.bones.items() if n in HAND_BONES}
    return HumanFrame(frame.hdr, frame.source, frame.root, bones, frame.oriented)


def is_wrist_only(frame: HumanFrame) -> bool:
    """True when the frame has valid hand bones and no valid shoulder or elbow."""
    arm = [b for n, b in frame.bones.items() if n.endswith(("_shoulder", "_elbow")) and b.valid]
    hands = [b for n, b in frame.bones.items() if n in HAND_BONES and b.valid]
    return bool(hands) and not arm
