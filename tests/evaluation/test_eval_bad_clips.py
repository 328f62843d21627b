"""`mimic eval` on a folder with one bad and one unknown-rig clip: one line each, the rest evaluated."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from services.ingest import generate_demo_clips
from shared.paths import REPO_ROOT

pytestmark = pytest.mark.integration


def test_eval_skips_bad_clips_in_one_line_and_evaluates_the_rest(tmp_path):
    good = generate_demo_clips(tmp_path / "clips")[1]  # the ellipse: the shorter of the project's motions
    (tmp_path / "clips" / "box_lift.bvh").unlink()
    broken = tmp_path / "clips" / "broken.bvh"
    broken.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    # A rig whose arm joints have names no built-in map knows.
    alien = tmp_path / "clips" / "alien.bvh"
    alien.write_text(good.read_text().replace("LeftArm", "Lupper").replace("RightArm", "Rupper"))
    out = tmp_path / "eval.json"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "eval",
            *sorted(map(str, (tmp_path / "clips").glob("*.bvh"))),
            "--algos",
            "hqp-nullspace",
            "--no-sim",
            "--json",
            str(out),
        ],
        cwd=REPO_ROOT,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    errors = [ln for ln in run.stderr.splitlines() if " E " in ln]
    assert len(errors) == 2 and all("skipping" in e for e in errors), errors
    result = json.loads(out.read_text())
    assert [c["clip"] for c in result["clips"]] == [good.stem]
    assert sorted(s["clip"] for s in result["skipped"]) == sorted([str(alien), str(broken)])
    assert "hqp-nullspace" in result["clips"][0]["algos"]


def test_a_run_that_fails_is_recorded_and_the_other_runs_are_kept(tmp_path, monkeypatch, capfd):
    """One (clip, algo) run raising must cost only that run: the JSON keeps the others, exit 1."""
    import services.evaluation.cli as eval_cli
    from services.cli import main as mimic

    clip = generate_demo_clips(tmp_path / "clips")[1]
    real = eval_cli.run_algorithm

    def wqp_breaks(robot, targets, algo, **kw):
        if algo == "wqp":  # stands in for a solver bug: nothing real fails on demand
            raise FloatingPointError("wqp diverged")
        return real(robot, targets, algo, **kw)

    monkeypatch.setattr(eval_cli, "run_algorithm", wqp_breaks)
    out = tmp_path / "eval.json"
    code = mimic(["eval", str(clip), "--algos", "hqp-nullspace,wqp", "--no-sim", "--json", str(out)])
    assert code == 1
    result = json.loads(out.read_text())
    assert list(result["clips"][0]["algos"]) == ["hqp-nullspace"]
    assert result["failed"] == [{"clip": clip.stem, "algo": "wqp", "error": "FloatingPointError: wqp diverged"}]
    assert "hqp-nullspace" in result["summary"]
    errors = [ln for ln in capfd.readouterr().err.splitlines() if " E " in ln]
    assert len(errors) == 2 and f"wqp on {clip.stem} failed: FloatingPointError: wqp diverged" in errors[0], errors
