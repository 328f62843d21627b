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
