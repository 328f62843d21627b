"""Joints too slow for the tasks: kept out of every level and brought to rest within their own limits.

Why (issue 12; measured with ``mimic eval --no-sim``, see ``services/solver/README.md``): with the G1's motor
acceleration limits (``[model] motor_acceleration_limits = true``) the waist roll and pitch can change their
speed by 3.2 rad/s^2 and the waist yaw by 39, against 44-830 for the arm joints (the solver plans with half of
each). In the velocity-level HQP every joint is a variable of the wrist level, so the waist is pushed to its
acceleration bound on 92-100 % of the ticks of a gesture clip: a demand it can only follow tens of
milliseconds late, so it swings its whole range end to end (0.5 rad of yaw on a clip where the operator's
pelvis barely moves), both shoulders swing with it, the wrist level is infeasible on every tick and takes all
the freedom the elbows would need (wave-right-hand elbow 0.44 -> 16.7 cm).

What this does instead: a joint whose acceleration limit is below ``threshold`` [rad/s^2] is not
a free variable of the task levels. Its velocity for the tick is fixed first (the box collapses to
one value): a pull towards the rest pose, ``gain`` [1/s] times the distance, no faster than it can
still brake to a stop at rest (``sqrt(2 a d)``) and changing by at most ``a dt`` a step, with a
quarter of its planning acceleration (the arms must follow it at the wrists), clipped into its own box (acceleration,
position braking, velocity, measured-state window), so every limit still holds. The arm joints then
meet the wrists (level 1) and elbows (level 2) with the waist's motion in their Jacobians: the arms
compensate for it, strictly, and the waist never fights them. The retargeter maps the wrist targets
into the arms' workspace with the waist at rest (``services/retarget``), so the targets do not need
it. With the shipped profile (one 1000 rad/s^2 cap on every joint) no joint is slow and nothing
changes.
"""

from __future__ import annotations

import numpy as np

#: Share of a slow joint's acceleration limit its pull uses (speeding up and braking): the arms must
#: compensate its motion at the wrists, and a waist yaw at its full 19.5 rad/s^2 (planning) moves a
#: wrist 0.3 m away at ~6 m/s^2, about what the shoulders can follow.
ACCEL_SHARE = 0.25


class SlowJoints:
    """Joints with ``amax < threshold``, their velocity fixed each tick before the levels are solved.

    Args:
        amax: (n,) the robot's acceleration limits [rad/s^2] (``RobotModel.amax``).
        rest: (n,) rest pose [rad].
        threshold: acceleration limit [rad/s^2] below which a joint is slow; 0 turns this off.
        gain: pull towards rest [1/s].
    """

    def __init__(self, amax: np.ndarray, rest: np.ndarray, threshold: float, gain: float):
        if not threshold >= 0.0:
            raise ValueError(f"slow joint threshold must be >= 0 [rad/s^2], got {threshold}")
        if not gain > 0.0:
            raise ValueError(f"slow joint gain must be > 0 [1/s], got {gain}")
        #: (k,) solver indices of the slow joints (empty: none)
        self.idx = np.flatnonzero(np.asarray(amax) < threshold)
        self.rest = np.asarray(rest, dtype=float)[self.idx]
        self.gain = float(gain)

    def fix(
        self, q: np.ndarray, qd: np.ndarray, lb: np.ndarray, ub: np.ndarray, amax_plan: np.ndarray, dt: float
    ) -> None:
        """Collapse [lb, ub] (n,) [rad/s] of the slow joints, in place, onto their pull to rest.

        Args:
            q, qd: (n,) joints [rad] and their velocity [rad/s] at the start of the step.
            amax_plan: (n,) the acceleration the solver plans with [rad/s^2]; the pull uses ``ACCEL_SHARE`` of it.
            dt: the step [s].

        The pull asks for ``gain d`` towards rest, no faster than it can brake to rest (``sqrt(2 a d)``), and
        changes by at most ``a dt`` a step; it is then clipped into the box, so the box's limits (position,
        velocity, acceleration) still hold.
        """
        j = self.idx
        if not j.size:
            return
        e = self.rest - q[j]
        d = np.abs(e)
        a = ACCEL_SHARE * amax_plan[j]
        v = np.sign(e) * np.minimum(self.gain * d, np.sqrt(2.0 * a * d))
        v = np.minimum(np.maximum(v, qd[j] - a * dt), qd[j] + a * dt)
        v = np.minimum(np.maximum(v, lb[j]), ub[j])
        lb[j] = v
        ub[j] = v
