"""Posture-policy files for tests: random weights of the real layout (no torch needed)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from services.posture.features import ARM_STATE_DIM, STATE_DIM, action_joints
from services.posture.policy import save_policy
from services.posture.swivel import SwivelFrame
from services.retarget.elbow import ArmGeometry
from shared.robot.pinocchio_model import RobotModel
from shared.rotations import matrix_to_quat
from shared.targets import SIDES


def random_weights(
    rng: np.random.Generator,
    hidden: int = 16,
    scale: float = 0.3,
    decoder: tuple[int, ...] | None = None,
    action: int = 3,
) -> dict[str, np.ndarray]:
    """Encoder 14-h-h-A and decoder (A + 14)-(decoder, default h-h)-6 per side, small random weights."""
    out = {}
    dec_hidden = (hidden, hidden) if decoder is None else decoder
    for side in SIDES:
        for net, dims in (
            ("enc", (STATE_DIM, hidden, hidden, action)),
            ("dec", (action + 14, *dec_hidden, ARM_STATE_DIM)),
        ):
            for k, (a, b) in enumerate(itertools.pairwise(dims)):
                out[f"{side}.{net}.W{k}"] = rng.normal(scale=scale, size=(a, b))
                out[f"{side}.{net}.b{k}"] = rng.normal(scale=scale, size=b)
    return out


def policy_meta(robot: RobotModel, threshold: float) -> dict:
    """Metadata of the real layout for ``robot`` (arms measured on it) with one gate threshold [m]."""
    rest = robot.frame_poses(robot.q_rest)
    arms = {}
    for s in SIDES:
        g = ArmGeometry.measure(robot, s, samples=100)
        arms[s] = {"centre": g.centre.tolist(), "upper": g.upper, "fore": g.fore}
    return {
        "robot": robot.profile.name,
        "arms": arms,
        "gate_threshold": dict.fromkeys(SIDES, threshold),
        "q_ref": {s: matrix_to_quat(rest[f"{s}_wrist"][1]).tolist() for s in SIDES},
        "action_joints": {s: [robot.joint_names[j] for j in action_joints(robot, s)] for s in SIDES},
    }


def write_random_policy(
    path: Path,
    robot: RobotModel,
    threshold: float = 1e3,
    seed: int = 0,
    posture_gain: float | None = None,
    elbow: dict[str, np.ndarray] | None = None,
    hidden: int = 16,
    scale: float = 0.3,
    decoder: tuple[int, ...] | None = None,
    swivel: dict[str, np.ndarray] | None = None,
) -> Path:
    """A loadable policy file with random weights (the gate open for threshold=1e3, shut for 0).

    Args:
        posture_gain: when given, a posture-kind policy (encoder output = shoulder posture) with this K.
        elbow: when given (side -> (3,) [m]), an elbow-kind policy whose encoder outputs that point for
            every state (output layer zero, bias the point); the decoder stays random.
        hidden, scale: hidden units and weight scale of the random layers.
        decoder: the decoder's hidden widths (default: two of ``hidden``).
        swivel: when given (side -> (2,) (cos, sin), any length), a swivel-kind policy whose encoder outputs
            that for every state; an empty dict: a swivel-kind policy with a random encoder.
    """
    meta = policy_meta(robot, threshold)
    rng = np.random.default_rng(seed)
    weights = random_weights(rng, hidden=hidden, scale=scale, decoder=decoder, action=2 if swivel is not None else 3)
    if posture_gain is not None:
        meta.update(action_kind="posture", posture_gain=posture_gain)
    if elbow is not None:
        meta.update(action_kind="elbow")
        for side, e in elbow.items():
            weights[f"{side}.enc.W2"] = np.zeros_like(weights[f"{side}.enc.W2"])
            weights[f"{side}.enc.b2"] = np.asarray(e, dtype=float)
    if swivel is not None:
        meta.update(action_kind="swivel")
        for side in SIDES:
            a = meta["arms"][side]
            a["swivel"] = SwivelFrame.for_arm(a["centre"], a["upper"], a["fore"], side).to_dict()
        for side, cs in swivel.items():
            weights[f"{side}.enc.W2"] = np.zeros_like(weights[f"{side}.enc.W2"])
            weights[f"{side}.enc.b2"] = np.asarray(cs, dtype=float)
    return save_policy(path, weights, meta)
