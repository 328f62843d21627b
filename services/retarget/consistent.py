"""Wrist and elbow targets one arm posture meets together (``RetargetConfig.consistent_targets``).

The retargeter maps the wrist position, the wrist orientation (eq. 4, forearm-relative) and the swivel
elbow each on its own. The G1 arm has seven joints, and with the wrist point on the hand link (4.6 cm past
the wrist pitch axis; the profile before session 15) about one joint was left for the three orientation
components once the wrist and elbow positions were fixed, so the mapped triple was often not reachable
together (on a slow gesture, ``guide_normal``, a third of the wrist + elbow pairs alone failed an IK check).
The shipped profile puts the wrist point on the pitch axis, which leaves the three wrist joints to the
orientation, within their ranges. Any solver then
spreads the disagreement over what it tracks: a strict hierarchy onto the elbow and the orientation, a
weighted one onto the wrist.

Here, per frame and arm, the position-level IK of :mod:`.arm_ik` over the arm's seven joints (waist at
rest, within the joint ranges minus the solver's own headroom) finds the posture that meets the wrist
position and comes closest to the mapped elbow and wrist orientation; the retargeter then publishes
that posture's elbow position and wrist orientation, and the mapped wrist position. Warm-started from
the previous frame's posture, so the targets stay continuous; restarted from the rest pose with a new
stream or after a gap.

Weights (of the least squares, see :data:`WRIST_WEIGHT`): the wrist position is the hard goal, and
the elbow [m] and the wrist orientation [rad] trade at :data:`ORIENTATION_WEIGHT` metres per radian.

An option, not the default: with the waist at rest here, the published elbows sit further from the
operator's than the solver gets with the plain targets, which it reaches with the waist (measured with
``mimic eval --consistent-targets``' ``*_vs_operator`` errors; figures in the retarget README).
"""

from __future__ import annotations

import numpy as np

from services.retarget.arm_ik import ArmIk
from services.solver.quintic import RAW_POSITION_MARGIN
from shared.robot.pinocchio_model import RobotModel
from shared.targets import elbow_of, wrist_of

#: Weight of the wrist position [1/m] against the elbow's 1 [1/m]: a conflict of c metres leaves about
#: c / WRIST_WEIGHT^2 on the wrist (5 cm -> 5 um), so the published (mapped) wrist stays met.
WRIST_WEIGHT = 100.0
#: Weight of the wrist orientation [m/rad] against the elbow's 1 [1/m]: the solver's level-2 row cost of
#: the time (``SolverConfig.wrist_orientation_cost`` 0.3 [1/rad] at orientation gain 30 beside the elbows'
#: 1 at 200; 0.045 at 200 since session 18); one degree of hand costs 5 mm of elbow.
#: On the 25 clips (``mimic eval``) 0.1 instead moved the elbows less (0.94 against 1.17 cm mean) and
#: the hands more (1.8 against 1.1 deg mean); the HQP then tracked the elbows a little better (1.47
#: against 1.52 cm mean) and the hands worse (wrist rotation p99 on wave-left-hand_normal 20 against
#: 10 deg, wave-left-hand_masculine 39 against 22).
ORIENTATION_WEIGHT = 0.3
#: Iterations per frame from the previous frame's posture, and from rest (first frame, after a gap).
ITERS, FIRST_ITERS = 2, 40
#: Wrist distance [m] under which the wrist counts as met; while it is not, up to CATCH_UP more
#: iterations run (a fast target), then a recovery (the warm start sat in a local minimum against a
#: joint stop, as on wave-left-hand_masculine).
WRIST_TOL, CATCH_UP = 1e-3, 10
#: Recovery starts besides the warm posture and the rest pose; frames after a recovery that found
#: nothing better than the warm posture (a target out of reach within the margins) before the next one may run
#: (a recovery costs up to (SEEDS + 2) * (FIRST_ITERS + CATCH_UP) iterations).
SEEDS, RETRY_AFTER = 4, 10
#: An iteration moving no joint more than this [rad] ends the frame's solve (converged).
STEP_TOL = 1e-4
#: Largest step of an iteration [rad] (norm over the arm's joints).
MAX_STEP = 0.2


