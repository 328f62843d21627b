"""Errors raised by the kinematics core, with messages that list valid choices."""

from __future__ import annotations


class KinematicsError(ValueError):
    """Base class of kinematics-core errors."""


class InvalidFrameError(KinematicsError):
    """A frame name that the model does not hold."""

    def __init__(self, name: str, known: list[str]):
        super().__init__(f"unknown frame {name!r}; known targets and frames: {known}")
        self.name = name


class InvalidTargetError(KinematicsError):
    """A task target of the wrong shape or with non-finite values."""


class InvalidConfigurationError(KinematicsError):
    """A joint vector of the wrong size or with non-finite values."""
