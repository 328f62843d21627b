"""Joint limits as box bounds on the joint velocity qd (n,) [rad/s] for one step dt [s].

A :class:`Limit` turns a configuration into ``lb <= qd <= ub``. Position
limits become ``(lower - q) / dt <= qd <= (upper - q) / dt`` so that one step
of ``q + qd dt`` cannot leave them; velocity limits are ``|qd| <= vmax``.
:func:`velocity_bounds` intersects any set of limits and repairs the one
inconsistent case (q already outside its position limits, faster return than
vmax allows) by letting the velocity limit win: the joint returns at vmax.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np

from shared.kinematics.configuration import Configuration


class Limit(ABC):
    """A joint limit expressed as velocity box bounds."""

    @abstractmethod
    def compute_velocity_bounds(self, configuration: Configuration, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(lb (n,), ub (n,)) [rad/s] for a step dt [s]."""

    def compute_qp_inequalities(self, configuration: Configuration, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The same bounds as ``G qd <= h``: G (2n, n) = [I; -I], h (2n,) = [ub; -lb]."""
        lb, ub = self.compute_velocity_bounds(configuration, dt)
        n = lb.shape[0]
        return np.vstack([np.eye(n), -np.eye(n)]), np.concatenate([ub, -lb])


class ConfigurationLimit(Limit):
    """Joint position limits [rad] turned into velocity bounds.

    Args:
        lower, upper: (n,) position limits [rad] (the model's, margin applied).
        gain: in (0, 1]; fraction of the remaining distance one step may cover
            (1 = reach the limit in one step).
    """

    def __init__(self, lower: np.ndarray, upper: np.ndarray, gain: float = 1.0):
        lower = np.asarray(lower, dtype=float)
        upper = np.asarray(upper, dtype=float)
        if lower.shape != upper.shape or np.any(lower > upper):
            raise ValueError("position limits: lower and upper must have one shape and lower <= upper")
        if not 0.0 < gain <= 1.0:
            raise ValueError(f"position limit gain must be in (0, 1], got {gain}")
        self.lower, self.upper, self.gain = lower, upper, float(gain)
        self._lb = np.zeros_like(lower)
        self._ub = np.zeros_like(upper)

    def compute_velocity_bounds(self, configuration: Configuration, dt: float) -> tuple[np.ndarray, np.ndarray]:
        k = self.gain / dt
        np.subtract(self.lower, configuration.q, out=self._lb)
        self._lb *= k
        np.subtract(self.upper, configuration.q, out=self._ub)
        self._ub *= k
        return self._lb, self._ub


class VelocityLimit(Limit):
    """Joint velocity limits ``|qd| <= vmax`` (n,) [rad/s]."""

    def __init__(self, vmax: np.ndarray):
        vmax = np.asarray(vmax, dtype=float)
        if np.any(vmax <= 0) or not np.all(np.isfinite(vmax)):
            raise ValueError("velocity limits must be finite and > 0")
        self.vmax = vmax
        self._neg = -vmax

    def compute_velocity_bounds(self, configuration: Configuration, dt: float) -> tuple[np.ndarray, np.ndarray]:
        return self._neg, self.vmax


def velocity_bounds(
    limits: Sequence[Limit],
    configuration: Configuration,
    dt: float,
    out: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Intersection of all limits as (lb (n,), ub (n,)) [rad/s], always with lb <= ub.

    Args:
        limits: limits to intersect (at least one).
        configuration: current configuration.
        dt: step [s], > 0.
        out: optional preallocated (lb, ub) buffers.
    """
    if dt <= 0:
        raise ValueError(f"dt must be > 0, got {dt}")
    if not limits:
        raise ValueError("velocity_bounds needs at least one limit")
    n = configuration.nv
    lb, ub = out if out is not None else (np.empty(n), np.empty(n))
    lb.fill(-np.inf)
    ub.fill(np.inf)
    for limit in limits:
        llb, lub = limit.compute_velocity_bounds(configuration, dt)
        np.maximum(lb, llb, out=lb)
        np.minimum(ub, lub, out=ub)
    crossed = lb > ub
    if crossed.any():
        # q outside its position limits: the bounds cross. The bound nearer zero is the velocity
        # limit, which wins: the joint moves back at vmax.
        v = np.where(np.abs(lb) < np.abs(ub), lb, ub)
        lb[crossed] = v[crossed]
        ub[crossed] = v[crossed]
    return lb, ub
