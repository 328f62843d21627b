"""A recording the logger produced, opened in the Rerun web viewer in headless Chromium.

The recording is made the way ``mimic log`` makes one: :func:`open_recording` (its batching and
blueprint), :class:`RerunLogger` with the real G1 meshes fed real sim states, then
:func:`compact` at close. ``rerun --serve-web`` serves it on loopback and Chromium (software
WebGL) shows it; the screenshot must show the robot, the operator and the time series, which a
recording that holds only the blueprint (same viewer, same panels) does not: so the pixels tell
"robot drawn" from "viewer chrome only".

Needs Debian's ``chromium``: ``make test-browser`` installs it (apt) and runs this file; plain
``make test`` leaves it out (marker ``browser``). Screenshots are kept in pytest's tmp dir.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import pytest
from test_rerun_logger import make_sequence

from services.logger.cli import add_arguments, configs, open_recording
from services.logger.compact import compact
from services.logger.rerun_logger import OPERATOR_RGB, RerunLogger
from services.logger.robot_visual import RobotVisual
from tests.support.web_viewer import WebViewer, chromium_path

pytestmark = [pytest.mark.browser, pytest.mark.slow]

#: Per page: application start plus the recording drawn [s]. About 40 s on a quiet 2-core
#: machine; the bound leaves room for a loaded CI runner (software rendering shares the CPU).
TIMEOUT = float(os.environ.get("MIMIC_BROWSER_TIMEOUT", "240"))
SIZE = (1024, 640)


def _recording(path: Path, frames: int) -> Path:
    """A compacted recording as ``mimic log`` writes it, of ``frames`` mocap frames (0: blueprint only)."""
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--rrd", str(path), "--session", "webviewer"])
    rc, lc = configs(args)
    rec = open_recording(rc, lc.operator_offset, args.session, path)
    if frames:
        lg = RerunLogger(rec, RobotVisual(args.robot), operator_offset=lc.operator_offset)
        lg.setup()
        for payload in make_sequence(frames):
            lg.step("mimic/webviewer/x", payload)
        lg.flush_error()
    rec.flush()
    rec.disconnect()
    assert compact(path), f"rerun rrd optimize failed on {path}"
    return path


# ---------------------------------------------------------------- what the pixels say
# Layout from the blueprint: the 3D view left (3 of 5 column shares), the time-series column
# right; a 40 px top bar, the view titles below it, the time panel at the bottom.


def _view3d(img: np.ndarray) -> np.ndarray:
    h, w, _ = img.shape
    return img[75 : h - 45, int(0.02 * w) : int(0.57 * w)].astype(int)


def _plots(img: np.ndarray) -> np.ndarray:
    h, w, _ = img.shape
    return img[40 : h - 45, int(0.62 * w) : int(0.98 * w)].astype(int)


def _saturated(px: np.ndarray) -> np.ndarray:
    """Coloured pixels: the theme's text, grid and background are grey."""
    return (px.max(axis=2) - px.min(axis=2)) > 60


def figures(img: np.ndarray) -> dict[str, int]:
    """Pixel counts: robot-like (dark or coloured) and operator-orange in the 3D view; series colours
    and panel text (dark grey) in the time-series column."""
    v, p = _view3d(img), _plots(img)
    orange = np.all(np.abs(v - np.array(OPERATOR_RGB)) < 45, axis=2)
    dark = v.max(axis=2) < 200  # the light theme's background and grid are lighter
    return {
        "robot": int(np.count_nonzero((dark | _saturated(v)) & ~orange)),
        "operator": int(np.count_nonzero(orange)),
        "series": int(np.count_nonzero(_saturated(p))),
        "panel_text": int(np.count_nonzero(p.max(axis=2) < 120)),
    }


def robot_drawn(img: np.ndarray) -> bool:
    f = figures(img)
    return f["robot"] > 2000 and f["operator"] > 300 and f["series"] > 300


@pytest.fixture(scope="module")
def browser():
    if chromium_path() is None:
        pytest.fail("chromium is not installed: run `make test-browser` (it installs Debian's chromium)")


def _shoot(rrd: Path, out: Path, ready, what: str) -> tuple[np.ndarray, WebViewer]:
    with WebViewer(rrd, size=SIZE, workdir=out.parent / f"{out.stem}-browser") as viewer:
        viewer.open(TIMEOUT)
        return viewer.wait_for(what, ready, TIMEOUT, save=out), viewer


@pytest.mark.timeout(2 * TIMEOUT + 240)  # two pages, plus making and compacting the recordings
def test_web_viewer_draws_the_robot_and_the_panels(browser, tmp_path):
    empty = _recording(tmp_path / "empty.rrd", 0)
    robot = _recording(tmp_path / "robot.rrd", 30)

    # The blueprint alone: panels drawn (their titles), nothing in them. Ready once two
    # screenshots in a row agree (the application has settled).
    last: list[np.ndarray] = []

    def settled(img: np.ndarray) -> bool:
        same = bool(last) and np.array_equal(last[-1], img)
        last.append(img)
        return same and figures(img)["panel_text"] > 500

    bare, _ = _shoot(empty, tmp_path / "empty.png", settled, "the panels of an empty recording")
    shot, viewer = _shoot(robot, tmp_path / "robot.png", robot_drawn, "the robot, the operator and the series")

    fb, fr = figures(bare), figures(shot)
    print(
        f"figures empty {fb}, robot {fr}; viewer up {viewer.t_app:.1f} s, drawn {viewer.t_drawn:.1f} s; in {tmp_path}"
    )
    assert shot.shape == bare.shape == (SIZE[1], SIZE[0], 3)
    # The same panels in both (their titles), ...
    assert fr["panel_text"] > 500 and fb["panel_text"] > 500, (fb, fr)
    # ... the robot, the operator and the series only where the recording holds them.
    assert fb["robot"] < 0.1 * fr["robot"] and fb["operator"] < 20 and fb["series"] < 0.1 * fr["series"], (fb, fr)
    # The robot stands in the middle of the view (the blueprint's camera looks at it), not in a corner.
    v = _view3d(shot)
    ys, xs = np.nonzero(v.max(axis=2) < 200)
    assert 0.2 < xs.mean() / v.shape[1] < 0.8 and 0.2 < ys.mean() / v.shape[0] < 0.8, (xs.mean(), ys.mean())
