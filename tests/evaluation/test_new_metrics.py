"""Issue-12 evaluation figures with known answers: p99, stuck_s, jerk, the IK reachability check,
self-collision clearance, the mink peer, and the eval's skeleton-map / service-default handling."""

from __future__ import annotations

import argparse
import re
import sys

import numpy as np
import pytest

from services.evaluation.cli import _settings, add_arguments, evaluate
from services.evaluation.collisions import SelfCollision
from services.evaluation.metrics import (
    _stats,
    acceleration_violations,
    jerk_rms,
    stuck_seconds,
    summarise,
    trace_metrics,
    waist_speed_rms,
)
from services.evaluation.reachability import IK_TOL, ArmIk, check_targets
from services.evaluation.runner import load_and_retarget, run_algorithm
from services.retarget.retargeter import RetargetConfig
from shared.messages import TARGET_NAMES, Target
from tests.evaluation.test_metrics import K, synthetic_trace
from tests.evaluation.test_runner import DURATION, RATE, fk_targets


def test_p99_is_the_99th_percentile():
    v = np.arange(1001, dtype=float)  # 0..1000
    s = _stats(v)
    assert s["p99"] == pytest.approx(990.0) and s["max"] == 1000.0 and s["mean"] == pytest.approx(500.0)


def test_stuck_counts_the_longest_reachable_miss(robot17):
    tr = synthetic_trace(robot17, {})
    tr.kin_p["left_wrist"][40:90] += np.array([0.03, 0.0, 0.0])  # 3 cm off for 50 ticks
    tr.kin_p["right_wrist"][100:120] += np.array([0.0, 0.05, 0.0])  # 5 cm off for 20 ticks
    tr.kin_p["left_wrist"][150:160] += np.array([0.01, 0.0, 0.0])  # 1 cm: under the 2 cm threshold
    ok = {"left": np.ones(K, bool), "right": np.ones(K, bool)}
    assert stuck_seconds(tr, ok) == pytest.approx(50 * tr.dt)
    ok["left"][:] = False  # the left targets were unreachable: its miss does not count
    assert stuck_seconds(tr, ok) == pytest.approx(20 * tr.dt)


def test_jerk_of_a_cubic_is_its_constant_third_derivative(robot17):
    tr = synthetic_trace(robot17, {})
    t = np.arange(K) * tr.dt
    tr.q = np.tile(robot17.q_rest, (K, 1))
    tr.q[:, 0] += 5.0 * t**3 / 6.0  # jerk 5 rad/s^3 on one joint of n
    n = tr.q.shape[1]
    assert jerk_rms(tr) == pytest.approx(5.0 / np.sqrt(n), rel=1e-6)


def test_waist_speed_is_the_rms_over_ticks_and_waist_joints(robot17, robot14):
    tr = synthetic_trace(robot17, {})
    waist = [robot17.joint_names.index(j) for j in robot17.profile.waist]
    tr.qd[:, waist[0]] = 3.0  # one of three waist joints at 3 rad/s throughout
    tr.qd[:, -1] = 8.0  # an arm joint does not count
    assert waist_speed_rms(tr, robot17) == pytest.approx(3.0 / np.sqrt(3.0))
    assert waist_speed_rms(synthetic_trace(robot14, {}), robot14) is None  # no waist in the model


def test_ik_check_reaches_forward_kinematics_and_rejects_far_points(robot14):
    rng = np.random.default_rng(3)
    ik = ArmIk(robot14, "left")
    for q in robot14.random_configurations(5, rng):
        p = robot14.frame_poses(q, names=("left_wrist", "left_elbow"))
        res, _ = ik.solve(p["left_wrist"][0])
        assert res <= IK_TOL
        # the pair the posture makes, from a start 0.2 rad off it (the stream check warm-starts likewise)
        start = robot14.clip(q + 0.2 * rng.uniform(-1.0, 1.0, q.shape))
        res, _ = ik.solve(p["left_wrist"][0], p["left_elbow"][0], q0=start)
        assert res <= 0.01
    far = ik.robot.frame_poses(robot14.q_rest, names=("left_wrist",))["left_wrist"][0] + np.array([0.0, 0.0, 1.0])
    res, _ = ik.solve(far)
    assert res > 0.2  # 1 m above the hanging hand is ~0.65 m from the shoulder; the arm reaches 0.38 m


