"""Joint-range centring: keep the waist and shoulders out of their stops on the elbow level.

Why the strict hierarchy locks up (issue 12, the wave-left-hand masculine clip at 7 s): with the
wrists on level 1 and the elbows and wrist orientations on level 2, level 2 uses all the freedom
the wrists leave, so the rest posture on level 3 has none left and never acts. Whatever the arm
does in its redundant directions (the swivel, the waist that moves both shoulders) then drifts
unchecked: on that clip the HQP's left shoulder roll and yaw and the waist pitch wander into
their stops seconds before the lock-up (the weighted QP, whose posture term always acts, keeps
them mid-range on the same targets). When the arm then comes down fast, the only directions that
keep the wrist without going further into those stops are the waist (swung end to end) and the
elbow (folded to its own stop): a local minimum of the position problem under the joint box, the
elbow 30 cm off for 0.6 s while the elbow target was reachable from another posture all along.

The fix at the cause: a row per waist and shoulder joint on level 2, beside the elbows, whose
weight is zero in the middle of the joint's range and grows quadratically over the last ``band``
of it towards each stop (``cost * (1 - d / band)^2``, d the distance to the nearer stop as a
fraction of the range), asking the joint back out of the band (its error is its depth in the
band: the demand stays bounded and a joint is never pulled past the band's edge). In mid-range it
costs nothing (the gestures' figures do not move); near a stop it trades some elbow accuracy for
staying out of the trap (targets placing a shoulder joint right at its stop are met 2-4 cm off on
the elbow, the wrist exactly). Level 1 is untouched: these are level-2 rows. The elbow and wrist
joints are not centred: their stops are poses the targets ask for (a straight arm puts the G1
elbow at its stop on a quarter of byebye_normal's ticks; centring every joint cost 0.14 cm of
elbow mean there).
"""

from __future__ import annotations

import numpy as np

from shared.kinematics import Configuration, Task
from shared.robot.pinocchio_model import RobotModel
from shared.targets import SIDES


def centred_joints(robot: RobotModel) -> np.ndarray:
    """(k,) solver indices of the joints whose range is centred: the waist and each arm's shoulder."""
    names = [*robot.profile.waist, *(j for s in SIDES for j in robot.profile.arms[s].shoulder)]
    return np.array(robot.indices(names), dtype=int)  # a model without the waist skips it


class RangeCentringTask(Task):
    """Rows ``q̇[j] = gain (edge[j] - q[j])`` for the centred joints j inside the band, weighted by their nearness
    to a stop (edge: the band's inner edge on that side; outside the band the row is zero).

    Args:
        robot: the solver's model (limits [rad], rest pose).
        cost: row weight [1/rad] at a stop (0 turns the task off).
        band: fraction (0, 0.5] of each joint's range, from each stop, where the weight is not zero.
        gain: pull gain [1/s].
        compiled: weights and rows in the numba kernel (``tick_kernel``, compiled when built: the solver's); False
            (default, no numba loaded) the numpy steps, the reference the kernel is tested against (same bits).
    """

    def __init__(self, robot: RobotModel, cost: float, band: float, gain: float, compiled: bool = False):
        if not 0.0 < band <= 0.5:
            raise ValueError(f"range centring band must be in (0, 0.5] of the range, got {band}")
        if not cost >= 0.0:
            raise ValueError(f"range centring cost must be >= 0, got {cost}")
        self.joints = centred_joints(robot)
        self.dim = len(self.joints)
        super().__init__("range_centring", np.zeros(self.dim), gain)
        self.peak = float(cost)
        self.band = float(band)
        self.lower = robot.lower[self.joints].copy()
        self.upper = robot.upper[self.joints].copy()
        self.span = np.maximum(self.upper - self.lower, 1e-9)
        #: the band's inner edges [rad]: the error is the distance into the band (0 between them)
        self.inner_lower = self.lower + self.band * self.span
        self.inner_upper = self.upper - self.band * self.span
        self._J = np.zeros((self.dim, robot.nq))
        self._J[np.arange(self.dim), self.joints] = 1.0
        self._err = np.zeros(self.dim)
        self._kernel = None
        if compiled:
            from services.solver import tick_kernel

            tick_kernel.warm_up()
            self._kernel = tick_kernel

    def update(self, q: np.ndarray) -> None:
        """Weights (k,) from the joints q (n,) [rad]: 0 beyond ``band`` from both stops, ``cost`` at a stop."""
        if self._kernel is not None:
            self._kernel.centring_weights(
                q, self.joints, self.lower, self.upper, self.span, self.band, self.peak, self.cost
            )
            return
        qj = q[self.joints]
        d = np.minimum(qj - self.lower, self.upper - qj) / self.span
        w = np.maximum(0.0, 1.0 - d / self.band)
        np.multiply(self.peak, w * w, out=self.cost)

    def compute_error(self, configuration: Configuration) -> np.ndarray:
        qj = configuration.q[self.joints]
        # np.clip's dispatch costs several times minimum(maximum()) on a few joints; the same values.
        np.subtract(np.minimum(np.maximum(qj, self.inner_lower), self.inner_upper), qj, out=self._err)
        return self._err

    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        return self._J

    def fill_qp_objective(self, configuration: Configuration, A: np.ndarray, b: np.ndarray) -> None:
        if self._kernel is None:
            super().fill_qp_objective(configuration, A, b)
            return
        self._kernel.centring_rows(
            configuration.q, self.joints, self.inner_lower, self.inner_upper, self.gain, self.feedforward(), self.cost,
            self._J, self._err, A, b,
        )  # fmt: skip
