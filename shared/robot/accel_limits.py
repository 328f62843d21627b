"""Per-joint acceleration limits the motors can deliver: effort / worst-case joint inertia.

A joint's motor gives at most ``effort_j`` (URDF ``<limit effort>``, MuJoCo ``jnt_actfrcrange``).
To accelerate joint j at ``a`` it must supply ``M_jj(q) a`` (joint-space mass matrix diagonal,
armature included) on top of the gravity torque ``g_j(q)``: the sim compensates gravity *through
the actuators* (``actgravcomp``), so that torque comes out of the same clamped budget, and a real
motor holding the arm up pays it too. So, over the reachable postures (the controlled joints
sampled uniformly within their limits, every other joint at the profile's rest pose)::

    a_motor_j = min_q (effort_j - |g_j(q)|) / M_jj(q)                      [rad/s^2]

and the limit written into the profile keeps ``reserve`` of it back::

    a_max_j = (1 - reserve) a_motor_j

for what this bound leaves out: the push of the other joints' accelerations through the
off-diagonal ``M_jk`` (a shoulder reversal pushes the elbow), velocity-product (Coriolis and
centrifugal) torques, and the servo's own feedback correcting an error. They scale with the
other joints' limits and speeds, so a worst case of all of them at once is far too pessimistic
(it leaves the waist nothing); half the net effort is held back for them.

This is computed offline and written as data into the robot profile (``[acceleration_limits]``;
robots are data). Print the table for a profile with::

    python -m shared.robot.accel_limits --robot g1_29dof

It only prints; nothing is written at run time. The solver, its smoother and the sim's servo target
use the table only when the profile sets ``[model] motor_acceleration_limits = true``
(``RobotProfile.joint_acceleration``). The G1 ships with it off: measured on 4 real clips
(``mimic eval --algos hqp-nullspace``, with and without the sim) the motor limits make the commands
feasible (the sim's steps past 1.01 vmax fall 34-61 %, run_happy's worst |qd| 2.97 -> 1.42 vmax with
no reserve), but the strict velocity-level HQP reaches the wrist targets with the fast distal joints
(up to 260x the waist's limit) and ends in another arm posture the elbow level cannot undo: elbow
errors 0.4-0.8 -> 2-18 cm on gesture clips. Both ``reserve`` 0.5 and 0 were measured; both lose.
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import dataclass

import mujoco
import numpy as np

from shared.robot.mujoco_model import build_mujoco_robot
from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile

log = logging.getLogger(__name__)

#: Fraction of the net motor acceleration held back for coupling, Coriolis and servo feedback.
RESERVE = 0.5
#: Posture samples (controlled joints uniform within their limits) and their seed.
SAMPLES = 2000
SEED = 0


@dataclass(frozen=True)
class MotorAccelerations:
    """What each controlled joint's motor can do, over the sampled postures.

    Attributes:
        joints: (n,) controlled joints, profile order.
        effort: (n,) motor torque limit [N m].
        inertia_max: (n,) max over postures of M_jj [kg m^2] (armature included).
        gravity_max: (n,) max over postures of |g_j| [N m].
        motor: (n,) min over postures of (effort - |g_j|) / M_jj [rad/s^2].
        limit: (n,) (1 - reserve) * motor [rad/s^2], before rounding.
    """

    joints: tuple[str, ...]
    effort: np.ndarray
    inertia_max: np.ndarray
    gravity_max: np.ndarray
    motor: np.ndarray
    limit: np.ndarray


def joint_inertia_and_gravity(model: mujoco.MjModel, data: mujoco.MjData, dofs: np.ndarray):
    """M_jj (k,) [kg m^2] and gravity torque g_j (k,) [N m] of ``dofs`` at ``data.qpos`` (at rest: qvel = 0).

    ``qfrc_bias`` at zero velocity is the gravity torque alone; ``mj_fullM`` includes ``dof_armature``.
    """
    data.qvel[:] = 0.0
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return full[dofs, dofs].copy(), data.qfrc_bias[dofs].copy()


def motor_accelerations(
    profile: RobotProfile | str | None = None, samples: int = SAMPLES, seed: int = SEED, reserve: float = RESERVE
) -> MotorAccelerations:
    """Derive the per-joint limits of the profile's controlled joints (waist included) on its MuJoCo model.

    Gravity compensation is off in this model: ``qfrc_bias`` is then the full gravity torque, which the
    motors pay whether the sim routes it through ``actgravcomp`` or the servo holds it.
    """
    if not 0.0 <= reserve < 1.0:
        raise ValueError(f"reserve must be in [0, 1), got {reserve}")
    prof = profile if isinstance(profile, RobotProfile) else load_profile(profile or DEFAULT_PROFILE)
    robot = build_mujoco_robot(prof, gravity_compensation=False)
    m, d = robot.model, robot.data
    jids = [m.joint(j).id for j in robot.joint_names]
    if not all(m.jnt_actfrclimited[j] for j in jids):
        unlimited = [n for n, j in zip(robot.joint_names, jids, strict=True) if not m.jnt_actfrclimited[j]]
        raise ValueError(f"profile {prof.name}: joints {unlimited} have no effort limit in the URDF")
    effort = np.array([min(-m.jnt_actfrcrange[j][0], m.jnt_actfrcrange[j][1]) for j in jids])
    lo = np.array([m.jnt_range[j][0] if m.jnt_limited[j] else -np.pi for j in jids])
    hi = np.array([m.jnt_range[j][1] if m.jnt_limited[j] else np.pi for j in jids])
    rest = d.qpos.copy()  # every joint at the profile's rest pose
    rng = np.random.default_rng(seed)
    n = len(jids)
    inertia_max, gravity_max, motor = np.zeros(n), np.zeros(n), np.full(n, np.inf)
    for k in range(samples):
        d.qpos[:] = rest
        d.qpos[robot.qpos_idx] = rest[robot.qpos_idx] if k == 0 else rng.uniform(lo, hi)
        inertia, gravity = joint_inertia_and_gravity(m, d, robot.dof_idx)
        np.maximum(inertia_max, inertia, out=inertia_max)
        np.maximum(gravity_max, np.abs(gravity), out=gravity_max)
        np.minimum(motor, (effort - np.abs(gravity)) / inertia, out=motor)
    if np.any(motor <= 0.0):
        weak = [robot.joint_names[i] for i in np.flatnonzero(motor <= 0.0)]
        raise ValueError(f"profile {prof.name}: joints {weak} cannot hold themselves against gravity")
    return MotorAccelerations(robot.joint_names, effort, inertia_max, gravity_max, motor, (1.0 - reserve) * motor)


def round_down(a: np.ndarray) -> np.ndarray:
    """Two significant digits, rounded down (a limit may only get safer): 337.7 -> 330, 6.53 -> 6.5."""
    a = np.asarray(a, dtype=float)
    scale = 10.0 ** (np.floor(np.log10(a)) - 1)
    return np.floor(a / scale + 1e-9) * scale


def profile_table(acc: MotorAccelerations) -> str:
    """The ``[acceleration_limits]`` TOML table, one commented line per joint."""
    lines = ["[acceleration_limits]"]
    for j, name in enumerate(acc.joints):
        value = float(round_down(acc.limit[j]))
        lines.append(
            f"{name} = {value:g}  # effort {acc.effort[j]:g} N m, M_jj <= {acc.inertia_max[j]:.4f} kg m^2, "
            f"|g| <= {acc.gravity_max[j]:.2f} N m, motor {acc.motor[j]:.1f} rad/s^2"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the profile's per-joint acceleration table (stdout); returns the exit code."""
    ap = argparse.ArgumentParser(prog="python -m shared.robot.accel_limits", description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default=DEFAULT_PROFILE, help="robot profile name or TOML file")
    ap.add_argument("--samples", type=int, default=SAMPLES, help="posture samples")
    ap.add_argument("--seed", type=int, default=SEED)
    ap.add_argument("--reserve", type=float, default=RESERVE, help="fraction of the net effort held back")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    try:
        acc = motor_accelerations(args.robot, args.samples, args.seed, args.reserve)
    except ValueError as exc:  # ProfileError is a ValueError
        print(f"error: {exc}", file=sys.stderr)
        return 2
    sys.stdout.write(profile_table(acc) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
