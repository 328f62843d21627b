"""Evaluation metrics on synthetic traces with known answers (no solver involved)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.evaluation.metrics import (
    REACHABLE_TOL,
    limit_violations,
    position_errors,
    reachable_mask,
    rotation_errors,
    rotation_ok,
    summarise,
    trace_metrics,
)
from services.evaluation.runner import Trace
from shared.robot.pinocchio_model import build_robot_model
from shared.targets import ELBOWS, TARGET_NAMES, WRISTS

K = 200


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def synthetic_trace(
    robot, offsets: dict[str, np.ndarray], rot_offset: np.ndarray | None = None, seed: int = 0
) -> Trace:
    """A trace whose achieved poses are the reference plus known constant offsets.

    Args:
        offsets: target -> (3,) achieved minus reference [m].
        rot_offset: (3,) rotation vector [rad]: achieved wrist = reference @ exp(rot_offset).
    """
    rng = np.random.default_rng(seed)
    ref_p = {n: rng.normal(scale=0.2, size=(K, 3)) for n in TARGET_NAMES}
    ref_R = {n: np.array([pin.exp3(rng.normal(size=3)) for _ in range(K)]) for n in WRISTS}
    dR = pin.exp3(np.zeros(3) if rot_offset is None else rot_offset)
    q = np.tile(robot.q_rest, (K, 1))
    return Trace(
        algo="synthetic",
        t=np.arange(K) / 500.0,
        seq=np.arange(K) // 16,
        ref_p=ref_p,
        ref_R=ref_R,
        ref_ok={n: np.ones(K, bool) for n in TARGET_NAMES},
        kin_p={n: ref_p[n] + offsets.get(n, np.zeros(3)) for n in TARGET_NAMES},
        kin_R={n: ref_R[n] @ dR for n in WRISTS},
        q=q,
        qd=np.zeros_like(q),
        solve_ms=np.linspace(0.1, 2.0, K),
        status=np.array(["ok"] * K),
        res1=np.zeros(K),
        sim_p={n: ref_p[n] + 2.0 * offsets.get(n, np.zeros(3)) for n in TARGET_NAMES},
        sim_R={n: ref_R[n] @ dR @ dR for n in WRISTS},  # the sim turned twice as far off
    )


def test_exact_tracking_gives_zero_errors(robot):
    m = trace_metrics(synthetic_trace(robot, {}), robot)
    for key in ("wrist_err_cm", "elbow_err_cm", "wrist_err_cm_sim", "elbow_err_cm_sim"):
        assert m[key]["mean"] == pytest.approx(0.0, abs=1e-12) and m[key]["max"] == pytest.approx(0.0, abs=1e-12)
    assert m["wrist_rot_err_deg"]["max"] == pytest.approx(0.0, abs=1e-5)
    assert m["wrist_rot_err_deg_sim"]["max"] == pytest.approx(0.0, abs=1e-5)
    assert m["limit_violations"] == 0


def test_constant_offsets_are_reported_exactly(robot):
    offs = {"left_wrist": np.array([0.003, -0.004, 0.0]), "right_wrist": np.array([0.0, 0.0, 0.005])}
    offs |= {e: np.array([0.0, 0.06, 0.08]) for e in ELBOWS}
    tr = synthetic_trace(robot, offs, rot_offset=np.radians([0.0, 0.0, 7.5]))
    m = trace_metrics(tr, robot)
    assert m["wrist_err_cm"]["mean"] == pytest.approx(0.5, rel=1e-9)  # both wrists 5 mm off
    assert m["wrist_err_cm"]["max"] == pytest.approx(0.5, rel=1e-9)
    assert m["elbow_err_cm"]["mean"] == pytest.approx(10.0, rel=1e-9)
    assert m["elbow_err_cm_sim"]["mean"] == pytest.approx(20.0, rel=1e-9)  # sim made twice the offset
    assert m["wrist_rot_err_deg"]["mean"] == pytest.approx(7.5, rel=1e-6)
    assert m["wrist_rot_err_deg_sim"]["mean"] == pytest.approx(15.0, rel=1e-6)
    assert m["solve_ms"]["p50"] == pytest.approx(np.median(tr.solve_ms))


def test_invalid_references_and_mask_are_left_out(robot):
    tr = synthetic_trace(robot, {"left_wrist": np.array([0.01, 0.0, 0.0])})
    tr.kin_p["left_wrist"][:50] += 1.0  # 1 m off, but only where the reference is invalid
    tr.ref_ok["left_wrist"][:50] = False
    e = position_errors(tr.ref_p, tr.kin_p, tr.ref_ok, ("left_wrist",))
    assert len(e) == K - 50 and np.allclose(e, 0.01)
    mask = np.zeros(K, bool)
    mask[100:] = True
    e = position_errors(tr.ref_p, tr.kin_p, tr.ref_ok, ("left_wrist",), mask)
    assert len(e) == K - 100
    assert len(rotation_errors(tr.ref_R, tr.kin_R, tr.ref_ok, mask)) == 2 * (K - 100)


def test_wrists_without_an_orientation_to_track_have_no_rotation_error(robot):
    # A marker-only source's wrists carry no rotation (use_rotation False): 10 deg off there is not an error.
    tr = synthetic_trace(robot, {}, rot_offset=np.array([0.0, 0.0, np.radians(10.0)]))
    tr.ref_rot = {n: np.arange(K) >= 100 for n in WRISTS}
    m = trace_metrics(tr, robot)
    assert m["wrist_rot_err_deg"]["mean"] == pytest.approx(10.0, rel=1e-6)
    assert len(rotation_errors(tr.ref_R, tr.kin_R, rotation_ok(tr))) == 2 * (K - 100)
    tr.ref_rot = {n: np.zeros(K, bool) for n in WRISTS}
    assert trace_metrics(tr, robot)["wrist_rot_err_deg"]["mean"] is None


def test_reachable_mask_follows_level_one_residual(robot):
    tr = synthetic_trace(robot, {})
    tr.res1 = np.where(np.arange(K) % 4 == 0, 10 * REACHABLE_TOL, 0.1 * REACHABLE_TOL)
    tr.res1[3] = np.nan  # no residual: not reachable
    mask = reachable_mask(tr)
    assert mask.sum() == K - K // 4 - 1
    offs = {"left_wrist": np.array([0.0, 0.002, 0.0])}
    tr2 = synthetic_trace(robot, offs)
    tr2.kin_p["left_wrist"][~mask] += 0.5  # big errors only on the unreachable ticks
    m = trace_metrics(tr2, robot, mask)
    assert m["reachable_fraction"] == pytest.approx(mask.mean())
    assert m["wrist_err_cm_reachable"]["max"] == pytest.approx(0.2, rel=1e-9)
    assert m["wrist_err_cm"]["max"] > 40.0


def test_limit_violations_are_counted_per_joint_and_tick(robot):
    tr = synthetic_trace(robot, {})
    tr.q[10, 0] = robot.upper[0] + 0.01
    tr.q[11, 3] = robot.lower[3] - 0.01
    tr.qd[12, 5] = robot.vmax[5] * 1.5
    tr.q[13, 4] = robot.upper[4]  # on the limit is allowed
    assert limit_violations(tr, robot) == 3


def test_summary_weights_means_by_frames_and_takes_max_of_max(robot):
    a = trace_metrics(synthetic_trace(robot, {n: np.array([0.01, 0, 0]) for n in TARGET_NAMES}), robot)
    b = trace_metrics(synthetic_trace(robot, {n: np.array([0.04, 0, 0]) for n in TARGET_NAMES}), robot)
    s = summarise([{"clip": "a", "frames": 30, "algos": {"x": a}}, {"clip": "b", "frames": 10, "algos": {"x": b}}])
    assert s["x"]["wrist_err_cm"]["mean"] == pytest.approx((30 * 1.0 + 10 * 4.0) / 40)
    assert s["x"]["elbow_err_cm"]["max"] == pytest.approx(4.0)
    assert isinstance(s["x"]["limit_violations"], int)


@pytest.mark.parametrize("first", [True, False])
def test_summary_takes_a_key_only_some_clips_have_over_those_clips(robot, first):
    """``recoveries`` is only in the metrics of a run whose solver started one: the summary must neither fail
    (it raised KeyError when the first clip had the key) nor drop it (it did when a later clip had it)."""
    a = trace_metrics(synthetic_trace(robot, {n: np.array([0.01, 0, 0]) for n in TARGET_NAMES}), robot)
    b = trace_metrics(synthetic_trace(robot, {n: np.array([0.04, 0, 0]) for n in TARGET_NAMES}), robot)
    b["recoveries"] = 3
    b["elbow_vs_policy_cm"] = {"mean": 2.0, "p99": 2.5, "max": 3.0}
    clips = [{"clip": "a", "frames": 30, "algos": {"x": a}}, {"clip": "b", "frames": 10, "algos": {"x": b}}]
    s = summarise(clips[::-1] if first else clips)["x"]
    assert s["recoveries"] == 3 and isinstance(s["recoveries"], int)
    assert s["elbow_vs_policy_cm"] == {"mean": 2.0, "p99": 2.5, "max": 3.0}
    assert s["wrist_err_cm"]["mean"] == pytest.approx((30 * 1.0 + 10 * 4.0) / 40)
