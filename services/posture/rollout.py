"""Closed-loop posture-mimicry CLIK on real clips (seed 004 Fig. 3 and Algorithm 1's rollouts).

A clip is retargeted once (:func:`prepare_clip`: wrist targets, the operator's upper-arm orientation
``R_m`` and the reference elbow per frame). :func:`rollout` then runs eq. (2) per arm at ``rate`` Hz
on the 14 arm joints (waist at rest): the full wrist pose is the end-effector task and ``q̇₀`` comes
from the *driver*, either the expert (the mimicry controller, ``-η ∇H`` of eqs. 3-6 with the
operator's real upper arm) or the policy (wrist pose and joints only). Every recorded tick carries
the state, the expert's label at that state (whoever drives) and the operator arm state, so the same
rollout serves behaviour cloning (expert drives) and relabelling (policy drives, expert labels).
Velocities are clamped into the joint limits, as the solver does.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from services.posture.features import (
    ACTION_DIM,
    ACTION_KINDS,
    ACTION_LIMIT,
    ELBOW_KINDS,
    POSTURE_ACTION_GAIN,
    ArmFrame,
    action_dim,
    action_joints,
    arm_state,
    elbow_action,
    posture_action,
    state,
)
from services.posture.policy import PosturePolicy
from services.posture.swivel import SwivelFrame
from services.solver.clik_mimicry import DEFAULT_ETA, clik_step
from shared.kinematics import AlignmentTask, Configuration
from shared.mirror import arm_joints, mirror_signs
from shared.robot.pinocchio_model import RobotModel
from shared.robot.profile import upper_arm_frame
from shared.rotations import matrix_to_quat, quat_to_matrix
from shared.targets import SIDES

log = logging.getLogger("mimic.posture")

#: Retarget settings of the posture data: swivel elbows (the reference), eq. 4 orientations against
#: the calibration posture (the forearm-relative default reads the operator's elbow, which a
#: wrist-only source does not have), raw finite-difference velocities (as ``mimic eval``).
POSTURE_RETARGET: dict = {
    "velocity_tau": 0.0,
    "elbow_placement": "swivel",
    "orientation_reference": "posture",
    "upper_arms": True,  # the expert (clik-mimicry) follows the operator's upper arm
}


@dataclass
class ClipData:
    """One retargeted clip, per frame k and arm side i (left, right).

    Attributes:
        name: clip name. t: (F,) frame times [s].
        p, v: (2, F, 3) wrist target position [m] and velocity [m/s]. R: (2, F, 3, 3). w: (2, F, 3) [rad/s].
        wrist_ok: (2, F). R_m: (2, F, 3, 3) operator upper arm on the robot; has_m: (2, F).
        elbow: (2, F, 3) reference (swivel) elbow [m]; elbow_ok: (2, F).
        q_star: (2, F, 3) the operator's shoulder posture [rad]: the robot's shoulder angles that put its
            elbow and wrist on the reference elbow and the wrist target (the posture kind's label;
            valid where elbow_ok and wrist_ok).
    """

    name: str
    t: np.ndarray
    p: np.ndarray
    R: np.ndarray
    v: np.ndarray
    w: np.ndarray
    wrist_ok: np.ndarray
    R_m: np.ndarray
    has_m: np.ndarray
    elbow: np.ndarray
    elbow_ok: np.ndarray
    q_star: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    def slice(self, k0: int, k1: int) -> ClipData:
        """Frames k0..k1-1 as their own clip (times kept)."""
        s = slice(k0, k1)
        return ClipData(f"{self.name}[{k0}:{k1}]", self.t[s], self.p[:, s], self.R[:, s], self.v[:, s],
                        self.w[:, s], self.wrist_ok[:, s], self.R_m[:, s], self.has_m[:, s], self.elbow[:, s],
                        self.elbow_ok[:, s], self.q_star[:, s])  # fmt: skip


def prepare_clip(path: str | Path, robot: RobotModel) -> ClipData:
    """Retarget a clip (fresh calibration from its first frame, as the live service) into ClipData."""
    from services.evaluation.runner import load_and_retarget

    clip, targets = load_and_retarget(Path(path), robot, "bounded", POSTURE_RETARGET)
    F = len(targets)
    out = {k: np.zeros((2, F, 3)) for k in ("p", "v", "w", "elbow")}
    R = np.tile(np.eye(3), (2, F, 1, 1))
    R_m = R.copy()
    ok = {k: np.zeros((2, F), bool) for k in ("wrist_ok", "has_m", "elbow_ok")}
    for k, tt in enumerate(targets):
        for i, side in enumerate(SIDES):
            w = tt.targets[f"{side}_wrist"]
            e = tt.targets[f"{side}_elbow"]
            out["p"][i, k], out["v"][i, k], out["w"][i, k] = w.p, w.v, w.w
            R[i, k] = quat_to_matrix(w.q)
            ok["wrist_ok"][i, k] = w.valid
            out["elbow"][i, k] = e.p
            ok["elbow_ok"][i, k] = e.valid
            if side in tt.upper_arms:
                R_m[i, k] = quat_to_matrix(tt.upper_arms[side])
                ok["has_m"][i, k] = True
    t = np.array([tt.hdr.stamp for tt in targets])
    q_star = shoulder_postures(robot, out["elbow"], out["p"], ok["elbow_ok"] & ok["wrist_ok"])
    return ClipData(clip.name, t, out["p"], R, out["v"], out["w"], ok["wrist_ok"], R_m, ok["has_m"], out["elbow"],
                    ok["elbow_ok"], q_star)  # fmt: skip


def shoulder_postures(robot: RobotModel, elbow: np.ndarray, wrist: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(2, F, 3) shoulder angles [rad] of the postures reaching elbow and wrist (2, F, 3) [m], frame by frame.

    The retargeter's upper-arm IK (:class:`services.retarget.upper_arm.UpperArmSolver`, warm-started
    along the clip); frames where ``ok`` (2, F) is False keep the previous posture.
    """
    from services.retarget.upper_arm import UpperArmSolver

    out = np.zeros((*elbow.shape[:2], ACTION_DIM))
    for i, side in enumerate(SIDES):
        solver = UpperArmSolver(robot, side, upper_arm_frame(robot.profile, side))
        act = action_joints(robot, side)
        for k in range(elbow.shape[1]):
            if ok[i, k]:
                solver(elbow[i, k], wrist[i, k])
            out[i, k] = solver.q[act]
    return out


