"""Kinematics core (mink/pink style): configuration, tasks, limits.

Import tree: exceptions -> configuration -> tasks / limits. The solvers live in
``services/solver`` and take prioritised levels of these tasks.
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
from shared.kinematics.limits import ConfigurationLimit, Limit, VelocityLimit, velocity_bounds
from shared.kinematics.position_task import PositionTask
from shared.kinematics.posture_task import PostureTask
from shared.kinematics.task import Task

__all__ = [
    "AlignmentTask",
    "Configuration",
    "ConfigurationLimit",
    "FrameTask",
    "InvalidConfigurationError",
    "InvalidFrameError",
    "InvalidTargetError",
    "JointVelocityTask",
    "KinematicsError",
    "Limit",
    "PositionTask",
    "PostureTask",
    "Task",
    "VelocityLimit",
    "delta_jacobian",
    "orientation_delta",
    "velocity_bounds",
]
