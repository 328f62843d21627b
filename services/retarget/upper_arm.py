"""The operator's upper arm as an orientation of the robot's upper-arm link (seed 004 eq. 6's ``R_m``).

Seed 004 aligns the robot link that plays the upper arm with the operator's upper arm, read off an
exoskeleton in a frame shared with the robot. Here the operator's arm is first put on the robot's
proportions (the swivel elbow target and the wrist target, :mod:`.elbow`): the robot posture that
puts its elbow and wrist frames there (wrist joints at zero) then gives the link orientation ``R_m``.
A frame built from the operator's bones directly would not do: the G1's shoulder axes do not meet,
its elbow axis is not normal to the shoulder-elbow-wrist plane, and the plane's normal flips once the
elbow folds past about 90 degrees, so such a frame is 10 degrees off the link, or upside down
(measured over random postures).

The posture is a damped Gauss-Newton least squares over the shoulder and elbow joints, warm-started
from the previous frame's (a few iterations per frame, about 0.1 ms).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from shared.robot.pinocchio_model import RobotModel

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class UpperArmSolver:
    """``R_m`` (3, 3) of one arm's upper-arm link for an elbow and a wrist target (robot base frame).

    Args:
        robot: reduced robot model (arms, waist at rest). side: "left" or "right".
        link: robot frame of the upper-arm link. iters: Gauss-Newton iterations per call at most.
        tol: stop when the position error is below this [m].
    """

    def __init__(self, robot: RobotModel, side: str, link: str, iters: int = 8, tol: float = 1e-4):
        self.robot = robot
        self.data = robot.model.createData()
        names = list(robot.joint_names)
        self.joints = [i for i, n in enumerate(names) if n.startswith(f"{side}_shoulder") or n == f"{side}_elbow_joint"]
        self.q0 = robot.q_rest.copy()
        for i, n in enumerate(names):
            if n.startswith(f"{side}_wrist"):
                self.q0[i] = 0.0
        self.q = self.q0.copy()
        self.f_elbow = robot.frame_id(f"{side}_elbow")
        self.f_wrist = robot.frame_id(f"{side}_wrist")
        self.f_link = robot.frame_id(link)
        self.iters = iters
        self.tol = tol

    def reset(self) -> None:
        """Start the next solve from the rest posture (a new stream)."""
        self.q = self.q0.copy()

    def __call__(self, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """Link orientation (3, 3) of the posture reaching ``elbow`` and ``wrist`` (3,) [m] (least squares)."""
        model, data, q, J = self.robot.model, self.data, self.q, self.joints
        lo, hi = self.robot.lower[J], self.robot.upper[J]
        for _ in range(self.iters):
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            e = np.r_[elbow - data.oMf[self.f_elbow].translation, wrist - data.oMf[self.f_wrist].translation]
            if e @ e < self.tol**2:
                break
            A = np.vstack(
                [
                    pin.getFrameJacobian(model, data, self.f_elbow, _LWA)[:3, J],
                    pin.getFrameJacobian(model, data, self.f_wrist, _LWA)[:3, J],
                ]
            )
            q[J] = np.clip(q[J] + np.linalg.solve(A.T @ A + 1e-4 * np.eye(len(J)), A.T @ e), lo, hi)
        pin.framesForwardKinematics(model, data, q)
        return data.oMf[self.f_link].rotation.copy()
