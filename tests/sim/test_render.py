"""Offscreen rendering: real frames where a GL backend exists, a clear skip where none does.

MuJoCo binds its GL backend at import, so each case runs in a fresh interpreter.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from shared.paths import REPO_ROOT

REPO = REPO_ROOT
SCRIPT = """
import json, sys
from pathlib import Path
import numpy as np
from services.sim.render import open_renderer
from services.sim.sim_core import SimCore
core = SimCore()
out = Path(sys.argv[1])
writer, why = open_renderer(core.robot.model, out, fps=10, width=160, height=120, fmt="png")
if writer is None:
    print(json.dumps({"ok": False, "why": why}))
    sys.exit(0)
for _ in range(3):
    writer.maybe_render(core.robot.data)
    core.step_physics(100)
writer.close()
from PIL import Image
imgs = [np.asarray(Image.open(p)) for p in sorted(out.glob("frame_*.png"))]
print(json.dumps({"ok": True, "frames": len(imgs), "shape": list(imgs[0].shape), "std": float(imgs[0].std())}))
"""


def _run(gl: str, out: Path) -> dict:
    env = {**os.environ, "MUJOCO_GL": gl, "LP_NUM_THREADS": "1"}
    env.pop("DISPLAY", None)
    res = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(out)], cwd=REPO, env=env, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_renders_png_frames_with_egl_or_says_why(tmp_path):
    r = _run("egl", tmp_path / "egl")
    if not r["ok"]:
        assert "libegl" in r["why"] and "libosmesa6" in r["why"], r["why"]
        pytest.skip(r["why"])
    assert r["frames"] == 3
    assert r["shape"] == [120, 160, 3]
    assert r["std"] > 1.0  # the robot is in the picture, not a blank frame


def test_without_a_display_glfw_is_skipped_with_a_clear_message(tmp_path):
    r = _run("glfw", tmp_path / "glfw")
    assert not r["ok"]
    assert "rendering skipped" in r["why"] and "MUJOCO_GL=glfw" in r["why"] and "libosmesa6" in r["why"]
