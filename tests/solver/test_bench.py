"""`mimic bench solvers` report shape on a short run (figures themselves come from the command, not tests)."""

from __future__ import annotations

import argparse
import json

import numpy as np

from services.solver import bench
from shared.robot.pinocchio_model import build_robot_model


def test_bench_report_has_the_agreed_shape(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    out = tmp_path / "bench.json"
    args = parser.parse_args(
        ["--json", str(out), "--seconds", "0.3", "--algos", "hqp-nullspace", "wqp", "--warmup", "10"]
    )
    assert bench.main(args) == 0
    report = json.loads(out.read_text())
    assert json.loads(capsys.readouterr().out) == report
    combos = {(r["algo"], r["qp"], r["dof"]) for r in report["results"]}
    assert combos == {(a, q, d) for a in ("hqp-nullspace", "wqp") for q in ("piqp", "daqp") for d in (14, 17)}
    for r in report["results"]:
        assert 0 < r["tick_ms"]["p50"] <= r["tick_ms"]["p99"]
        assert r["ticks"] > 100
        assert sum(r["statuses"].values()) == r["ticks"]  # counted after the warm-up, like the times
        assert r["counts"]["failed"] == 0 and r["counts"]["safety_clamps"] == 0
    mink = report["mink"]
    assert mink["dof"] >= 17 and 0 < mink["tick_ms"]["p50"] <= mink["tick_ms"]["p99"]
    # The goal block and the mink ratio are read off the hqp-nullspace 17-DoF row of this same run.
    goal = report["goal"]
    row = next(r for r in report["results"] if (r["algo"], r["dof"], r["qp"]) == ("hqp-nullspace", 17, goal["qp"]))
    assert (goal["p50_ms"], goal["p99_ms"]) == (row["tick_ms"]["p50"], row["tick_ms"]["p99"])
    assert goal["met"] == (goal["p50_ms"] <= goal["p50_goal_ms"] and goal["p99_ms"] <= goal["p99_goal_ms"])
    assert mink["ratio_p50_vs_hqp_nullspace"] == round(mink["tick_ms"]["p50"] / row["tick_ms"]["p50"], 2)


def test_npz_targets_round_trip(tmp_path):
    robot = build_robot_model()
    frames = bench.synthetic_targets(robot, 0.1)
    arrays = {"t": np.array([f.hdr.stamp for f in frames])}
    for name in frames[0].targets:
        for key in ("p", "q", "v", "w"):
            arrays[f"{name}_{key}"] = np.array([getattr(f.targets[name], key) for f in frames])
    path = tmp_path / "targets.npz"
    np.savez(path, **arrays)
    loaded = bench.load_targets(path)
    assert len(loaded) == len(frames)
    np.testing.assert_allclose(loaded[3].targets["left_wrist"].p, frames[3].targets["left_wrist"].p)
    np.testing.assert_allclose(loaded[3].targets["right_elbow"].v, frames[3].targets["right_elbow"].v)


def test_self_collision_flag_reaches_the_solver(tmp_path):
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    common = ["--seconds", "0.2", "--algos", "hqp-nullspace", "--qps", "daqp", "--dofs", "17"]
    common += ["--warmup", "10", "--mink-solver", "none"]
    for flag in ("on", "off"):
        out = tmp_path / f"{flag}.json"
        assert bench.main(parser.parse_args([*common, "--json", str(out), "--self-collision", flag])) == 0
        (row,) = json.loads(out.read_text())["results"]
        assert row["self_collision"] is (flag == "on")
