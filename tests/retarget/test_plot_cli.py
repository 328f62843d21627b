"""`mimic retarget-plot`: Fig. 6 and Fig. 7 from a real clip draw what the retargeter maps."""

from __future__ import annotations

import argparse
import json

import matplotlib.pyplot as plt
import numpy as np
import pytest

from services.cli import main as mimic_main
from services.ingest.clip import load_clip
from services.retarget.calibration import Calibration
from services.retarget.cli import add_retarget_options, config_from_args
from services.retarget.plots import _MAX_POINTS
from services.retarget.retargeter import Retargeter
from shared.messages import TARGET_NAMES


def _mapped(clip, argv, cal):
    """Operator bones H and mapped targets U, target -> (T, 3) [m], from a retargeter of our own."""
    p = argparse.ArgumentParser()
    add_retarget_options(p)
    r = Retargeter(config_from_args(p.parse_args(argv)), calibration=cal)
    H = {t: np.full((clip.n_frames, 3), np.nan) for t in TARGET_NAMES}
    U = {t: np.full((clip.n_frames, 3), np.nan) for t in TARGET_NAMES}
    for i in range(clip.n_frames):
        f = clip.frame(i, seq=i + 1)
        out = r.step(f)
        for t in TARGET_NAMES:
            if out is not None and out.targets[t].valid:
                H[t][i], U[t][i] = f.bones[r.bone_of[t]].p, out.targets[t].p
    return H, U, r


@pytest.mark.slow
def test_retarget_plot_draws_the_mapped_targets(bvh_clips, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MIMIC_CACHE_DIR", str(tmp_path / "cache"))
    figs = []
    monkeypatch.setattr(plt, "close", figs.append)  # keep the figures to read their data back
    path = min(bvh_clips, key=lambda p: p.stat().st_size)
    cal_file = tmp_path / "operator.json"
    argv = ["--samples", "3000"]
    rc = mimic_main(["retarget-plot", str(path), "--out", str(tmp_path / "fig"), *argv, "--calibrate", "clip",
                     "--write-calibration", str(cal_file)])  # fmt: skip
    assert rc == 0
    cal = Calibration.load(cal_file)
    assert cal.source == f"recording:{path.stem}"
    report = json.loads(capsys.readouterr().out)
    clip = load_clip(path)
    H, U, r = _mapped(clip, argv, cal)
    assert report["frames"] == clip.n_frames and report["mode"] == "bounded"
    assert sorted(report["files"]) == sorted(str(tmp_path / "fig" / n) for n in
                                             ("fig6_workspace.png", "fig7_left.png", "fig7_right.png"))  # fmt: skip
    for t, stats in report["targets"].items():
        assert stats["valid_frames"] == int(np.all(np.isfinite(U[t]), axis=1).sum()), t
        assert stats["clamped_frames"] == r.counts.get(f"clamped_{t}", 0), t
    by_title = {f._suptitle.get_text(): f for f in figs}
    assert len(by_title) == 3
    for side in ("left", "right"):
        (fig7,) = [f for title, f in by_title.items() if f"{side} arm" in title]
        axes = np.array(fig7.axes).reshape(2, 3)
        for row, joint in enumerate(("wrist", "elbow")):
            t = f"{side}_{joint}"
            for k in range(3):
                operator, robot = axes[row, k].get_lines()
                np.testing.assert_array_equal(robot.get_xdata(), clip.times)
                np.testing.assert_allclose(robot.get_ydata(), U[t][:, k], atol=1e-12)
                np.testing.assert_allclose(operator.get_ydata(), H[t][:, k], atol=1e-12)
    (fig6,) = [f for title, f in by_title.items() if title.startswith("Fig. 6")]
    ws = r.workspace
    clouds = 0
    for ax, joint in zip(fig6.axes, ("wrist", "wrist", "elbow")):
        for coll in ax.collections:
            label = coll.get_label()
            if not label.startswith("robot"):
                continue
            t = f"{label.split()[1]}_{joint}"
            pts = np.column_stack(coll._offsets3d)
            # the restricted workspace: inside the box, subsampled to at most _MAX_POINTS
            assert 100 < len(pts) <= _MAX_POINTS, (label, len(pts))
            assert np.all((pts >= ws.lower[t] - 1e-12) & (pts <= ws.upper[t] + 1e-12)), label
            clouds += 1
    assert clouds == 6


def test_retarget_plot_bad_input_is_a_clear_error(tmp_path, caplog):
    bad = tmp_path / "x.bvh"
    bad.write_text("not a bvh")
    assert mimic_main(["retarget-plot", str(bad), "--out", str(tmp_path)]) == 2
    assert mimic_main(["retarget-plot", str(tmp_path / "none.bvh"), "--out", str(tmp_path)]) == 2
