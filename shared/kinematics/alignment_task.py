"""Upper-arm alignment (seed 004 eqs. 3-6) and a joint-velocity task.

Seed 004 aligns the robot link that plays the operator's upper arm with the operator's
upper arm. With the operator's orientation ``R_m`` and the link's ``R_s`` (both (3, 3) in
the robot base frame), eq. (6) gives the differential rotation

    S(δ) = R_m R_sᵀ - I,        δ = (δx, δy, δz) from the skew part of S (eq. 5),

eq. (4) the objective ``H(q) = δx² + δy² + δz²`` and eq. (3) the null-space velocity
``q̇₀ = -η ∇H(q)``. With ``M = R_m R_sᵀ`` and the link's angular Jacobian ``J_ω`` (3, n)
(base frame), ``dR_s = [J_ω q̇]× R_s`` gives ``dM = -M [ω]×`` and, from the identity
``M[ω]× + [ω]×Mᵀ = [(tr M · I - M) ω]×``, the exact derivative

    ∂δ/∂q = -½ (tr M · I - M) J_ω,        ∇H = 2 (∂δ/∂q)ᵀ δ.

Near alignment (M ≈ I) this is ``∇H ≈ -2 J_ωᵀ δ``: the link turns about δ.
"""

from __future__ import annotations

import numpy as np

from shared.kinematics.configuration import Configuration
from shared.kinematics.frame_task import _check
from shared.kinematics.task import Task


def orientation_delta(R_m: np.ndarray, R_s: np.ndarray) -> np.ndarray:
    """δ (3,) [rad, ~sin of the angle] of eqs. (5)-(6): the skew part of ``R_m R_sᵀ - I``."""
    M = R_m @ R_s.T
    return 0.5 * np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])


def delta_jacobian(R_m: np.ndarray, R_s: np.ndarray, J_w: np.ndarray) -> np.ndarray:
    """∂δ/∂q (3, n) for the link's base-frame angular Jacobian ``J_w`` (3, n)."""
    M = R_m @ R_s.T
    return -0.5 * ((np.trace(M) * np.eye(3) - M) @ J_w)


class AlignmentTask(Task):
    """Turn a link (the robot's upper arm) towards a target orientation ``R_m`` (seed 004 eqs. 3-6).

    Error (3,): δ of eq. (6) [rad]; Jacobian: ``-∂δ/∂q`` (3, n), so ``J q̇ = -dδ/dt`` as for every
    task. :meth:`gradient` is the paper's ``∇H(q)`` (n,), restricted to ``joints``.

    Args:
        frame: robot frame of the link (``left_shoulder_yaw_link`` on the G1).
        joints: indices of the joints allowed to act (the arm's); None = all.
        cost: row weight [1/rad]. gain: proportional gain [1/s] (HQP use).
    """

    dim = 3

    def __init__(self, frame: str, joints: np.ndarray | None = None, cost: float = 1.0, gain: float = 1.0):
        super().__init__(f"align:{frame}", np.full(3, cost), gain)
        self.frame = frame
        self.joints = None if joints is None else np.asarray(joints, dtype=int)
        self.R_target = np.eye(3)
        self.active = False

    def set_target(self, R: np.ndarray, check: bool = True) -> None:
        """Operator upper-arm orientation (3, 3) in the robot base frame."""
        self.R_target[:] = _check(R, (3, 3), f"{self.name} rotation") if check else R
        self.active = True

    def clear(self) -> None:
        """No operator upper arm: the task asks for nothing (zero gradient, zero rows)."""
        self.active = False

    def _parts(self, configuration: Configuration) -> tuple[np.ndarray, np.ndarray]:
        _p, R_s = configuration.get_frame_pose(self.frame)
        J_w = configuration.get_frame_jacobian(self.frame)[3:]
        if self.joints is not None:
            mask = np.zeros(J_w.shape[1])
            mask[self.joints] = 1.0
            J_w = J_w * mask
        return orientation_delta(self.R_target, R_s), delta_jacobian(self.R_target, R_s, J_w)

    def compute_error(self, configuration: Configuration) -> np.ndarray:
        if not self.active:
            return np.zeros(3)
        return self._parts(configuration)[0]

    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        if not self.active:
            return np.zeros((3, configuration.nv))
        return -self._parts(configuration)[1]

    def objective(self, configuration: Configuration) -> float:
        """H(q) of eq. (4) [rad²]."""
        d = self.compute_error(configuration)
        return float(d @ d)

    def gradient(self, configuration: Configuration) -> np.ndarray:
        """∇H(q) (n,) of eq. (3) (zero on joints outside ``joints``, and when inactive)."""
        if not self.active:
            return np.zeros(configuration.nv)
        delta, D = self._parts(configuration)
        return 2.0 * (D.T @ delta)


class JointVelocityTask(Task):
    """Ask chosen joints for given velocities: ``q̇[joints] = v`` (a null-space velocity ``q̇₀`` as a task).

    In a strict hierarchy, below a level with Jacobian J, ``min ||q̇ - q̇₀||`` over that level's
    solutions is ``J⁺ b + (I - J⁺J) q̇₀``: seed 004's eq. (2) null-space term, with the limits kept hard.

    Args:
        joints: (k,) joint indices. n: number of joints. cost: row weight.
    """

    def __init__(self, joints: np.ndarray, n: int, cost: float = 1.0):
        self.joints = np.asarray(joints, dtype=int)
        self.dim = len(self.joints)
        super().__init__("joint_velocity", np.full(self.dim, cost), 0.0)
        self._J = np.zeros((self.dim, n))
        self._J[np.arange(self.dim), self.joints] = 1.0
        self._zero = np.zeros(self.dim)

    def set_velocity(self, v: np.ndarray) -> None:
        """Desired velocities (k,) [rad/s] of the joints."""
        self._ff[:] = v

    def compute_error(self, configuration: Configuration) -> np.ndarray:
        return self._zero

    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        return self._J
