"""State, action and operator-arm layouts of the posture policy (seed 004 section 3.1).

Per arm (the policy is applied to each arm with that arm's own network):

- state ``s = (Q, p, q)`` (14,): the tracked hand pose, quaternion ``Q`` (4,) wxyz and position
  ``p`` (3,) [m] in the robot base frame (the wrist target), and the arm's 7 joint angles ``q`` [rad]
  in profile order. ``Q`` is sign-fixed against the robot's rest wrist orientation (``Q·Q_rest >= 0``),
  which puts the quaternion's double-cover seam 180° away from where hands go.
- action ``q̇₀`` (3,) [rad/s] on the joints that move the upper-arm link: the shoulder pitch, roll and
  yaw. Seed 004's xMate3 has 4 (its link 4 follows joints 1-4); on the G1 the upper-arm link follows
  the three shoulder joints, and the mimicry gradient ``-η ∇H`` is zero on every other arm joint.
  Two action kinds (:data:`ACTION_KINDS`): ``"velocity"`` is the paper's ``q̇₀`` itself; ``"posture"``
  is the operator's shoulder posture ``q*`` (3,) [rad] (the shoulder angles that put the robot's upper
  arm along the operator's), turned into ``q̇₀ = K (q* - q_shoulder)`` (:func:`posture_action`). A
  posture depends on the hand pose alone, so its encoder reads ``(Q, p)`` only (:data:`HAND_INPUTS`).
- decoder input ``(q̇₀, q, x_d)`` (17,): action, joints, and the target pose ``x_d = (Q, p)``.
- operator arm state (6,): unit directions of the operator's upper arm ``u`` and forearm ``f`` on the
  robot's proportions (robot base frame). The virtual target (the master's forward kinematics) is
  ``x_dv = c + L_u u + L_f f`` with the robot's shoulder centre c and segment lengths.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from shared.mirror import mirror_points, mirror_quats
from shared.robot.pinocchio_model import RobotModel

STATE_DIM = 14
ACTION_DIM = 3
ARM_STATE_DIM = 6
#: Largest |q̇₀| per joint [rad/s], for the expert's labels and the policy's actions alike: seed 004
#: leaves "occasional wrong outputs" of the network to future filtering; a bound keeps any output a
#: gentle pull (the G1 profile caps the arm joints at 8 rad/s), and the expert's saturated labels teach the same.
ACTION_LIMIT = 2.0
#: State entries by name (for the model file's metadata).
STATE_LAYOUT = ("Qw", "Qx", "Qy", "Qz", "px", "py", "pz", *(f"q{i}" for i in range(7)))
ACTION_LAYOUT = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw")
ARM_STATE_LAYOUT = ("ux", "uy", "uz", "fx", "fy", "fz")
#: What the encoder outputs: the null-space velocity q̇₀ [rad/s], the shoulder posture q* [rad], or the
#: operator's elbow e* (3,) [m] (robot base frame, on the robot's proportions: the retargeted elbow the
#: full-mocap solver tracks), which the solver tracks on the elbow level (the wrist fixes the elbow up to
#: its swivel, so a 3-D point is all a hand-only predictor needs to give).
#: ``"swivel"``: the operator's elbow as its angle (cos φ, sin φ) (2,) on the circle of elbows that reach the
#: wrist target (:mod:`.swivel`), placed on that circle for the elbow level.
ACTION_KINDS = ("velocity", "posture", "elbow", "swivel")
#: Kinds whose output is an elbow target for the arm's elbow task (the policy gives it as ``elbow``).
ELBOW_KINDS = ("elbow", "swivel")
#: Action entries by name, per kind (for the model file's metadata).
ACTION_LAYOUTS = {
    "velocity": ACTION_LAYOUT,
    "posture": ACTION_LAYOUT,
    "elbow": ("elbow_x", "elbow_y", "elbow_z"),
    "swivel": ("swivel_cos", "swivel_sin"),
}


def action_dim(kind: str) -> int:
    """Length of the encoder's output for an action kind (3, or 2 for the swivel angle)."""
    return len(ACTION_LAYOUTS[kind])


def decoder_dim(kind: str) -> int:
    """Length of the decoder's input ``(a, q, x_d)`` for an action kind."""
    return action_dim(kind) + 7 + 7


#: State entries a posture encoder reads: the hand pose (Q, p); the joints are masked out.
HAND_INPUTS = 7
#: Posture kind: gain K [1/s] of ``q̇₀ = K (q* - q)`` (the solver's elbow-task order of magnitude; with
#: ACTION_LIMIT it saturates beyond 0.1 rad of shoulder error; 20 measured 0.3 cm better than 10).
POSTURE_ACTION_GAIN = 20.0