class ConsistentArm:
    """The arm posture closest to one frame's mapped wrist and elbow targets, and its targets.

    Args:
        robot: reduced robot model (arms; waist at rest). side: "left" or "right".
        orientation_weight: :data:`ORIENTATION_WEIGHT`.
        iters: :data:`ITERS`.
    """

    def __init__(
        self, robot: RobotModel, side: str, orientation_weight: float = ORIENTATION_WEIGHT, iters: int = ITERS
    ):
        roles = robot.profile.arms[side]
        # The solver keeps its raw solution RAW_POSITION_MARGIN inside the (profile-shrunk) limits:
        # a posture the targets need must be one it can take.
        self.ik = ArmIk(robot, roles.joints, robot.q_rest, margin=RAW_POSITION_MARGIN)
        self.f_wrist = self.ik.frame(wrist_of(side))
        self.f_elbow = self.ik.frame(elbow_of(side))
        #: the frame whose orientation is the wrist's (the hand, past the wrist point on the G1)
        self.r_wrist = self.ik.rotation_frame(wrist_of(side))
        self.orientation_weight = orientation_weight
        self.iters = iters
        self._fresh = True
        rng = np.random.default_rng(0)
        lo, hi = self.ik.lower, self.ik.upper
        #: recovery starts (rest, then SEEDS postures drawn within the middle of the ranges)
        self.seeds = [self.ik.q_start, *(lo + rng.uniform(0.2, 0.8, (SEEDS, len(lo))) * (hi - lo))]
        #: frames whose warm start could not reach the wrist (solved again from the wrist alone)
        self.recoveries = 0
        self._cooldown = 0  # frames before the next recovery may run

    def reset(self) -> None:
        """Solve the next frame from the rest pose (a new stream, or after a gap)."""
        self.ik.reset()
        self._fresh = True
        self._cooldown = 0

    def __call__(
        self, wrist_p: np.ndarray, elbow_p: np.ndarray, wrist_R: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Targets of the posture for the mapped wrist position ``wrist_p`` (3,) [m], elbow ``elbow_p`` (3,) [m]
        and wrist orientation ``wrist_R`` (3, 3) (robot base frame).

        Returns:
            (elbow position (3,) [m], wrist orientation (3, 3), elbow orientation (3, 3)) of the posture.
        """
        goals = [(self.f_wrist, wrist_p, WRIST_WEIGHT), (self.f_elbow, elbow_p, 1.0)]
        rotation = (self.r_wrist, wrist_R, self.orientation_weight)

        def run(iters: int) -> float:
            self.ik.solve(goals, rotation, iters=iters, tol=0.0, step_tol=STEP_TOL, max_step=MAX_STEP)
            return float(np.linalg.norm(self.ik.pose(self.f_wrist)[0] - wrist_p))

        miss = run(FIRST_ITERS if self._fresh else self.iters)
        if miss > WRIST_TOL:
            miss = run(CATCH_UP)
        self._cooldown = max(self._cooldown - 1, 0)
        if miss > WRIST_TOL and not self._cooldown:
            # A local minimum: the elbow or the orientation holds the arm against a stop on a branch
            # where the wrist is out of reach (e.g. raising the arm by shoulder roll instead of pitch).
            # Reach the wrist alone first, which leaves that branch, then weigh the others in again;
            # from the warm posture, else from rest, else from fixed postures spread over the ranges.
            self.recoveries += 1
            best = warm = (miss, self.ik.q)
            for start in (warm[1], *self.seeds):
                self.ik.q = start.copy()
                self.ik.solve([goals[0]], None, FIRST_ITERS, tol=0.1 * WRIST_TOL * WRIST_WEIGHT, max_step=MAX_STEP)
                m = run(CATCH_UP)
                if m < best[0]:
                    best = (m, self.ik.q)
                if m <= WRIST_TOL:
                    break
            self.ik.q = best[1]
            run(0)
            if best is warm:  # no start did better: out of reach within the margins, not again for a while
                self._cooldown = RETRY_AFTER
        self._fresh = False
        elbow, elbow_R = self.ik.pose(self.f_elbow)
        return elbow, self.ik.pose(self.r_wrist)[1], elbow_R
