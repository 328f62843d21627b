"""Kinematics core (mink/pink style): configuration and tasks.

Import tree: exceptions -> configuration -> tasks. The solvers live in
``services/solver`` and take prioritised levels of these tasks; the joint limits of a
solver step are ``services/solver/bounds.py``.
"""

from shared.kinematics.alignment_task import AlignmentTask, JointVelocityTask, delta_jacobian, orientation_delta
from shared.kinematics.configuration import Configuration
from shared.kinematics.exceptions import (
    InvalidConfigurationError,
    InvalidFrameError,
    InvalidTargetError,
    KinematicsError,
)
from shared.kinematics.frame_task import FrameTask
from shared.kinematics.position_task import PositionTask
from shared.kinematics.posture_task import PostureTask
from shared.kinematics.task import Task

__all__ = [
    "AlignmentTask",
    "Configuration",
    "FrameTask",
    "InvalidConfigurationError",
    "InvalidFrameError",
    "InvalidTargetError",
    "JointVelocityTask",
    "KinematicsError",
    "PositionTask",
    "PostureTask",
    "Task",
    "delta_jacobian",
    "orientation_delta",
]
