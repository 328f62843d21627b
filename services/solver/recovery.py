"""Lock-up recovery: leave a wrong posture the velocity-level hierarchy cannot leave by itself.

A strict velocity-level HQP is a local method: it can reach its wrist target with the arm on a branch from which
no velocity that keeps the wrist brings the elbow closer, because a joint stop blocks the way. Two such locks are
known. On the wave-left-hand clips at 7 s the shoulder roll and yaw sit at their stops and the waist swings across
its range while the elbow error grows to 30 cm (the range centring keeps the arm out of that one). On
kick_normal, after the fast kicks, the right elbow ends past straight at its hyperextension stop (2.07 rad, the
straight arm is at ~1.3-1.4 rad) with the waist roll and pitch far out: the wrist target is near, and on this
branch the arm can only shorten by extending the elbow further (blocked) or by the waist bringing the shoulder
back (which the blocked elbow cannot follow); the folded branch the elbow target asks for lies past the straight
arm, which the wrist first has to lengthen through. The elbow level's gradient cannot do that: 9-14 cm of elbow
error for seconds, with level 1 met on 98-100 % of the ticks.

Recovery, per arm, only on such a lock: over ``trigger_time`` the wrist level is met on most ticks and the wrist
within ``wrist_tolerance``, the elbow more than ``trigger_error`` off, one of the arm's joints within
``stop_margin`` of a stop, and the elbow error has not fallen by ``min_progress``. A speed-saturated tick (the
wrists behind their targets at the joints' speed limit, the vigorous clips) or an elbow still closing in does not
fire it. Then a position-level IK (damped Gauss-Newton on that arm's wrist and elbow positions, over the arm's
joints and the waist, started from the rest pose and pulled towards it in its null space) looks for a posture
meeting both targets. If it finds one, a joint-space task towards it joins the hierarchy right below the wrists: the
arm moves to it inside the wrists' null space, within the joint bounds (velocity, acceleration, self-collision), so
level 1 keeps its strict priority; the elbow level follows below. The IK posture is refreshed as the targets move,
and the recovery ends when the elbow is back within ``release_error``, the arm within ``release_distance`` of the IK
posture, or after ``max_time``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from shared.kinematics import Configuration, PostureTask, Task
from shared.robot.pinocchio_model import RobotModel
from shared.rotations import norm3
from shared.targets import ELBOWS, SIDES, WRISTS


@dataclass
class RecoveryConfig:
    """Recovery settings.

    Attributes:
        trigger_error: elbow error [m] that counts as off.
        trigger_time: how long [s] the elbow must stay off (with the wrist tracked and a joint at a stop)
            without closing in before recovering.
        min_progress: the elbow error [m] must fall by less than this over ``trigger_time`` to count as locked.
        stop_margin: a joint this close [rad] to a limit counts as at its stop (the solver keeps 0.01 rad of
            headroom, and braking holds a joint a little further off).
        met_fraction: the share of the window's ticks on which the wrist level must have been met (a wrist near its
            target but behind a fast one at the joints' speed limit misses it on most ticks; a locked arm on a few).
        wrist_tolerance: the wrist error [m] under which the wrist counts as tracked (a recovery
            only starts from a tracked wrist: otherwise level 1 itself is the problem, e.g. the wrists behind
            fast targets at the joints' speed limit).
        release_error: elbow error [m] that ends a recovery.
        release_distance: a recovery also ends when every joint of the arm is this close [rad] to the IK posture:
            the arm is on the IK's branch, where the elbow level closes the rest by itself (the joint-space task
            would hold the elbow at the IK posture's error, refreshed only every ``refresh_time``).
        max_time: longest recovery [s].
        refresh_time: the IK posture is recomputed this often [s] during a recovery.
        gain: the joint-space task's gain [1/s].
        ik_iterations: Gauss-Newton iterations of the IK.
        ik_tolerance: wrist and elbow error [m] the IK posture must reach to be used.
    """

    trigger_error: float = 0.05
    trigger_time: float = 0.1
    min_progress: float = 0.01
    stop_margin: float = 0.05
    met_fraction: float = 0.8
    wrist_tolerance: float = 0.01
    release_error: float = 0.015
    release_distance: float = 0.15
    max_time: float = 1.5
    refresh_time: float = 0.04
    gain: float = 20.0
    ik_iterations: int = 40
    ik_tolerance: float = 0.01


@dataclass
class _ArmState:
    off_since: float | None = None
    off_error: float = 0.0  # elbow error [m] when off_since was set
    next_try: float = -np.inf  # [s] after an IK that found no posture, the next attempt
    ticks: int = 0  # ticks since off_since
    met: int = 0  # of which the wrist level was met
    active_since: float | None = None
    refreshed: float = -np.inf
    q_ik: np.ndarray | None = None
    events: int = 0
    history: list = field(default_factory=list)


class LockupRecovery:
    """Per-arm lock-up detector and the joint-space task that leads the arm out.

    Args:
        robot: the solver's reduced model.
        config: settings.
    """

    def __init__(self, robot: RobotModel, config: RecoveryConfig | None = None):
        self.robot = robot
        self.config = config or RecoveryConfig()
        self.data = robot.model.createData()
        names = robot.joint_names
        waist = [i for i, n in enumerate(names) if n in robot.profile.waist]
        self.arm_joints = {s: np.array(robot.indices(robot.profile.arms[s].joints)) for s in SIDES}
        self.ik_joints = {s: np.array(sorted(waist + list(self.arm_joints[s]))) for s in SIDES}
        self.state = {s: _ArmState() for s in SIDES}
        n = robot.nq
        self.task = PostureTask(robot.q_rest, np.zeros(n), self.config.gain)
        self._fid = {t: robot.frame_id(t) for t in (*WRISTS, *ELBOWS)}

    @property
    def active(self) -> list[str]:
        """Sides recovering now."""
        return [s for s in SIDES if self.state[s].active_since is not None]

    @property
    def events(self) -> int:
        """Recoveries started so far."""
        return sum(st.events for st in self.state.values())

    def update(
        self,
        conf: Configuration,
        wrist_tasks: list[Task],
        elbow_tasks: list[Task],
        t: float,
        level1_met: bool = True,
    ) -> bool:
        """Detect lock-ups at solver time t [s] and set the joint-space task; True while one is active.

        Args:
            conf: configuration at this tick (kinematics up to date).
            wrist_tasks, elbow_tasks: the position tasks per side (``SIDES`` order), targets set.
            level1_met: the previous tick met the wrist level (``met_fraction``).
        """
        cfg = self.config
        for side, wt, et in zip(SIDES, wrist_tasks, elbow_tasks):
            st = self.state[side]
            e_el = norm3(et.p_target - conf.get_frame_pose(et.frame)[0])  # (np.linalg.norm cost more)
            if st.active_since is None and e_el <= cfg.trigger_error:
                st.off_since = None  # the elbow is near its target: no lock (most ticks end here)
                continue
            if st.active_since is not None:
                near = np.max(np.abs(conf.q[self.arm_joints[side]] - st.q_ik[self.arm_joints[side]]))
                if e_el < cfg.release_error or near < cfg.release_distance or t - st.active_since > cfg.max_time:
                    st.active_since = None
                    st.off_since = None
                    continue
                if t - st.refreshed >= cfg.refresh_time:
                    q = self._ik(conf.q if st.q_ik is None else st.q_ik, side, wt.p_target, et.p_target)
                    if q is not None:
                        st.q_ik = q
                    st.refreshed = t
                continue
            if norm3(wt.p_target - conf.get_frame_pose(wt.frame)[0]) < cfg.wrist_tolerance and self.at_stop(
                conf.q, side
            ):
                if st.off_since is None:
                    st.off_since, st.off_error, st.ticks, st.met = t, e_el, 0, 0
                st.ticks += 1
                st.met += level1_met
                if t - st.off_since < cfg.trigger_time or t < st.next_try:
                    pass
                elif e_el < st.off_error - cfg.min_progress or st.met < cfg.met_fraction * st.ticks:
                    # still closing in by itself, or the wrists mostly behind their targets (saturated): not a lock
                    st.off_since, st.off_error, st.ticks, st.met = t, e_el, 0, 0
                else:
                    seed = conf.q.copy()
                    seed[self.ik_joints[side]] = self.robot.q_rest[self.ik_joints[side]]
                    q = self._ik(seed, side, wt.p_target, et.p_target)
                    if q is not None:
                        st.q_ik, st.active_since, st.refreshed = q, t, t
                        st.events += 1
                        st.history.append(t)
                    else:
                        st.next_try = t + cfg.refresh_time  # no posture meets both targets (yet): try again soon
            else:
                st.off_since = None
        active = self.active
        if active:
            cost = self.task.cost
            cost.fill(0.0)
            target = conf.q.copy()
            for side in active:
                idx = self.arm_joints[side]
                cost[idx] = 1.0
                target[idx] = self.state[side].q_ik[idx]
            self.task.set_target(target)
        return bool(active)

    def at_stop(self, q: np.ndarray, side: str) -> bool:
        """True when one of this side's arm joints (q (n,) [rad]) is within ``stop_margin`` of a limit (the waist is
        left out: it sits near its stops on most vigorous ticks, locked or not)."""
        idx, m = self.arm_joints[side], self.config.stop_margin
        return bool(np.any((q[idx] - self.robot.lower[idx] < m) | (self.robot.upper[idx] - q[idx] < m)))

    def _ik(self, seed: np.ndarray, side: str, p_wrist: np.ndarray, p_elbow: np.ndarray) -> np.ndarray | None:
        """A posture (n,) [rad] within the limits placing this side's wrist and elbow at their targets, or None."""
        model, data, robot = self.robot.model, self.data, self.robot
        cols = self.ik_joints[side]
        fw, fe = self._fid[f"{side}_wrist"], self._fid[f"{side}_elbow"]
        q = seed.copy()
        lam = 1e-4
        for _ in range(self.config.ik_iterations):
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            e = np.r_[p_wrist - data.oMf[fw].translation, p_elbow - data.oMf[fe].translation]
            if np.linalg.norm(e[:3]) < 1e-4 and np.linalg.norm(e[3:]) < 1e-4:
                break
            J = np.vstack(
                (
                    pin.getFrameJacobian(model, data, fw, pin.LOCAL_WORLD_ALIGNED)[:3, cols],
                    pin.getFrameJacobian(model, data, fe, pin.LOCAL_WORLD_ALIGNED)[:3, cols],
                )
            )
            H = J @ J.T
            H.flat[::7] += lam
            Jp = J.T @ np.linalg.solve(H, np.eye(6))
            dq = Jp @ e
            # null-space pull towards the rest pose keeps the posture away from the stops
            dq += 0.1 * (np.eye(len(cols)) - Jp @ J) @ (robot.q_rest[cols] - q[cols])
            q[cols] = np.clip(q[cols] + dq, robot.lower[cols], robot.upper[cols])
        pin.framesForwardKinematics(model, data, q)
        ok_w = np.linalg.norm(p_wrist - data.oMf[fw].translation) < self.config.ik_tolerance
        ok_e = np.linalg.norm(p_elbow - data.oMf[fe].translation) < self.config.ik_tolerance
        return q if ok_w and ok_e else None
