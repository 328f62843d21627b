"""Variants of the shipped robot profile written to a temporary folder (for tests that need a switch flipped)."""

from __future__ import annotations

import re
from pathlib import Path

from shared.robot.profile import load_profile


def g1_with_motor_acceleration_limits(folder: Path) -> str:
    """The G1 profile with ``motor_acceleration_limits = true``: each joint's acceleration limit is its
    ``[acceleration_limits]`` entry (what its motor can deliver) instead of the global cap. Returns the path."""
    text = load_profile().source.read_text()
    text, n = re.subn(r"^motor_acceleration_limits = .*$", "motor_acceleration_limits = true", text, flags=re.M)
    assert n == 1, "the G1 profile lost its motor_acceleration_limits switch"
    path = Path(folder) / "g1_motor_accel.toml"
    path.write_text(text.replace('name = "g1_29dof"', 'name = "g1_motor_accel"'))
    return str(path)


def g1_with_the_hand_as_wrist_point(folder: Path) -> str:
    """The G1 profile as it was before session 15: the wrist targets' position *and* orientation on the hand link
    (the wrist yaw link, 4.6 cm past the pitch axis the shipped profile puts the position on). The lock-up
    scenarios of the recovery tests were recorded with it; the shipped G1 does not run into them. Returns the
    path."""
    prof = load_profile()
    text = prof.source.read_text()
    for side in ("left", "right"):
        wrist = f"{side}_wrist"
        old = f'{wrist} = "{prof.frames[wrist]}"'
        assert text.count(old) == 1 and prof.orientation_frame(wrist) != prof.frames[wrist], "the G1 wrist frames moved"
        text = text.replace(old, f'{wrist} = "{prof.orientation_frame(wrist)}"')
    text = text.replace("[orientation_frames]", "[unused_orientation_frames]")
    path = Path(folder) / "g1_hand_wrist_point.toml"
    path.write_text(text.replace('name = "g1_29dof"', 'name = "g1_hand_wrist_point"'))
    return str(path)
