"""The operator's upper arm as an orientation of the robot's upper-arm link (seed 004 eq. 6's ``R_m``).

Seed 004 aligns the robot link that plays the upper arm with the operator's upper arm, read off an
exoskeleton in a frame shared with the robot. Here the operator's arm is first put on the robot's
proportions (the swivel elbow target and the wrist target, :mod:`.elbow`): the robot posture that
puts its elbow and wrist frames there (wrist joints at zero) then gives the link orientation ``R_m``.
A frame built from the operator's bones directly would not do: the G1's shoulder axes do not meet,
its elbow axis is not normal to the shoulder-elbow-wrist plane, and the plane's normal flips once the
elbow folds past about 90 degrees, so such a frame is 10 degrees off the link, or upside down
(measured over random postures).

The posture is the arm IK of :mod:`.arm_ik` over the shoulder and elbow joints, warm-started from
the previous frame's (a few iterations per frame).
"""

from __future__ import annotations

import numpy as np

from services.retarget.arm_ik import ArmIk
from shared.robot.pinocchio_model import RobotModel


class UpperArmSolver:
    """``R_m`` (3, 3) of one arm's upper-arm link for an elbow and a wrist target (robot base frame).

    Args:
        robot: reduced robot model (arms, waist at rest). side: "left" or "right".
        link: robot frame of the upper-arm link. iters: Gauss-Newton iterations per call at most.
        tol: stop when the position error is below this [m].
    """

    def __init__(self, robot: RobotModel, side: str, link: str, iters: int = 8, tol: float = 1e-4):
        roles = robot.profile.arms[side]
        q0 = robot.q_rest.copy()
        q0[robot.indices(roles.wrist)] = 0.0
        self.ik = ArmIk(robot, (*roles.shoulder, roles.elbow), q0)
        #: the rest posture with the wrist joints at zero (robot.nq,) [rad], and the moved joints' indices in it
        self.q0 = q0
        self.joints = list(self.ik.idx)
        self.f_elbow = self.ik.frame(f"{side}_elbow")
        self.f_wrist = self.ik.frame(f"{side}_wrist")
        self.f_link = self.ik.frame(link)
        self.iters = iters
        self.tol = tol

    @property
    def q(self) -> np.ndarray:
        """The last posture as a robot configuration (robot.nq,) [rad] (wrist joints at zero)."""
        return self.ik.full()

    def reset(self) -> None:
        """Start the next solve from the rest posture (a new stream)."""
        self.ik.reset()

    def __call__(self, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """Link orientation (3, 3) of the posture reaching ``elbow`` and ``wrist`` (3,) [m] (least squares)."""
        self.ik.solve([(self.f_elbow, elbow, 1.0), (self.f_wrist, wrist, 1.0)], iters=self.iters, tol=self.tol)
        return self.ik.pose(self.f_link)[1]