def action_joints(robot: RobotModel, side: str) -> np.ndarray:
    """Indices (3,) of the joints the action drives: the profile's shoulder joints (before the elbow)."""
    shoulder = robot.profile.arms[side].shoulder
    if len(shoulder) != ACTION_DIM:
        raise ValueError(
            f"{robot.profile.name}: {side} arm has {len(shoulder)} shoulder joints, the policy {ACTION_DIM}"
        )
    return np.array([robot.joint_names.index(n) for n in shoulder])


@dataclass(frozen=True)
class ArmFrame:
    """Robot constants of one arm for the operator arm state: shoulder centre (3,) [m], lengths [m]."""

    centre: np.ndarray
    upper: float
    fore: float

    def to_dict(self) -> dict:
        d = asdict(self)
        d["centre"] = [float(x) for x in self.centre]
        return d


def posture_action(target: np.ndarray, q_shoulder: np.ndarray, gain: float) -> np.ndarray:
    """q̇₀ (…, 3) [rad/s] pulling the shoulder joints q_shoulder (…, 3) to target (…, 3) [rad], bounded."""
    return np.clip(gain * (target - q_shoulder), -ACTION_LIMIT, ACTION_LIMIT)


def elbow_action(J: np.ndarray, target: np.ndarray, elbow: np.ndarray, gain: float) -> np.ndarray:
    """q̇₀ (3,) [rad/s] on the shoulder joints moving the elbow (3,) [m] toward target (3,) [m], bounded.

    The elbow kind in the arms-only rollouts (the solver tracks the target with its own elbow task):
    a damped least-squares step through the elbow Jacobian J (3, 3) of the shoulder joints.
    """
    v = gain * (target - elbow)
    dq = J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(3), v)
    return np.clip(dq, -ACTION_LIMIT, ACTION_LIMIT)


def mirror_action(A: np.ndarray, sign: np.ndarray, kind: str) -> np.ndarray:
    """Actions (…, 3) of one arm as the other arm's: joint signs (shoulder joints) or, for the elbow kind,
    the point reflected through the x-z plane; swivel angles (…, 2): sin φ negated (the right arm's angle
    frame is the left's mirror image, :mod:`.swivel`)."""
    if kind == "elbow":
        return A * np.array([1.0, -1.0, 1.0])
    if kind == "swivel":
        return A * np.array([1.0, -1.0])
    return A * sign[:ACTION_DIM]


def canonical_quat(Q: np.ndarray, Q_ref: np.ndarray) -> np.ndarray:
    """Quaternion(s) (..., 4) with the sign that makes the dot product with Q_ref (4,) non-negative."""
    Q = np.asarray(Q, dtype=float)
    s = np.where((Q @ Q_ref) < 0.0, -1.0, 1.0)
    return Q * s[..., None]


def state(Q: np.ndarray, p: np.ndarray, q_arm: np.ndarray, Q_ref: np.ndarray) -> np.ndarray:
    """s (14,) from Q (4,), p (3,) [m], q_arm (7,) [rad]."""
    return np.concatenate([canonical_quat(Q, Q_ref), p, q_arm])


def decoder_input(action: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(…, A + 14) decoder input ``(q̇₀, q, x_d)`` from actions (…, A) and states (…, 14)."""
    return np.concatenate([action, s[..., 7:14], s[..., 0:7]], axis=-1)


def arm_state(arm: ArmFrame, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
    """Operator arm state (…, 6): upper-arm and forearm unit directions from elbow/wrist targets (…, 3)."""
    u = elbow - arm.centre
    f = wrist - elbow
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    f = f / np.linalg.norm(f, axis=-1, keepdims=True)
    return np.concatenate([u, f], axis=-1)


def virtual_target(arm: ArmFrame, z: np.ndarray) -> np.ndarray:
    """x_dv (…, 3) [m]: the master's forward kinematics of an arm state (…, 6) (directions renormalised)."""
    u = z[..., :3] / np.maximum(np.linalg.norm(z[..., :3], axis=-1, keepdims=True), 1e-9)
    f = z[..., 3:6] / np.maximum(np.linalg.norm(z[..., 3:6], axis=-1, keepdims=True), 1e-9)
    return arm.centre + arm.upper * u + arm.fore * f


def mirror_state(S: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """States (…, 14) of one arm as the other arm's: hand pose reflected through x-z, joints * sign (7,).

    The rotation ``M R M`` has quaternion ``(w, -x, y, -z)``; that keeps ``Q · Q_ref >= 0`` when the
    other arm's rest wrist is the mirror image of this one's.
    """
    out = np.array(S, dtype=float, copy=True)
    out[..., 0:4] = mirror_quats(out[..., 0:4])
    out[..., 4:7] = mirror_points(out[..., 4:7])
    out[..., 7:14] *= sign
    return out


def mirror_arm_state(Z: np.ndarray) -> np.ndarray:
    """Operator arm states (…, 6) reflected through the x-z plane (both directions' y negated)."""
    return np.concatenate([mirror_points(Z[..., 0:3]), mirror_points(Z[..., 3:6])], axis=-1)
