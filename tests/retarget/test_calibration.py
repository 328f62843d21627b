"""Operator calibration: builders, validation and file round trips."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import REST_LEFT, make_frame, random_quat

from services.retarget.calibration import MIN_SPAN, Calibration, CalibrationError, anthropometric, from_recording
from shared.rotations import quat_to_matrix
from shared.targets import TARGET_NAMES


def test_anthropometric_extents_scale_with_measured_arm_length():
    cal = anthropometric(make_frame(0, 0.0))
    sh = np.array(REST_LEFT["left_shoulder"])
    el = np.array(REST_LEFT["left_elbow"])
    wr = np.array(REST_LEFT["left_wrist"])
    upper_arm, forearm = np.linalg.norm(el - sh), np.linalg.norm(wr - el)
    assert cal.arm_length["left"] == pytest.approx(upper_arm + forearm)
    # wrist box = shoulder +- arm length (widened by MIN_SPAN under the hanging rest when needed)
    np.testing.assert_allclose(cal.upper["left_wrist"], sh + upper_arm + forearm)
    np.testing.assert_allclose(cal.lower["left_wrist"][:2], sh[:2] - (upper_arm + forearm))
    assert cal.lower["left_wrist"][2] <= wr[2] - MIN_SPAN + 1e-12
    np.testing.assert_allclose(cal.upper["left_elbow"], sh + upper_arm)
    np.testing.assert_allclose(cal.rest["left_wrist"], wr)
    # right arm mirrored
    assert cal.rest["right_wrist"][1] == pytest.approx(-wr[1])
    for t in TARGET_NAMES:
        assert np.all(cal.lower[t] < cal.rest[t]) and np.all(cal.rest[t] < cal.upper[t])


def test_bigger_operator_gets_bigger_extents():
    small = anthropometric(make_frame(0, 0.0))
    # stretch the left arm down by 10 cm: longer forearm
    big = anthropometric(make_frame(0, 0.0, offsets={"left_wrist": np.array([0.0, 0.0, -0.1])}))
    assert big.arm_length["left"] > small.arm_length["left"] + 0.09
    assert np.all(
        big.upper["left_wrist"] - big.lower["left_wrist"] > small.upper["left_wrist"] - small.lower["left_wrist"]
    )


def test_from_recording_contains_every_sample():
    frames = [
        make_frame(i, i / 30, offsets={"left_wrist": np.array([0.02 * i, -0.05 * i, 0.1 * i])}) for i in range(12)
    ]
    cal = from_recording(frames, name="syn")
    assert cal.source == "recording:syn"
    for f in frames:
        for t in TARGET_NAMES:
            p = f.bones[t].p
            assert np.all(cal.lower[t] <= p) and np.all(p <= cal.upper[t])
    # observed-only extents are tighter than the anthropometric union
    tight = from_recording(frames, include_anthropometric=False)
    assert np.all(
        tight.upper["right_wrist"] - tight.lower["right_wrist"] <= cal.upper["right_wrist"] - cal.lower["right_wrist"]
    )


def test_calibration_file_round_trips_json(tmp_path):
    cal = from_recording(
        [make_frame(i, i / 30, offsets={"left_elbow": np.array([0.0, 0.01 * i, 0.0])}) for i in range(5)]
    )
    path = cal.save(tmp_path / "sub" / "operator.json")
    back = Calibration.load(path)
    assert back.to_dict() == cal.to_dict()
    assert json.loads(path.read_text())["source"] == cal.source


def test_calibration_file_loads_toml(tmp_path):
    d = anthropometric(make_frame(0, 0.0)).to_dict()
    lines = []
    for part in ("rest", "rest_q", "lower", "upper"):
        lines.append(f"[{part}]")
        lines += [f"{t} = {d[part][t]!r}" for t in TARGET_NAMES]
    path = tmp_path / "operator.toml"
    path.write_text("\n".join(lines) + "\n")
    back = Calibration.load(path)
    assert back.source == "file:operator.toml"
    for part in ("rest", "rest_q", "lower", "upper"):
        for t in TARGET_NAMES:
            np.testing.assert_allclose(getattr(back, part)[t], d[part][t])


def test_bad_calibrations_are_clear_errors(tmp_path):
    d = anthropometric(make_frame(0, 0.0)).to_dict()
    bad = json.loads(json.dumps(d))
    del bad["lower"]["left_elbow"]
    with pytest.raises(CalibrationError, match="lower lacks targets"):
        Calibration.from_dict(bad)
    bad = json.loads(json.dumps(d))
    bad["upper"]["left_wrist"][2] = bad["rest"]["left_wrist"][2]
    with pytest.raises(CalibrationError, match=r"left_wrist\.z: rest .* must be < upper"):
        Calibration.from_dict(bad)
    bad = json.loads(json.dumps(d))
    bad["rest_q"]["right_wrist"] = [2.0, 0.0, 0.0, 0.0]
    with pytest.raises(CalibrationError, match="quaternion norm"):
        Calibration.from_dict(bad)
    bad = json.loads(json.dumps(d))
    bad["rest"]["right_wrist"] = [0.0, "a", 0.0]
    with pytest.raises(CalibrationError, match="3 numbers"):
        Calibration.from_dict(bad)
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(CalibrationError, match="not valid"):
        Calibration.load(tmp_path / "x.json")
    with pytest.raises(CalibrationError, match="cannot read"):
        Calibration.load(tmp_path / "missing.json")
    with pytest.raises(CalibrationError, match=r"no arm can be calibrated.*invalid"):
        anthropometric(make_frame(0, 0.0, invalid=("left_wrist", "right_shoulder")))


def test_one_armed_capture_mirrors_the_measured_arm():
    rng = np.random.default_rng(3)
    q = random_quat(rng)
    # right arm only (like the Vicon right-arm marker set), right wrist moved so mirroring is visible
    frame = make_frame(
        0, 0.0, offsets={"right_wrist": np.array([0.05, -0.02, 0.01])}, quats={"right_wrist": q},
        drop=("left_shoulder", "left_elbow", "left_wrist"),
    )  # fmt: skip
    cal = anthropometric(frame)
    assert "left mirrored from right" in cal.source
    np.testing.assert_allclose(cal.rest["left_wrist"], cal.rest["right_wrist"] * [1, -1, 1])
    # mirrored box: x and z unchanged, y range flipped
    np.testing.assert_allclose(cal.lower["left_wrist"][[0, 2]], cal.lower["right_wrist"][[0, 2]])
    assert cal.lower["left_wrist"][1] == pytest.approx(-cal.upper["right_wrist"][1])
    assert cal.upper["left_wrist"][1] == pytest.approx(-cal.lower["right_wrist"][1])
    R_right, R_left = quat_to_matrix(cal.rest_q["right_wrist"]), quat_to_matrix(cal.rest_q["left_wrist"])
    S = np.diag([1.0, -1.0, 1.0])
    np.testing.assert_allclose(R_left, S @ R_right @ S, atol=1e-12)
    assert cal.arm_length["left"] == cal.arm_length["right"]


def _cli_args(*argv: str):
    import argparse

    from services.retarget.cli import add_arguments

    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(list(argv))


def test_calibration_state_survives_a_restart_and_a_bad_state_is_ignored(tmp_path):
    from services.retarget.cli import initial_calibration

    state = tmp_path / "runs" / "s_calibration.json"
    args = _cli_args("--calibration-state", str(state))
    assert initial_calibration(args) is None  # first start: auto-calibrate on the rest frame
    cal = anthropometric(make_frame(0, 0.0))
    cal.save(state)  # what the node writes on every new calibration
    assert not state.with_name(state.name + ".tmp").exists()  # written whole, then renamed
    restored = initial_calibration(args)  # the restarted service
    assert restored is not None
    for t in TARGET_NAMES:
        np.testing.assert_allclose(restored.rest[t], cal.rest[t])
    state.write_text("{ truncated")
    assert initial_calibration(args) is None  # a corrupt state cannot keep the service down
    given = tmp_path / "given.json"
    cal.save(given)
    assert initial_calibration(_cli_args("--calibration", str(given), "--calibration-state", str(state))) is not None