def test_reachability_report_counts_every_valid_target(robot17, robot14):
    targets = fk_targets(robot14, np.arange(0.0, 0.3, 0.05))
    # one frame with the left wrist 1 m away, one with it invalid (not counted)
    bad = targets[2].targets["left_wrist"]
    targets[2].targets["left_wrist"] = Target(bad.p + np.array([1.0, 0, 0]), bad.q, bad.v, bad.w, True, True)
    t5 = targets[5].targets["left_wrist"]
    targets[5].targets["left_wrist"] = Target(t5.p, t5.q, t5.v, t5.w, False, True)
    rep = check_targets(robot14, targets)
    assert rep.fraction() == pytest.approx(10 / 11)  # 12 wrist targets, 1 invalid, 1 out of reach
    assert not rep.reachable()["left"][2] and rep.reachable()["left"][5]
    tr = run_algorithm(robot17, targets, "hqp-nullspace", qp="daqp", collisions=False)
    m = trace_metrics(tr, robot17, report=rep)
    assert m["reachable_fraction"] == pytest.approx(10 / 11)
    # the miss spans the unreachable frame (0.05 s, not counted) and the way back (counted)
    everything = {s: np.ones(len(tr.t), bool) for s in ("left", "right")}
    assert stuck_seconds(tr, everything) - m["stuck_s"] == pytest.approx(0.05, abs=0.006)


def test_clearance_is_positive_at_rest_and_negative_with_a_hand_in_the_torso(robot17):
    sc = SelfCollision(robot17.profile, robot17.joint_names)
    rest = sc.clearance(robot17.q_rest)
    assert 0.01 < rest < 0.2
    q = robot17.q_rest.copy()
    j = {n: i for i, n in enumerate(robot17.joint_names)}
    # left upper arm rolled in against the body, elbow folded: the forearm goes into the torso
    q[j["left_shoulder_pitch_joint"]] = 0.0
    q[j["left_shoulder_roll_joint"]] = -0.6
    q[j["left_shoulder_yaw_joint"]] = 0.0
    q[j["left_elbow_joint"]] = 2.0
    assert sc.clearance(robot17.clip(q)) < -0.02


def test_mink_peer_tracks_reachable_targets(robot17):
    targets = fk_targets(robot17, np.arange(0.0, DURATION, 1.0 / RATE))
    tr = run_algorithm(robot17, targets, "mink", collisions=False)
    m = trace_metrics(tr, robot17)
    assert m["wrist_err_cm"]["mean"] < 0.5, m["wrist_err_cm"]
    assert m["limit_violations"] == 0
    assert tr.q.shape[1] == robot17.nq and set(np.unique(tr.status)) == {"ok"}


def test_mink_peer_moves_only_the_joints_the_run_controls(robot14):
    """An arms-only run (``mimic eval --no-waist``): mink's model still has the waist and legs, which must stay where
    the robot holds them; a free waist put mink's arms where the 14-joint kinematics did not see them (8.5 cm wrist
    error over the real clips, session 21)."""
    from services.evaluation.mink_peer import MinkPeer

    peer = MinkPeer(robot14)
    q0 = peer.configuration.q.copy()
    targets = fk_targets(robot14, np.arange(0.0, DURATION, 1.0 / RATE))
    for k, tt in enumerate(targets):
        for i in range(5):  # 500 Hz between 100 Hz targets
            peer.step(tt if i == 0 else None, None, k / RATE + i * peer.dt)
    others = np.setdiff1d(np.arange(len(q0)), peer.qpos_idx)
    assert len(others) > 3  # waist and legs
    np.testing.assert_allclose(peer.configuration.q[others], q0[others], atol=1e-9)  # QP round-off: 2e-16 rad
    assert np.abs(peer.configuration.q[peer.qpos_idx] - q0[peer.qpos_idx]).max() > 0.1  # the arms did move


def test_mink_peer_runs_when_a_target_is_never_valid(robot17):
    """A marker set without the left elbow (as on one of the C3D clips): mink gets the targets there are
    (it raises on a task whose target was never set) and still tracks them."""
    from dataclasses import replace

    targets = fk_targets(robot17, np.arange(0.0, DURATION, 1.0 / RATE))
    no_elbow = [replace(tt, targets=tt.targets | {"left_elbow": replace(tt.targets["left_elbow"], valid=False)})
                for tt in targets]  # fmt: skip
    tr = run_algorithm(robot17, no_elbow, "mink", collisions=False)
    m = trace_metrics(tr, robot17)
    assert m["wrist_err_cm"]["mean"] < 0.5 and set(np.unique(tr.status)) == {"ok"}, m["wrist_err_cm"]


