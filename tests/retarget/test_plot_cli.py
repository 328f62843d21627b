"""`mimic retarget-plot`: Fig. 6 and Fig. 7 PNGs and the JSON report from a real clip."""

from __future__ import annotations

import json

import pytest

from services.cli import main as mimic_main
from services.retarget.calibration import Calibration

pytest.importorskip("services.ingest.clip", reason="ingest service (services/ingest/clip.py) not available")


@pytest.mark.slow
def test_retarget_plot_writes_figures_and_report(bvh_clips, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MIMIC_CACHE_DIR", str(tmp_path / "cache"))
    clip = min(bvh_clips, key=lambda p: p.stat().st_size)
    cal_file = tmp_path / "operator.json"
    argv = ["retarget-plot", str(clip), "--out", str(tmp_path / "fig"), "--samples", "3000"]
    rc = mimic_main([*argv, "--calibrate", "clip", "--write-calibration", str(cal_file)])
    assert rc == 0
    assert Calibration.load(cal_file).source == f"recording:{clip.stem}"
    report = json.loads(capsys.readouterr().out)
    for name in ("fig6_workspace.png", "fig7_left.png", "fig7_right.png"):
        png = tmp_path / "fig" / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    assert report["frames"] > 30 and report["mode"] == "bounded"
    for t, stats in report["targets"].items():
        assert stats["valid_frames"] == report["frames"], t
        assert stats["inside_box"] == 1.0, t


def test_retarget_plot_bad_input_is_a_clear_error(tmp_path, caplog):
    bad = tmp_path / "x.bvh"
    bad.write_text("not a bvh")
    assert mimic_main(["retarget-plot", str(bad), "--out", str(tmp_path)]) == 2
    assert mimic_main(["retarget-plot", str(tmp_path / "none.bvh"), "--out", str(tmp_path)]) == 2