@dataclass
class RolloutConfig:
    """Closed-loop settings.

    Attributes:
        rate: CLIK rate [Hz]. Seed 004 runs 200 Hz; 50 Hz (above the clips' 30 fps, gain x dt = 0.6)
            tracks the same within 0.1 cm of elbow on real clips and keeps training to minutes.
        record_every: keep every k-th tick.
        gain, orientation_gain: K_p of eq. (2) [1/s] on position and orientation.
        eta: η of eq. (3) [1/s]. settle: first frame held this long [s] before recording.
        posture_gain: gate fallback: rest-posture pull [1/s] on the arm joints.
        action_kind: "velocity" (the expert's label is ``-η ∇H``, eqs. 3-6), "posture" (the label is
            the operator's shoulder posture ``q*``, driven as ``q̇₀ = K (q* - q)``), "elbow" (the label
            is the operator's elbow ``e*``, driven as a bounded damped least-squares step
            ``q̇₀ = J_e⁺ K (e* - e)`` of the shoulder joints, :func:`.features.elbow_action`) or "swivel"
            (the label is ``e*``'s angle on the circle of elbows that reach the wrist target, driven as
            "elbow" with the elbow placed at that angle on the current target's circle, :mod:`.swivel`).
        action_gain: K [1/s] of the posture and elbow kinds.
    """

    rate: float = 50.0
    record_every: int = 1
    gain: float = 30.0
    orientation_gain: float = 20.0
    eta: float = DEFAULT_ETA
    settle: float = 1.0
    posture_gain: float = 2.0
    action_kind: str = "velocity"
    action_gain: float = POSTURE_ACTION_GAIN