def test_acceleration_violations_count_velocity_steps_above_amax_dt(robot17):
    tr = synthetic_trace(robot17, {})
    dt = float(tr.t[1] - tr.t[0])
    a = robot17.amax
    tr.qd[10:, 0] = 0.999 * a[0] * dt  # one step just inside the limit: not counted
    tr.qd[50:, 1] = 1.01 * a[1] * dt  # one step just past it on another joint
    tr.qd[80, 2], tr.qd[81, 2] = -2.0 * a[2] * dt, 0.0  # a spike: out past the limit and back
    assert acceleration_violations(tr, robot17) == 3
    assert trace_metrics(tr, robot17)["acceleration_violations"] == 3


def test_mink_limited_keeps_our_acceleration_limit_where_mink_does_not(robot17):
    """Targets that jump 5 cm (a marker swap): mink steps its joints at once, past a_max; the limited peer
    brakes into the same box as our solvers and still reaches the targets."""
    targets = fk_targets(robot17, np.arange(0.0, DURATION, 1.0 / RATE), {"left_wrist": np.array([0.05, 0.0, 0.0])})
    raw = trace_metrics(run_algorithm(robot17, targets, "mink", collisions=False), robot17)
    limited_tr = run_algorithm(robot17, targets, "mink-limited", collisions=False)
    limited = trace_metrics(limited_tr, robot17)
    assert raw["acceleration_violations"] > 0
    assert limited["acceleration_violations"] == 0 and limited["limit_violations"] == 0
    assert limited["wrist_err_cm"]["mean"] < 2.0 * raw["wrist_err_cm"]["mean"] + 0.1, (limited, raw)
    assert set(np.unique(limited_tr.status)) == {"ok"}


def test_summary_has_p99_of_the_worst_clip_and_sums_collisions(robot17):
    a = trace_metrics(synthetic_trace(robot17, {n: np.array([0.01, 0, 0]) for n in TARGET_NAMES}), robot17)
    b = trace_metrics(synthetic_trace(robot17, {n: np.array([0.04, 0, 0]) for n in TARGET_NAMES}), robot17)
    a["self_collisions"], b["self_collisions"] = 2, 3
    a["stuck_s"], b["stuck_s"] = 0.1, 0.4
    s = summarise([{"clip": "a", "frames": 30, "algos": {"x": a}}, {"clip": "b", "frames": 10, "algos": {"x": b}}])
    assert s["x"]["wrist_err_cm"]["p99"] == pytest.approx(4.0)
    assert s["x"]["self_collisions"] == 5 and s["x"]["stuck_s"] == pytest.approx(0.4)


def _args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(argv)


def test_eval_defaults_are_the_service_retarget_settings(tmp_path):
    args = _args(["x.bvh", "--json", str(tmp_path / "o.json")])
    cfg = RetargetConfig()
    assert args.velocity_tau == cfg.velocity_tau and args.mapping == cfg.mode
    retarget = _settings(args)[3]  # what the retargeter is built with
    assert retarget["elbow_placement"] == cfg.elbow_placement
    assert retarget["orientation_reference"] == cfg.orientation_reference and retarget["mode"] == cfg.mode
    assert retarget["consistent_targets"] == cfg.consistent_targets
    assert _settings(_args(["x.bvh", "--json", "o.json", "--consistent-targets"]))[3]["consistent_targets"] is True
    assert retarget["wrist_range"] == cfg.wrist_range and retarget["forearm_blend"] == cfg.forearm_blend
    for flag in ("wrist_range", "forearm_blend"):
        on = _settings(_args(["x.bvh", "--json", "o.json", f"--{flag.replace('_', '-')}"]))[3]
        off = _settings(_args(["x.bvh", "--json", "o.json", f"--no-{flag.replace('_', '-')}"]))[3]
        assert on[flag] is True and off[flag] is False
    # self-collision and the lock-up recovery: the solver's defaults unless --self-collision / --recovery on|off
    # say otherwise
    assert "self_collision" not in _settings(args)[1] and "recovery" not in _settings(args)[1]
    for flag in ("on", "off"):
        solver = _settings(_args(["x.bvh", "--json", "o.json", "--self-collision", flag]))[1]
        assert solver["self_collision"] is (flag == "on")
        solver = _settings(_args(["x.bvh", "--json", "o.json", "--recovery", flag]))[1]
        assert solver["recovery"] is (flag == "on")


