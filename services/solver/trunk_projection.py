"""Wrist targets projected onto the surface of the trunk where the waist holds it now
(``SolverConfig.trunk_projection``; issue 12 item 4).

Where the operator's hands rest on the belly, the wrist target can put the robot's hand inside its
(thicker) trunk. The self-collision dampers keep the hand out, and a strict HQP then meets its wrist level
by turning the waist: the waist carries the torso and both arms rigidly, so it changes no arm-torso
distance, but it carries the torso away from a target fixed in the pelvis frame (call_normal_001: waist yaw
-40 deg, pitch +17 deg, the left elbow 14 cm off). Each tick, before the wrist tasks see it, a target that
would put the hand inside the trunk links the waist carries (torso, logo, head; not the pelvis, which no
joint moves) *where they are at the solver's current waist joints* is moved onto their surface plus the
clearance, so level 1 is met without turning the torso.

The distance and the exit ray are the retargeter's (:class:`services.retarget.trunk.TrunkClearance`, on
the solver's own link proxies): its trunk sits at the waist's rest pose, so the target is mapped into that
pose by the carrier link's motion since the rest, projected there, and mapped back,

    T = T_c(q_rest) T_c(q)^-1,   p' = T^-1 project(T p, R_T R),

with ``T_c`` the carrier's pose (the waist's last link, base frame). The published target's velocity keeps
its component along the surface only (``v - min(0, v.u) u`` with ``u`` the exit direction): its inward part
would feed the wrist task a velocity into the body.
"""

from __future__ import annotations

import numpy as np

from services.retarget.trunk import TrunkClearance
from services.solver.collision import SelfCollisionAvoidance
from services.solver.targets import TargetSample
from shared.robot.pinocchio_model import RobotModel
from shared.targets import SIDES


class TrunkProjection:
    """Moves wrist target samples (base frame) onto the surface of the waist-carried trunk at its current pose.

    Args:
        robot: the solver's model (with or without the waist: without, the trunk stays at its rest pose).
        sca: the solver's self-collision model, whose link proxies are shared (default: one is built).

    Raises:
        ValueError: the profile has no ``[collision]`` table or no waist (``TrunkClearance``).
    """

    def __init__(self, robot: RobotModel, sca: SelfCollisionAvoidance | None = None):
        frames = {s: robot.profile.frames[f"{s}_wrist"] for s in SIDES}
        self.trunk = TrunkClearance(robot, frames, waist_carried=True, sca=sca)
        #: the frame that carries the trunk (the waist's last link)
        self.carrier: str = self.trunk.carrier
        p0, R0 = robot.frame_poses(robot.q_rest, names=(self.carrier,))[self.carrier]
        self._rest = (p0.copy(), R0.copy())
        #: the current-to-rest map of the last :meth:`set_carrier`: rotation (3, 3), translation (3,) [m]
        self._A = np.eye(3)
        self._b = np.zeros(3)
        #: side -> [m] how far its last :meth:`sample` moved the target (absent: not moved)
        self.moved: dict[str, float] = {}

    @property
    def clearance(self) -> float:
        """[m] the hand's distance from the trunk on a projected target (safety distance plus a pad)."""
        return self.trunk.clearance

    def set_carrier(self, p: np.ndarray, R: np.ndarray) -> None:
        """The carrier's current pose p (3,) [m], R (3, 3) (base frame); clears :attr:`moved`."""
        p0, R0 = self._rest
        self._A = R0 @ R.T
        self._b = p0 - self._A @ p
        self.moved.clear()

    def project(self, side: str, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """The wrist target p (3,) [m] with the hand at orientation R (3, 3) kept off the trunk at the carrier's
        current pose (base frame); ``p`` itself (the same object) when it already is."""
        A = self._A
        p_rest = A @ p + self._b
        out = self.trunk(side, p_rest, A @ R)
        if out is p_rest:
            return p
        return A.T @ (out - self._b)

    def sample(self, side: str, s: TargetSample, R: np.ndarray) -> TargetSample:
        """``s`` projected (:meth:`project`, hand orientation R (3, 3)), its velocity kept along the surface; ``s``
        itself when its target is clear of the trunk."""
        p = self.project(side, s.p, R)
        if p is s.p:
            return s
        step = p - s.p
        depth = float(np.linalg.norm(step))
        self.moved[side] = depth
        u = step / depth if depth > 0.0 else step
        inward = float(s.v @ u)
        v = s.v - inward * u if inward < 0.0 else s.v
        return TargetSample(p, s.R, v, s.w, s.use_rotation, s.held)
