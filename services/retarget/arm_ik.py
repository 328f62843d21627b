"""Position-level IK of one robot arm: weighted damped Gauss-Newton least squares, warm-started.

One idea, used three times by the retargeter: :func:`.orientation.calibration_posture` and
:class:`.upper_arm.UpperArmSolver` (shoulder and elbow joints, wrist joints at zero; elbow and wrist
positions) and :class:`.consistent.ConsistentArm` (all seven joints; wrist position, elbow position
and wrist orientation). Each call runs a few iterations from the previous call's solution, so a
slowly moving target costs one or two. (The evaluation's reachability check,
``services/evaluation/reachability.py``, keeps its own IK on purpose: it checks this one.)

The arm is evaluated on its own Pinocchio model (the other joints locked where the caller put them,
the waist at rest), so forward kinematics and Jacobians cover its joints only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from shared.robot.pinocchio_model import RobotModel

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class ArmIk:
    """IK over some joints of one arm of a reduced robot model.

    Args:
        robot: reduced robot model (arms; its waist, if any, at rest).
        joints: names of the joints moved (the others are locked at ``q_fixed``).
        q_fixed: (robot.nq,) configuration [rad] of the locked joints (and the rest start of the moved ones).
        margin: kept inside each position limit of the moved joints [rad], on top of the profile's.
        damping: Levenberg damping of the normal equations [m^2].
    """

    def __init__(
        self,
        robot: RobotModel,
        joints: Sequence[str],
        q_fixed: np.ndarray,
        margin: float = 0.0,
        damping: float = 1e-4,
    ):
        idx = robot.indices(joints)
        if len(idx) != len(joints):
            raise KeyError(f"joints {sorted(set(joints) - {robot.joint_names[i] for i in idx})} not in the model")
        self.robot = robot
        self.idx = np.array(idx)
        locked = [robot.model.getJointId(n) for i, n in enumerate(robot.joint_names) if i not in set(idx)]
        self.model = pin.buildReducedModel(robot.model, locked, np.asarray(q_fixed, dtype=float))
        self.data = self.model.createData()
        # the reduced model keeps the moved joints in the robot model's order
        m = np.minimum(margin, 0.5 * (robot.upper[self.idx] - robot.lower[self.idx]))
        self.lower, self.upper = robot.lower[self.idx] + m, robot.upper[self.idx] - m
        self.q_fixed = np.asarray(q_fixed, dtype=float).copy()
        self.q_start = np.clip(self.q_fixed[self.idx], self.lower, self.upper)
        #: the current solution (n,) [rad], the warm start of the next call
        self.q = self.q_start.copy()
        self.damping = damping
        self._eye = np.eye(len(idx))
        #: Gauss-Newton iterations run since the counter was last set to 0 (cost figures and tests)
        self.iterations = 0

    def frame(self, name: str) -> int:
        """Frame id (in this arm's model) of a robot frame or target name (``left_wrist``...)."""
        return self.model.getFrameId(self.robot.model.frames[self.robot.frame_id(name)].name)

    def rotation_frame(self, name: str) -> int:
        """Frame id (in this arm's model) of a target's orientation frame (``RobotModel.rotation_id``)."""
        return self.model.getFrameId(self.robot.model.frames[self.robot.rotation_id(name)].name)

    def reset(self) -> None:
        """Start the next solve from ``q_fixed``'s pose (a new stream, or after a gap)."""
        self.q = self.q_start.copy()

    def solve(
        self,
        positions: Sequence[tuple[int, np.ndarray, float]],
        rotation: tuple[int, np.ndarray, float] | None = None,
        iters: int = 8,
        tol: float = 1e-4,
        step_tol: float = 0.0,
        max_step: float = np.inf,
    ) -> np.ndarray:
        """Minimise ``sum w_i^2 |p_i - x_i(q)|^2 + w_r^2 |log(R R(q)^T)|^2`` within the limits, from ``self.q``.

        Args:
            positions: (frame id, target (3,) [m] base frame, weight [1/m]) per position goal.
            rotation: (frame id, target (3, 3) base frame, weight [1/rad]) or None.
            iters: iterations at most. tol: stop when the weighted residual norm is below it.
            step_tol: stop when no joint moved more than this in an iteration [rad] (a residual
                that cannot vanish: conflicting goals).

        Returns:
            The solution (n,) [rad] (also kept as ``self.q``); the data holds its frame placements.
        """
        model, data, q = self.model, self.data, self.q
        rows = 3 * len(positions) + (3 if rotation is not None else 0)
        A = np.empty((rows, len(q)))
        b = np.empty(rows)
        for _ in range(iters):
            pin.computeJointJacobians(model, data, q)  # also the joint placements
            k = 0
            for f, p, w in positions:
                b[k : k + 3] = w * (p - pin.updateFramePlacement(model, data, f).translation)
                A[k : k + 3] = w * pin.getFrameJacobian(model, data, f, _LWA)[:3]
                k += 3
            if rotation is not None:
                f, R, w = rotation
                b[k:] = w * pin.log3(R @ pin.updateFramePlacement(model, data, f).rotation.T)
                A[k:] = w * pin.getFrameJacobian(model, data, f, _LWA)[3:]
            if b @ b < tol * tol:
                break
            self.iterations += 1
            dq = np.linalg.solve(A.T @ A + self.damping * self._eye, A.T @ b)
            # Joints at a stop that the step pushes further are held and the step solved again
            # without them: clipping alone leaves the other joints' share of the step aimed at a
            # motion that does not happen, and the iteration stalls against the stop.
            at_lo, at_hi = q <= self.lower, q >= self.upper
            if at_lo.any() or at_hi.any():  # (rarely: tested first, the per-call cost of numpy dominates)
                held = (at_lo & (dq < 0)) | (at_hi & (dq > 0))
                if held.any():
                    A[:, held] = 0.0
                    dq = np.linalg.solve(A.T @ A + self.damping * self._eye, A.T @ b)
            n = float(np.sqrt(dq @ dq))
            if n > max_step:
                dq *= max_step / n
            q_new = np.clip(q + dq, self.lower, self.upper)
            moved = np.abs(q_new - q).max()
            q = q_new
            if moved < step_tol:
                break
        self.q = q
        pin.framesForwardKinematics(model, data, q)
        return q

    def pose(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        """Position (3,) [m] and rotation (3, 3) of frame ``f`` at the last solution (base frame)."""
        oMf = self.data.oMf[f]
        return oMf.translation.copy(), oMf.rotation.copy()

    def full(self) -> np.ndarray:
        """The last solution as a robot configuration (robot.nq,) [rad] (locked joints at ``q_fixed``)."""
        q = self.q_fixed.copy()
        q[self.idx] = self.q
        return q