def _renamed_rig(src, dst) -> None:
    """A real Bandai clip with every joint renamed (no built-in map fits it)."""
    text = src.read_text()
    text = re.sub(r"\b(\w+)_L\b", r"Sin\1", text)
    text = re.sub(r"\b(\w+)_R\b", r"Dex\1", text)
    dst.write_text(text.replace("Hips", "Pelvis0"))


def test_unknown_rig_is_a_one_line_error_and_a_skeleton_map_fixes_it(bvh_clips, tmp_path, robot17, caplog):
    src = next(p for p in bvh_clips if "raise-up-both-hands_normal" in p.name)
    clip = tmp_path / "rig.bvh"
    _renamed_rig(src, clip)
    args = _args([str(clip), "--algos", "hqp-nullspace", "--no-sim", "--json", str(tmp_path / "o.json")])
    with pytest.raises(SystemExit) as exc:
        evaluate(args)
    msg = str(exc.value)
    # The clip is skipped with one line naming the fix; with no clip left the run ends in one line.
    assert msg.startswith("mimic eval:") and "no clip could be evaluated" in msg and "Traceback" not in msg
    skipped = [r.getMessage() for r in caplog.records if "skipping" in r.getMessage()]
    assert len(skipped) == 1 and "--skeleton-map" in skipped[0] and "\n" not in skipped[0]
    smap = tmp_path / "map.toml"
    bones = {"pelvis": "Pelvis0", "spine": "Spine", "chest": "Chest", "neck": "Neck", "head": "Head"}
    for side, pre in (("left", "Sin"), ("right", "Dex")):
        bones |= {
            f"{side}_clavicle": f"{pre}Shoulder",
            f"{side}_shoulder": f"{pre}UpperArm",
            f"{side}_elbow": f"{pre}LowerArm",
            f"{side}_wrist": f"{pre}Hand",
            f"{side}_hand": f"{pre}Hand/end",
        }
    text = 'name = "renamed"\n[bones]\n' + "".join(f'{k} = "{v}"\n' for k, v in bones.items())
    smap.write_text(text + '[hips]\nleft = "SinUpperLeg"\nright = "DexUpperLeg"\n')  # as the built-in map
    _, mapped = load_and_retarget(clip, robot17, retarget={}, skeleton_map=smap)
    _, original = load_and_retarget(src, robot17, retarget={})
    assert len(mapped) == len(original)
    for a, b in zip(mapped[::10], original[::10]):
        for n in TARGET_NAMES:
            np.testing.assert_allclose(a.targets[n].p, b.targets[n].p, atol=1e-9)


def test_missing_mink_is_a_one_line_error(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "mink", None)  # import mink -> ImportError
    args = _args(["x.bvh", "--algos", "hqp-nullspace,mink", "--json", str(tmp_path / "o.json")])
    with pytest.raises(SystemExit) as exc:
        evaluate(args)
    assert "mink" in str(exc.value) and "\n" not in str(exc.value)


def test_frame_errors_compare_the_robot_with_each_frame_at_its_own_instant(robot17):
    """Reachable FK targets with exact velocities: the robot is at every frame when it arrives
    (frame errors ~0, positions and hand orientations). The same frames with velocities that
    mispredict between them (doubled, or none): the robot lags the frames and the frame error says
    so, however the reference is built."""
    from dataclasses import replace

    targets = fk_targets(robot17, np.arange(0.0, DURATION, 1.0 / RATE))
    exact = trace_metrics(run_algorithm(robot17, targets, "hqp-nullspace", qp="daqp"), robot17)
    assert exact["wrist_frame_err_cm"]["max"] < 0.02, exact["wrist_frame_err_cm"]
    assert exact["wrist_rot_frame_err_deg"]["max"] < 0.05, exact["wrist_rot_frame_err_deg"]  # measured 0.014 deg
    for k in (0.0, 2.0):
        off = [replace(tt, targets={n: replace(t, v=k * t.v, w=k * t.w) for n, t in tt.targets.items()})
               for tt in targets]  # fmt: skip
        m = trace_metrics(run_algorithm(robot17, off, "hqp-nullspace", qp="daqp"), robot17)
        assert m["wrist_frame_err_cm"]["mean"] > 20 * exact["wrist_frame_err_cm"]["mean"], (k, m["wrist_frame_err_cm"])
        assert m["elbow_frame_err_cm"]["mean"] > 10 * exact["elbow_frame_err_cm"]["mean"], (k, m["elbow_frame_err_cm"])
        assert m["wrist_rot_frame_err_deg"]["mean"] > 0.5, (k, m["wrist_rot_frame_err_deg"])  # measured 0.71 deg
