"""Balance and joint control of the wheeled-legged robot in MuJoCo (pure logic, no bus).

Seed 002 assumes the TITA keeps its own balance; this module is that layer. It turns the
planner's torso and arm motion into motor torques on the physical model (free-floating torso,
wheels rolling on the floor, every joint torque-limited by Table 2):

* **Wheels: LQR on the wheeled inverted pendulum.** The robot above the wheel axle is one
  rigid body (legs held stiff) leaning by φ, the angle of the centre of mass (COM) ahead of
  the axle midpoint. Linear model (per unit of total wheel torque τ, forward motion x of the
  axle, small φ)::

      (M + m_w + I_w/r²) ẍ + M h φ̈ = τ / r
      M h ẍ + (I + M h²) φ̈ - M g h φ = -τ

  M, h, I: mass, COM height above the axle and pitch inertia (about the COM) of everything but
  the wheels; m_w, I_w: both wheels' mass and spin inertia; r: wheel radius. All are read from
  the MuJoCo model at the current configuration. Discrete LQR (ZOH at the control period) on
  ``[x_b - x_b,ref, φ - φ_ref, ẋ - ẋ_ref, φ̇]`` with the torque and lean that hold the planned
  acceleration as feed-forward. The position state is the torso's (not the axle's) error to
  its plan, so leg sag cannot offset the torso. Gains are recomputed every ``regain_period``
  (the arm moves the COM).
* **Legs: the COM leans, not the torso.** Hip pitch and knee are placed by planar 2-link IK so
  that the torso centre sits at the planned height z_b and the axle lies where the lean φ_ref
  wants it relative to the COM (``x_axle = x_com - h tan φ_ref``). The torso therefore stays
  level while the pendulum leans: with the legs held stiff, the torso's pitch is the
  pendulum's pitch error only.
* **Heading**: PD on the torso yaw through differential wheel torque, plus the planned yaw
  acceleration as feed-forward.
* **Joints** (legs, arm, gripper): PD on the reference plus MuJoCo's bias forces
  (``qfrc_bias``: gravity, Coriolis) as feed-forward, clipped to the motor limits.

Simplifications (stated): the pendulum model is planar (sagittal) and linear; roll is left to
the ground contact (hip-outside joints held at 0); the heading loop is a PD, not part of the
LQR; the COM/inertia come from the simulator's model (a real robot would use its own model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
import scipy.linalg

G = 9.81


@dataclass
class BalanceConfig:
    """Gains and weights.

    Attributes:
        dt: control period [s] (the LQR is discretised at it).
        q_lqr: (4,) LQR state weights on [x [m], φ [rad], ẋ [m/s], φ̇ [rad/s]].
        r_lqr: LQR weight on the total wheel torque [1/(N m)^2].
        regain_period: recompute the LQR gains every this many seconds.
        joint_kp, joint_kd: PD gains of the legs [N m/rad, N m s/rad]; arm_kp, arm_kd: of the arm.
        yaw_kp, yaw_kd: heading PD [N m/rad, N m s/rad] (differential wheel torque).
        trim_gain: integral gain [m/(rad s)] moving the axle target to level the torso's pitch
            (and [1/s] on the torso height error, for the legs' sag under load).
    """

    dt: float = 0.001
    q_lqr: tuple[float, float, float, float] = (10000.0, 2000.0, 500.0, 10.0)
    r_lqr: float = 1.0
    regain_period: float = 0.1
    joint_kp: float = 3000.0
    joint_kd: float = 20.0
    arm_kp: float = 400.0
    arm_kd: float = 10.0
    yaw_kp: float = 200.0
    yaw_kd: float = 40.0
    trim_gain: float = 2.0


def yaw_pitch_roll(quat_wxyz: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (yaw α, pitch β, roll γ) [rad] of a quaternion w, x, y, z."""
    w, x, y, z = quat_wxyz
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    return yaw, pitch, roll


def leg_ik(dx: float, dz: float, length: float) -> tuple[float, float]:
    """(hip pitch, knee) [rad] putting the wheel centre at (dx, dz) [m] from the hip, in the leg's plane.

    Two equal links of ``length`` [m], both joints about +y (positive tilts the link's -z end
    towards -x), knee bent negative (Table 2's knee range is negative). Thigh at angle θh, crus at
    θh + θk: ``(dx, dz) = l (-sin θh - sin(θh + θk), -cos θh - cos(θh + θk))``.
    """
    d = math.hypot(dx, dz)
    c = d * d / (2.0 * length * length) - 1.0
    knee = -math.acos(max(-1.0, min(1.0, c)))
    psi = math.atan2(-dx, -dz)
    return psi - knee / 2.0, knee


def wip_lqr(M: float, h: float, I: float, m_w: float, I_w: float, r: float, dt: float, Qd, Rd) -> np.ndarray:
    """Discrete LQR gain K (1, 4) for the wheeled inverted pendulum of the module docstring."""
    A11 = M + m_w + I_w / (r * r)
    A12 = M * h
    A22 = I + M * h * h
    Minv = np.linalg.inv(np.array([[A11, A12], [A12, A22]]))
    # [ẍ; φ̈] = Minv ([0; M g h] φ + [1/r; -1] τ)
    gphi = Minv @ np.array([0.0, M * G * h])
    gtau = Minv @ np.array([1.0 / r, -1.0])
    Ac = np.zeros((4, 4))
    Ac[0, 2] = Ac[1, 3] = 1.0
    Ac[2, 1], Ac[3, 1] = gphi
    Bc = np.zeros((4, 1))
    Bc[2, 0], Bc[3, 0] = gtau
    # Zero-order hold via the augmented matrix exponential.
    aug = np.zeros((5, 5))
    aug[:4, :4] = Ac * dt
    aug[:4, 4:] = Bc * dt
    E = scipy.linalg.expm(aug)
    Ad, Bd = E[:4, :4], E[:4, 4:]
    Q = np.diag(Qd)
    R = np.array([[Rd]])
    P = scipy.linalg.solve_discrete_are(Ad, Bd, Q, R)
    return np.linalg.solve(R + Bd.T @ P @ Bd, Bd.T @ P @ Ad)


def wip_feedforward(M: float, h: float, m_w: float, I_w: float, r: float, acc: float) -> tuple[float, float]:
    """(τ [N m], φ [rad]) that hold a constant forward acceleration acc [m/s^2] with φ̈ = 0."""
    tau = r * (M + m_w + I_w / (r * r)) * acc
    phi = math.asin(max(-0.5, min(0.5, (M * h * acc + tau) / (M * G * h))))
    return tau, phi


@dataclass
class Reference:
    """What the planner asks of the robot at one instant.

    Attributes:
        base: (4,) [x_b, y_b, z_b, α] [m, rad]; base_d: (4,) velocities; base_dd: (4,) accelerations.
        arm: (3,) planned arm joints [rad]; arm_d: (3,) their velocities [rad/s].
    """

    base: np.ndarray
    base_d: np.ndarray
    base_dd: np.ndarray
    arm: np.ndarray
    arm_d: np.ndarray


class BalanceController:
    """Torques for every motor of the wheeled-legged robot from a :class:`Reference` (see module docstring).

    Args:
        model: MuJoCo model of the robot (free root body = torso).
        arm: planner arm joint names (3); held: other arm joints -> angle [rad].
        wheels: (left, right) wheel body names. torso: torso body name.
        config: gains.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        arm: tuple[str, ...],
        held: dict[str, float],
        wheels: tuple[str, str],
        torso: str = "torso",
        config: BalanceConfig | None = None,
    ):
        self.m = model
        self.cfg = config or BalanceConfig()
        self.torso = model.body(torso).id
        self.wheel_bodies = [model.body(w).id for w in wheels]
        self.wheel_joints = [model.joint(w).id for w in wheels]
        self.r = float(model.geom_size[model.geom(f"{wheels[0]}_geom").id][0])
        self.m_w = float(sum(model.body_mass[b] for b in self.wheel_bodies))
        self.I_w = float(sum(model.body_inertia[b][1] for b in self.wheel_bodies))
        self.arm = [model.joint(n).id for n in arm]
        self.held = {model.joint(n).id: v for n, v in held.items()}
        self.sides = ("left", "right")
        self.legs = {
            s: [model.joint(f"{s}_hip_out").id, model.joint(f"{s}_hip_pitch").id, model.joint(f"{s}_knee").id]
            for s in self.sides
        }
        self.fingers = [j for j in range(model.njnt) if model.joint(j).name.startswith("finger")]
        thigh = model.body("left_crus").pos
        self.leg_length = float(abs(thigh[2]))
        hip = model.body("left_hip").pos
        self.hip_offset = np.array(hip)  # hip pivot in the torso frame [m]
        self.act = {model.actuator(a).trnid[0]: a for a in range(model.nu)}
        self.total_mass = float(model.body_subtreemass[self.torso])
        self.K = np.zeros((1, 4))
        self._t_gain = -math.inf
        self.params = (1.0, 1.0, 1.0)
        self.trim = 0.0  # axle target trim in the torso frame [m]
        self.ztrim = 0.0  # torso height target trim [m] (leg servo sag)
        self.last = {}

    # ------------------------------------------------------------------ measurements

    def pendulum(self, d: mujoco.MjData, with_inertia: bool = False) -> dict:
        """Measured pendulum state in the heading frame: axle x [m], φ [rad], ẋ [m/s], φ̇ [rad/s].

        Also M and h (non-wheel mass [kg], its COM height over the axle [m]), the COM (3,) [m],
        the torso's yaw/pitch/roll [rad] and, with ``with_inertia``, I: the non-wheel pitch
        inertia about the COM [kg m^2] (a loop over bodies: only when the gains are recomputed).
        """
        m = self.m
        yaw, pitch, roll = yaw_pitch_roll(d.qpos[3:7])
        c, s = math.cos(yaw), math.sin(yaw)
        fwd = np.array([c, s, 0.0])
        w0, w1 = self.wheel_bodies
        axle = 0.5 * (d.xpos[w0] + d.xpos[w1])
        mujoco.mj_subtreeVel(m, d)
        mw0, mw1 = m.body_mass[w0], m.body_mass[w1]
        M = self.total_mass - mw0 - mw1
        com = (self.total_mass * d.subtree_com[self.torso] - mw0 * d.xipos[w0] - mw1 * d.xipos[w1]) / M
        vcom = (
            self.total_mass * d.subtree_linvel[self.torso] - mw0 * d.subtree_linvel[w0] - mw1 * d.subtree_linvel[w1]
        ) / M
        vaxle = 0.5 * (d.subtree_linvel[w0] + d.subtree_linvel[w1])  # a wheel's COM is its centre
        rel = com - axle
        h = float(rel[2])
        dxf = float(rel @ fwd)
        vrel = vcom - vaxle
        phi = math.atan2(dxf, h)
        phid = (float(vrel @ fwd) * h - float(vrel[2]) * dxf) / (h * h + dxf * dxf)
        out = {
            "x": float(axle @ fwd),
            "phi": phi,
            "xd": float(vaxle @ fwd),
            "phid": phid,
            "M": M,
            "h": h,
            "yaw": yaw,
            "pitch": pitch,
            "roll": roll,
            "com": com,
        }
        if with_inertia:
            lat = np.array([-s, c, 0.0])
            Iyy = 0.0
            for b in range(1, m.nbody):
                if b in self.wheel_bodies:
                    continue
                Rb = d.ximat[b].reshape(3, 3)
                Iyy += float(lat @ (Rb @ np.diag(m.body_inertia[b]) @ Rb.T) @ lat)
                dxb = d.xipos[b] - com
                Iyy += m.body_mass[b] * (float(dxb @ fwd) ** 2 + float(dxb[2]) ** 2)
            out["I"] = Iyy
        return out

    # ------------------------------------------------------------------ control

    def _pd(self, d: mujoco.MjData, jid: int, q_ref: float, qd_ref: float, kp: float, kd: float) -> None:
        m = self.m
        qa, va = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
        tau = kp * (q_ref - d.qpos[qa]) + kd * (qd_ref - d.qvel[va]) + d.qfrc_bias[va]
        a = self.act[jid]
        lo, hi = m.actuator_ctrlrange[a]
        d.ctrl[a] = min(hi, max(lo, tau))

    def compute(self, d: mujoco.MjData, ref: Reference) -> None:
        """Write every motor torque into ``d.ctrl`` for the current state and reference."""
        cfg = self.cfg
        regain = d.time - self._t_gain >= cfg.regain_period - 1e-9
        pend = self.pendulum(d, with_inertia=regain)
        self.last = pend
        M, h = pend["M"], pend["h"]
        if regain:
            self.K = wip_lqr(M, h, pend["I"], self.m_w, self.I_w, self.r, cfg.dt, cfg.q_lqr, cfg.r_lqr)
            self._t_gain = float(d.time)
        alpha = ref.base[3]
        ca, sa = math.cos(alpha), math.sin(alpha)
        fwd_ref = np.array([ca, sa])
        # Planned forward acceleration and velocity of the torso, along the planned heading.
        acc = float(fwd_ref @ ref.base_dd[:2])
        vel = float(fwd_ref @ ref.base_d[:2])
        tau_ff, phi_ref = wip_feedforward(M, h, self.m_w, self.I_w, self.r, acc)
        # Where the axle should be: under the COM, shifted back by the planned lean. The COM is
        # taken in the torso frame (what it would be with the torso level), plus a slow trim that
        # integrates the torso's pitch away (leg servo sag, model error).
        Rt = d.xmat[self.torso].reshape(3, 3)
        com_t = Rt.T @ (pend["com"] - d.xpos[self.torso])
        self.trim -= cfg.trim_gain * pend["pitch"] * cfg.dt
        self.trim = max(-0.05, min(0.05, self.trim))
        self.ztrim += cfg.trim_gain * (ref.base[2] - float(d.qpos[2])) * cfg.dt
        self.ztrim = max(-0.02, min(0.02, self.ztrim))
        lean = h * math.tan(phi_ref)
        ax_in_torso = float(com_t[0]) - lean + self.trim
        # Position error taken on the torso (what the plan asks for), not on the axle: the legs'
        # servo sag would otherwise offset the torso from its plan by millimetres.
        x_err = float(fwd_ref @ (d.qpos[:2] - ref.base[:2]))
        err = np.array([x_err, pend["phi"] - phi_ref, pend["xd"] - vel, pend["phid"]])
        tau = tau_ff - float((self.K @ err)[0])
        # Heading: differential torque (right wheel forward turns left, +yaw).
        yaw_rate = float(d.qvel[5])  # body-frame z rate ~ world yaw rate with the torso level
        yaw_err = math.atan2(math.sin(alpha - pend["yaw"]), math.cos(alpha - pend["yaw"]))
        tau_yaw = cfg.yaw_kp * yaw_err + cfg.yaw_kd * (ref.base_d[3] - yaw_rate)
        for sign, w in zip((-1.0, 1.0), self.wheel_joints):  # left, right
            a = self.act[w]
            lo, hi = self.m.actuator_ctrlrange[a]
            d.ctrl[a] = min(hi, max(lo, 0.5 * tau + sign * 0.5 * tau_yaw))
        # Legs: torso at height z_b, level; axle where the lean wants it (in the torso's heading frame).
        for s in self.sides:
            hip_out, hip_pitch, knee = self.legs[s]
            dz = -(ref.base[2] + self.ztrim - self.r) - self.hip_offset[2]
            hp, kn = leg_ik(ax_in_torso - self.hip_offset[0], dz, self.leg_length)
            self._pd(d, hip_out, 0.0, 0.0, cfg.joint_kp, cfg.joint_kd)
            self._pd(d, hip_pitch, hp, 0.0, cfg.joint_kp, cfg.joint_kd)
            self._pd(d, knee, kn, 0.0, cfg.joint_kp, cfg.joint_kd)
        for j, qr, qdr in zip(self.arm, ref.arm, ref.arm_d):
            self._pd(d, j, float(qr), float(qdr), cfg.arm_kp, cfg.arm_kd)
        for j, v in self.held.items():
            self._pd(d, j, v, 0.0, cfg.arm_kp, cfg.arm_kd)
        for j in self.fingers:
            self._pd(d, j, 0.0, 0.0, 200.0, 2.0)
