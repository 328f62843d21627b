"""Seed 003's PoE kinematics held against Pinocchio and MuJoCo (independent implementations).

Screw axes of each chain are read off Pinocchio once at q = 0 (:func:`arm_screws`); from
then on the PoE code runs alone and must agree with both libraries over random configurations.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from shared.kinematics.poe import (
    adjoint,
    exp6,
    fk_body,
    fk_space,
    jacobian_body,
    jacobian_space,
    jacobian_space_dot,
    log6,
    mixed_from_body,
    mixed_from_space,
    point_acceleration_bias,
    space_to_body,
    trans_inv,
)
from shared.robot.mujoco_model import build_mujoco_robot
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.wheeled import arm_screws, build_wheeled_robot
from shared.targets import SIDES, wrist_of

TOL = 1e-10
N_CONFIGS = 40


def _swap(J: np.ndarray) -> np.ndarray:
    """Pinocchio's [v; ω] rows to Modern Robotics' [ω; v]."""
    return np.vstack([J[3:], J[:3]])


@pytest.fixture(scope="module")
def g1():
    robot = build_robot_model(with_waist=False)
    chains = {}
    for side in SIDES:
        joints = robot.profile.arms[side].joints
        # the hand link, the rigid frame at the chain's end (the wrist target's position is the pitch axis before it)
        frame = robot.profile.orientation_frame(wrist_of(side))
        S, M = arm_screws(robot.model, tuple(joints), frame, robot.profile.base_frame)
        idx = [robot.model.joints[robot.model.getJointId(j)].idx_q for j in joints]
        chains[side] = (S, M, idx, frame)
    return robot, chains


@pytest.fixture(scope="module")
def tita():
    return build_wheeled_robot("tita_piper")


def test_exp6_log6_against_pinocchio():
    rng = np.random.default_rng(1)
    for _ in range(50):
        V = rng.normal(size=6) * 1.2
        T = exp6(V)
        ref = pin.exp6(pin.Motion(V[3:], V[:3])).homogeneous
        assert np.abs(T - ref).max() < 1e-12
        assert np.abs(log6(T) - V).max() < 1e-9 or np.linalg.norm(V[:3]) > np.pi


@pytest.mark.parametrize("side", ["right", "left"])
def test_g1_arm_fk_and_jacobians_match_pinocchio(g1, side):
    robot, chains = g1
    S, M, idx, frame = chains[side]
    B = space_to_body(M, S)
    model, data = robot.model, robot.model.createData()
    fid = model.getFrameId(frame)
    rng = np.random.default_rng(7)
    for q in robot.random_configurations(N_CONFIGS, rng):
        theta = q[idx]
        # The other arm's joints move too: they must not change this chain.
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        T_ref = data.oMf[fid].homogeneous
        assert np.abs(fk_space(M, S, theta) - T_ref).max() < TOL
        assert np.abs(fk_body(M, B, theta) - T_ref).max() < TOL
        Js = jacobian_space(S, theta)
        Jb = jacobian_body(B, theta)
        J_world = _swap(pin.getFrameJacobian(model, data, fid, pin.WORLD))[:, idx]
        J_local = _swap(pin.getFrameJacobian(model, data, fid, pin.LOCAL))[:, idx]
        J_lwa = _swap(pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED))[:, idx]
        assert np.abs(Js - J_world).max() < TOL
        assert np.abs(Jb - J_local).max() < TOL
        assert np.abs(mixed_from_space(Js, T_ref[:3, 3]) - J_lwa).max() < TOL
        assert np.abs(mixed_from_body(Jb, T_ref[:3, :3]) - J_lwa).max() < TOL
        # Space and body Jacobians are one adjoint apart.
        assert np.abs(adjoint(T_ref) @ Jb - Js).max() < TOL


def test_g1_arm_fk_and_jacobian_match_mujoco(g1):
    robot, chains = g1
    S, M, idx, frame = chains["right"]
    mj = build_mujoco_robot(robot.profile, joint_names=robot.joint_names)
    m, d = mj.model, mj.data
    bid = m.body(frame).id
    base = mj.body_ids["__base__"]
    rng = np.random.default_rng(3)
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for q in robot.random_configurations(N_CONFIGS, rng):
        mj.set_q(q)
        mujoco.mj_comPos(m, d)
        Rb = d.xmat[base].reshape(3, 3)
        p, R = Rb.T @ (d.xpos[bid] - d.xpos[base]), Rb.T @ d.xmat[bid].reshape(3, 3)
        T = fk_space(M, S, q[idx])
        assert np.abs(T[:3, 3] - p).max() < TOL
        assert np.abs(T[:3, :3] - R).max() < TOL
        mujoco.mj_jacBody(m, d, jacp, jacr, bid)
        dofs = mj.dof_idx[idx]
        J_mj = np.vstack([Rb.T @ jacr[:, dofs], Rb.T @ jacp[:, dofs]])
        assert np.abs(mixed_from_space(jacobian_space(S, q[idx]), p) - J_mj).max() < TOL


def test_jacobian_derivative_against_finite_differences_and_pinocchio(g1):
    robot, chains = g1
    S, M, idx, frame = chains["right"]
    model, data = robot.model, robot.model.createData()
    fid = model.getFrameId(frame)
    rng = np.random.default_rng(11)
    h = 1e-6
    for q in robot.random_configurations(10, rng):
        theta = q[idx]
        dtheta = rng.normal(size=len(idx))
        Jd = jacobian_space_dot(S, theta, dtheta)
        fd = (jacobian_space(S, theta + h * dtheta) - jacobian_space(S, theta - h * dtheta)) / (2 * h)
        assert np.abs(Jd - fd).max() < 1e-7
        # The origin's acceleration at zero joint acceleration: Pinocchio's classical acceleration.
        v = np.zeros(model.nv)
        v[idx] = dtheta
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.updateFramePlacements(model, data)
        a_ref = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
        assert np.abs(point_acceleration_bias(S, M, theta, dtheta) - a_ref).max() < 1e-10


def test_tita_arm_matches_pinocchio_and_mujoco(tita):
    """The new robot's whole arm chain (J1-J6) in Σb, on a torso placed anywhere."""
    prof = tita.profile
    m = tita.mj_model
    d = mujoco.MjData(m)
    model = tita.pin_model
    data = model.createData()
    S, M = tita.S_chain, tita.M_chain
    fid = model.getFrameId(prof.hand_site)
    site = m.site(prof.hand_site).id
    torso = m.body("torso").id
    chain = prof.arm_chain
    jq = [model.joints[model.getJointId(j)].idx_q for j in chain]
    jv = [model.joints[model.getJointId(j)].idx_v for j in chain]
    mq = [m.jnt_qposadr[m.joint(j).id] for j in chain]
    mv = [m.jnt_dofadr[m.joint(j).id] for j in chain]
    ranges = np.array([prof.joint_range(j) for j in chain])
    rng = np.random.default_rng(5)
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for _ in range(N_CONFIGS):
        theta = rng.uniform(ranges[:, 0], ranges[:, 1])
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        pos = rng.uniform(-2, 2, 3)
        # Pinocchio: free flyer [p, quat xyzw]; MuJoCo: [p, quat wxyz].
        qp = pin.neutral(model)
        qp[:3], qp[3:7] = pos, np.r_[quat[1:], quat[0]]
        qp[jq] = theta
        pin.computeJointJacobians(model, data, qp)
        pin.updateFramePlacements(model, data)
        d.qpos[:] = 0.0
        d.qpos[:3], d.qpos[3:7] = pos, quat
        d.qpos[mq] = theta
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        oMb = pin.SE3(d.xmat[torso].reshape(3, 3).copy(), d.xpos[torso].copy())
        T_pin = (oMb.inverse() * data.oMf[fid]).homogeneous
        T_mj = trans_inv(oMb.homogeneous) @ np.vstack(
            [np.c_[d.site_xmat[site].reshape(3, 3), d.site_xpos[site]], [0, 0, 0, 1]]
        )
        T = fk_space(M, S, theta)
        assert np.abs(T - T_pin).max() < TOL
        assert np.abs(T - T_mj).max() < TOL
        # Jacobians in the mixed frame, expressed in Σb axes.
        Jm = mixed_from_space(jacobian_space(S, theta), T[:3, 3])
        Rb = oMb.rotation
        J_lwa = _swap(pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED))[:, jv]
        assert np.abs(np.vstack([Rb @ Jm[:3], Rb @ Jm[3:]]) - J_lwa).max() < TOL
        mujoco.mj_jacSite(m, d, jacp, jacr, site)
        J_mj = np.vstack([jacr[:, mv], jacp[:, mv]])
        assert np.abs(np.vstack([Rb @ Jm[:3], Rb @ Jm[3:]]) - J_mj).max() < TOL
