"""Wrist orientation targets within the wrist joints' ranges (``RetargetConfig.wrist_range``).

The forearm-relative orientation map (:class:`.orientation.ForearmOrientationMap`) turns the robot hand
relative to its forearm as the operator's hand turns relative to theirs. The operator's hand may turn
further than the robot's wrist joints go (G1: roll +-113 deg, pitch and yaw +-92 deg), and a source
without hand orientations (C3D markers: identity quaternions, the hand held fixed in the pelvis frame
while the forearm moves) asks for hand poses no wrist takes (the Vicon clip: up to 41 deg past the
ranges at p99). The solver then trades the unreachable rest against the elbow on level 2.

Here the target is expressed relative to the robot's elbow link as the published elbow and wrist
positions imply it, decomposed into the three wrist joint angles, clipped into their ranges (less the
solver's headroom) and composed again:

    R_E = F_U C,   (a, b, c) = xyz-Euler(R_E^T R),   R' = R_E Rx(clip a) Ry(clip b) Rz(clip c)

``F_U`` is the robot forearm frame of the targets (:func:`.orientation.arm_frame` of shoulder centre ->
elbow target -> wrist target) and ``C`` the elbow link's fixed offset from it, the mean over flexed arm
postures of the robot model (the G1's shoulder axes do not meet and its wrist frame sits off the
forearm axis, so the offset varies by a few degrees with the posture; that is the model's error). The
G1's wrist joints are x (roll), y (pitch), z (yaw) in series with no rotation in the joint origins, so
``R_E^T R`` is exactly ``Rx(roll) Ry(pitch) Rz(yaw)``. Clipping the angles is continuous in the target
(the Euler branch with ``|pitch| <= 90 deg`` is taken; it is within the pitch range) and leaves a target
inside the ranges unchanged. While the robot arm is straight (its plane undefined) the last forearm frame
is carried along by the smallest rotation of the forearm direction, so the frame stays continuous.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from services.retarget.orientation import align, arm_frame
from services.solver.quintic import RAW_POSITION_MARGIN
from shared.robot.pinocchio_model import RobotModel
from shared.rotations import cross3, norm3
from shared.targets import elbow_of, wrist_of

#: Postures sampled to measure the elbow link's offset from the forearm frame, and its seed.
OFFSET_SAMPLES, OFFSET_SEED = 400, 0
#: sin of the smallest elbow bend of those postures (20 deg): the arm plane is well defined.
MIN_BEND_SIN = float(np.sin(np.radians(20.0)))
#: Iterations taking the wrist joints' lever out of the forearm direction (each shrinks its error ~4x).
LEVER_ITERS = 2
#: Wrist angle [rad] from every stop beyond which a target counts as inside without the lever iterations
#: (the lever turns the implied elbow link by up to ~15 deg).
LEVER_SLACK = 0.35
#: Clipping passes of a target past the ranges (each against the elbow link implied with the last one).
PASSES = 4


def euler_xyz(M: np.ndarray) -> np.ndarray:
    """Angles (3,) [rad] with ``M = Rx(a) Ry(b) Rz(c)`` (3, 3) (intrinsic x-y-z), on the branch ``|b| <= pi/2``."""
    return Rotation.from_matrix(M).as_euler("XYZ")


def from_euler_xyz(e: np.ndarray) -> np.ndarray:
    """``Rx(a) Ry(b) Rz(c)`` (3, 3) for angles e (3,) [rad]."""
    return Rotation.from_euler("XYZ", e).as_matrix()


def forearm_offset(robot: RobotModel, side: str, centre: np.ndarray) -> np.ndarray:
    """``C`` (3, 3): the elbow link's orientation in the forearm frame of its elbow and wrist positions.

    Averaged (then made a rotation again) over postures sampled within the limits, wrist joints at zero,
    with the elbow bent by at least 20 deg (the plane well defined) the way the rest pose bends it: an
    elbow that over-stretches past straight (the G1's goes ~40 deg past) turns its plane normal over,
    and an operator's elbow does not.

    Args:
        robot: reduced robot model (arms). side: "left" or "right". centre: (3,) shoulder centre [m].
    """
    roles = robot.profile.arms[side]
    wrist_idx = robot.indices(roles.wrist)
    f_elbow, f_wrist = robot.frame_id(elbow_of(side)), robot.frame_id(wrist_of(side))

    def offset(q: np.ndarray, min_sin: float) -> np.ndarray | None:
        q = q.copy()
        q[wrist_idx] = 0.0
        data = robot.forward(q)
        E, W = data.oMf[f_elbow].translation, data.oMf[f_wrist].translation
        F = arm_frame(E - centre, W - E)
        if F is None or norm3(cross3((E - centre) / norm3(E - centre), (W - E) / norm3(W - E))) < min_sin:
            return None
        return F.T @ data.oMf[f_elbow].rotation

    C_rest = offset(robot.q_rest, 0.0)
    if C_rest is None:
        raise ValueError(f"{side} arm: straight at the rest pose; wrist_range needs its elbow bent there")
    kept = []
    for q in robot.random_configurations(OFFSET_SAMPLES, np.random.default_rng(OFFSET_SEED)):
        C = offset(q, MIN_BEND_SIN)
        if C is not None and np.trace(C_rest.T @ C) > 1.0:  # within 90 deg of the rest pose's bend
            kept.append(C)
    # the chordal mean: the rotation nearest the samples' mean matrix
    return Rotation.from_matrix(np.array(kept)).mean().as_matrix()


class WristRange:
    """Projects one arm's wrist orientation targets into its wrist joints' ranges.

    Args:
        robot: reduced robot model (arms; waist at rest). side: "left" or "right".
        centre: (3,) the arm's shoulder centre [m] (:class:`.elbow.ArmGeometry`).
        margin: kept inside the (profile-shrunk) wrist joint limits [rad]: the solver's own headroom.
    """

    def __init__(self, robot: RobotModel, side: str, centre: np.ndarray, margin: float = RAW_POSITION_MARGIN):
        roles = robot.profile.arms[side]
        idx = robot.indices(roles.wrist)
        if len(idx) != 3:
            raise ValueError(f"{side} arm: wrist_range needs 3 wrist joints (roll, pitch, yaw), got {roles.wrist}")
        self.lower, self.upper = robot.lower[idx] + margin, robot.upper[idx] - margin
        self.centre = np.asarray(centre, dtype=float)
        self.C = forearm_offset(robot, side, self.centre)
        self._F: np.ndarray | None = None  # the last forearm frame (carried while the arm is straight)
        # The wrist frame in the elbow link frame as the wrist joints turn: a model of the wrist joints
        # alone (the others locked; the elbow link is then fixed in it).
        locked = [robot.model.getJointId(n) for i, n in enumerate(robot.joint_names) if i not in set(idx)]
        self._wrist_model = pin.buildReducedModel(robot.model, locked, robot.q_rest)
        self._wrist_data = self._wrist_model.createData()
        name = robot.model.frames
        self._f_elbow = self._wrist_model.getFrameId(name[robot.frame_id(elbow_of(side))].name)
        self._f_wrist = self._wrist_model.getFrameId(name[robot.frame_id(wrist_of(side))].name)
        self._p0 = self._lever(np.zeros(3))

    def reset(self) -> None:
        """Forget the last forearm frame (a new stream)."""
        self._F = None

    def _lever(self, e: np.ndarray) -> np.ndarray:
        """Wrist frame position (3,) [m] in the elbow link frame with the wrist joints at e (3,) [rad]."""
        m, d = self._wrist_model, self._wrist_data
        pin.framesForwardKinematics(m, d, e)
        return d.oMf[self._f_elbow].actInv(d.oMf[self._f_wrist]).translation

    def _forearm(self, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray | None:
        """Forearm frame (3, 3) of elbow -> wrist (3,) [m]; while straight the last one carried along."""
        fore = wrist - elbow
        F = arm_frame(elbow - self.centre, fore)
        if F is None:
            if self._F is None:
                return None
            F = align(self._F[:, 0], fore) @ self._F  # smallest turn of the last frame onto this forearm
        return F

    def elbow_link(
        self, elbow: np.ndarray, wrist: np.ndarray, R: np.ndarray | None = None, iters: int = LEVER_ITERS
    ) -> np.ndarray | None:
        """Robot elbow link orientation (3, 3) implied by elbow and wrist targets (3,) [m]; None while the
        arm is straight with no earlier frame to carry.

        With the wrist target orientation R (3, 3), the wrist joints' lever is taken out: a wrist point
        off the wrist axes (the G1's hand link, 4.6 cm past the pitch axis, the wrist point before session
        15) moves when the hand pitches, and the forearm of the positions by up to ~15 deg; on the shipped
        G1 (wrist point on the pitch axis) the lever is zero and the iterations change nothing. Each of
        ``iters`` iterations takes the joint angles of the current estimate and moves the wrist back to where
        zero angles put it.
        """
        elbow, wrist = np.asarray(elbow, dtype=float), np.asarray(wrist, dtype=float)
        F = self._forearm(elbow, wrist)
        if F is None:
            return None
        R_E = F @ self.C
        if R is not None:
            for _ in range(iters):
                e = np.clip(euler_xyz(R_E.T @ R), self.lower, self.upper)
                F1 = self._forearm(elbow, wrist - R_E @ (self._lever(e) - self._p0))
                if F1 is None:
                    break
                F, R_E = F1, F1 @ self.C
        self._F = F
        return R_E

    def joint_angles(self, R: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray | None:
        """Wrist roll, pitch, yaw (3,) [rad] that turn the implied elbow link onto R (3, 3) (None: unknown)."""
        R_E = self.elbow_link(elbow, wrist, R)
        return None if R_E is None else euler_xyz(R_E.T @ R)

    def __call__(self, R: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """Wrist target orientation R (3, 3) within the wrist ranges, for elbow and wrist targets (3,) [m].

        Returns R itself when it is within the ranges. Otherwise the clipped target, clipped again against
        the elbow link implied with it (its lever moves the implied link by up to a degree), up to
        :data:`PASSES` times, so it passes its own check (:meth:`joint_angles`) to under 0.1 deg.
        """
        R_E = self.elbow_link(elbow, wrist)  # without the lever: enough to tell a target well inside
        if R_E is None:
            return R
        e = euler_xyz(R_E.T @ R)
        if np.all(e > self.lower + LEVER_SLACK) and np.all(e < self.upper - LEVER_SLACK):
            return R
        out = R
        for _ in range(PASSES):
            R_E = self.elbow_link(elbow, wrist, out)
            if R_E is None:
                return out
            e = euler_xyz(R_E.T @ out)
            clipped = np.clip(e, self.lower, self.upper)
            if np.array_equal(clipped, e):
                return out  # within the ranges (the first time: unchanged, bit for bit)
            out = R_E @ from_euler_xyz(clipped)
        return out