@dataclass
class Rollout:
    """Recorded ticks of one rollout, per tick k and arm i.

    Attributes:
        S: (K, 2, 14) states. A: (K, 2, A) expert labels. A_pi: (K, 2, A) policy actions (zeros when the
        expert drove); both of the config's action kind (A = 3, or 2 for the swivel kind).
        Z: (K, 2, 6) operator arm state.
        label_ok: (K, 2) expert label defined.
        elbow_err, wrist_err: (K, 2) [m] robot elbow / wrist vs the references. gate: (K, 2).
    """

    S: np.ndarray
    A: np.ndarray
    A_pi: np.ndarray
    Z: np.ndarray
    label_ok: np.ndarray
    elbow_err: np.ndarray
    wrist_err: np.ndarray
    gate: np.ndarray
    seconds: float = 0.0
    meta: dict = field(default_factory=dict)


class ArmsModel:
    """The robot pieces a rollout needs (arms-only model, per-side indices, frames, alignment tasks)."""

    def __init__(self, robot: RobotModel):
        if robot.nq != 14:
            raise ValueError(f"rollouts run on the 14 arm joints (waist at rest), got {robot.nq}")
        self.robot = robot
        self.arm = [arm_joints(robot, s) for s in SIDES]
        self.act = [action_joints(robot, s) for s in SIDES]
        self.align = [AlignmentTask(upper_arm_frame(robot.profile, s), self.act[i]) for i, s in enumerate(SIDES)]
        rest = robot.frame_poses(robot.q_rest)
        self.Q_ref = [matrix_to_quat(rest[f"{s}_wrist"][1]) for s in SIDES]
        from services.retarget.elbow import ArmGeometry

        arms = ArmGeometry.measure_arms(robot)
        geo = [arms[s] for s in SIDES]
        self.frames = [ArmFrame(g.centre.copy(), g.upper, g.fore) for g in geo]
        #: per side: the swivel kind's circle and angle reference
        self.swivel = [SwivelFrame.for_arm(g.centre, g.upper, g.fore, s) for g, s in zip(geo, SIDES)]
        #: (7,) left -> right joint signs of the mirror image (for mirrored demonstrations)
        self.mirror = mirror_signs(robot)


def rollout(
    arms: ArmsModel,
    clip: ClipData,
    driver: str = "expert",
    policy: PosturePolicy | None = None,
    config: RolloutConfig | None = None,
    use_gate: bool = False,
) -> Rollout:
    """Run eq. (2) on both arms over a clip, driven by ``"expert"`` or ``"policy"``.

    Args:
        use_gate: with the policy, fall back to the rest-posture pull where the gate is closed.
    """
    cfg = config or RolloutConfig()
    if driver not in ("expert", "policy"):
        raise ValueError(f"driver must be 'expert' or 'policy', got {driver!r}")
    if driver == "policy" and policy is None:
        raise ValueError("the policy driver needs a policy")
    if cfg.action_kind not in ACTION_KINDS:
        raise ValueError(f"action_kind must be one of {ACTION_KINDS}, got {cfg.action_kind!r}")
    kind = cfg.action_kind
    posture = kind != "velocity"  # posture and elbow kinds: a label from the clip frame alone
    n_act = action_dim(kind)
    robot = arms.robot
    conf = Configuration(robot)
    q = robot.q_rest.copy()
    dt = 1.0 / cfg.rate
    t0 = clip.t[0]
    t_start = t0 - cfg.settle
    n_ticks = int((clip.t[-1] - t_start) / dt) + 1
    frame_dt = float(np.median(np.diff(clip.t))) if len(clip.t) > 1 else 1.0 / 30.0
    rec: dict[str, list] = {k: [] for k in ("S", "A", "A_pi", "Z", "ok", "ee", "we", "gate")}
    wrist_names = [f"{s}_wrist" for s in SIDES]
    elbow_names = [f"{s}_elbow" for s in SIDES]
    k = 0
    for tick in range(n_ticks):
        t = t_start + tick * dt
        while k + 1 < len(clip.t) and clip.t[k + 1] <= t + 1e-12:
            k += 1
        settling = t < t0
        tau = 0.0 if settling else min(t - clip.t[k], frame_dt)
        conf.update(q)
        S = np.zeros((2, 14))
        A = np.zeros((2, n_act))
        lab = np.zeros(2, bool)
        p_t = []
        for i in range(2):
            p_t.append(clip.p[i, k] + (0.0 if settling else 1.0) * clip.v[i, k] * tau)
            S[i] = state(matrix_to_quat(clip.R[i, k]), p_t[i], q[arms.arm[i]], arms.Q_ref[i])
            if kind == "swivel":
                A[i] = arms.swivel[i].angle(clip.elbow[i, k], clip.p[i, k])  # (the frame's own wrist target)
                lab[i] = True
            elif posture:
                A[i] = clip.elbow[i, k] if kind == "elbow" else clip.q_star[i, k]
                lab[i] = True
            elif clip.has_m[i, k]:
                arms.align[i].set_target(clip.R_m[i, k], check=False)
                A[i] = np.clip(-cfg.eta * arms.align[i].gradient(conf)[arms.act[i]], -ACTION_LIMIT, ACTION_LIMIT)
                lab[i] = True
        A_pi = np.zeros((2, n_act))
        gate = np.zeros(2, bool)
        if driver == "policy":
            out = policy.act(S)
            # copies: the policy's output arrays are its buffers, overwritten by the next call
            A_pi, gate, qd0_pi = out.action.astype(float), out.gate.copy(), out.qd0.copy()
            elbow_pi = out.elbow.astype(float)
        qd = np.zeros(robot.nq)
        for i in range(2):
            J = conf.get_frame_jacobian(wrist_names[i])[:, arms.arm[i]]
            p, R = conf.get_frame_pose(wrist_names[i])
            ff = np.zeros(6) if settling else np.r_[clip.v[i, k], clip.w[i, k]]
            b = ff + np.r_[cfg.gain * (p_t[i] - p), cfg.orientation_gain * pin.log3(clip.R[i, k] @ R.T)]
            qd0 = np.zeros(7)
            a_i = A[i] if driver == "expert" else A_pi[i]
            if driver == "policy" and use_gate and not gate[i]:
                qd0 = cfg.posture_gain * (robot.q_rest[arms.arm[i]] - q[arms.arm[i]])
            elif kind in ELBOW_KINDS:
                J_e = conf.get_frame_jacobian(elbow_names[i])[:3, arms.act[i]]
                e_now = conf.get_frame_pose(elbow_names[i])[0]
                if driver == "policy":
                    e_t = elbow_pi[i]
                else:
                    e_t = arms.swivel[i].place(a_i, p_t[i]) if kind == "swivel" else a_i
                qd0[:ACTION_DIM] = elbow_action(J_e, e_t, e_now, cfg.action_gain)
            elif driver == "expert":
                qd0[:ACTION_DIM] = posture_action(a_i, q[arms.act[i]], cfg.action_gain) if posture else a_i
            else:
                qd0[:ACTION_DIM] = qd0_pi[i]
            if not cfg.orientation_gain:
                J, b = J[:3], b[:3]  # position-only end-effector task
            qd[arms.arm[i]] = clik_step(J, b, qd0)
        lb = np.maximum(-robot.vmax, (robot.lower - q) / dt)
        ub = np.minimum(robot.vmax, (robot.upper - q) / dt)
        q = q + np.minimum(np.maximum(qd, lb), ub) * dt
        if tick % cfg.record_every:
            continue
        ee = np.full(2, np.nan)
        we = np.full(2, np.nan)
        Z = np.zeros((2, 6))
        for i in range(2):
            pe = conf.get_frame_pose(elbow_names[i])[0]
            pw = conf.get_frame_pose(wrist_names[i])[0]
            if clip.elbow_ok[i, k]:
                Z[i] = arm_state(arms.frames[i], clip.elbow[i, k], clip.p[i, k])
                if not settling:  # the settle is labelled (the robot leaves its rest pose) but not scored
                    ee[i] = np.linalg.norm(pe - clip.elbow[i, k])
            if clip.wrist_ok[i, k] and not settling:
                we[i] = np.linalg.norm(pw - p_t[i])
        rec["S"].append(S)
        rec["A"].append(A)
        rec["A_pi"].append(A_pi)
        rec["Z"].append(Z)
        rec["ok"].append(lab & clip.elbow_ok[:, k] & clip.wrist_ok[:, k])
        rec["ee"].append(ee)
        rec["we"].append(we)
        rec["gate"].append(gate)
    arr = {k: np.asarray(v) for k, v in rec.items()}
    return Rollout(arr["S"], arr["A"], arr["A_pi"], arr["Z"], arr["ok"], arr["ee"], arr["we"], arr["gate"],
                   clip.duration, {"clip": clip.name, "driver": driver})  # fmt: skip
