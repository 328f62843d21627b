"""C3D marker files through ezc3d: the Vicon right-arm box lift and the Qualisys walk."""

from __future__ import annotations

import re
from dataclasses import replace

import ezc3d
import numpy as np
import pytest

from services.ingest import load_clip
from services.ingest.c3d import BUILTIN_MARKER_MAPS, C3dError

VICON = "ezc3d-testFiles_Vicon.c3d"
QUALISYS = "ezc3d-testFiles_Qualisys.c3d"


@pytest.fixture(scope="module")
def vicon(c3d_dir):
    return load_clip(c3d_dir / VICON)


def _raw_marker(path, label):
    c = ezc3d.c3d(str(path))
    labels = [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]]
    return c["data"]["points"][:3, labels.index(label), :].T / 1000.0


def test_vicon_right_arm_tracks(vicon, mocap_dir):
    assert vicon.meta["marker_map"] == "vicon_epaule_droite" and vicon.meta["prefix"] == "Daphnee:"
    assert vicon.meta["root_from"] == "pelvis" and not vicon.has_orientation
    assert vicon.fps == 100.0 and vicon.n_frames == 580
    for b in ("right_wrist", "right_elbow", "right_shoulder"):
        assert vicon.valid[b].mean() > 0.9, b
    assert "left_wrist" not in vicon.positions  # only the right arm is instrumented
    fore = np.linalg.norm(vicon.positions["right_wrist"] - vicon.positions["right_elbow"], axis=1)
    ok = vicon.valid["right_wrist"] & vicon.valid["right_elbow"]
    assert 0.20 < np.median(fore[ok]) < 0.32  # adult forearm (elbow centre to wrist centre)
    assert np.std(fore[ok]) < 0.01  # rigid segment: skin-marker noise only
    upper = np.linalg.norm(vicon.positions["right_elbow"] - vicon.positions["right_shoulder"], axis=1)
    assert 0.22 < np.nanmedian(upper) < 0.36
    # the right arm is on the right: y < 0 in the pelvis frame
    assert np.nanmedian(vicon.positions["right_elbow"][:, 1]) < -0.1
    # wrist travel against SOURCES.md ("about 0.5 m horizontally and 0.8 m vertically")
    text = (mocap_dir / "SOURCES.md").read_text()
    h, v = map(
        float, re.search(r"wrist travels about ([\d.]+) m horizontally and ([\d.]+) m vertically", text).groups()
    )
    w = vicon.world_positions("right_wrist")
    span = np.nanmax(w, axis=0) - np.nanmin(w, axis=0)
    assert abs(span[2] - v) < 0.1
    assert abs(np.hypot(span[0], span[1]) - h) < 0.2


def test_vicon_gaps_are_invalid_not_zero(vicon, c3d_dir):
    raw = np.stack([_raw_marker(c3d_dir / VICON, f"Daphnee:{m}") for m in ("STYLr", "STYLu")])
    missing = np.any(np.isnan(raw), axis=(0, 2))
    assert missing.any(), "the file is known to have styloid gaps"
    assert np.array_equal(~vicon.valid["right_wrist"], missing)
    assert np.all(np.isnan(vicon.positions["right_wrist"][missing]))
    assert not np.any(np.all(vicon.positions["right_wrist"][~missing] == 0.0, axis=1))
    # the bus frame keeps the bone, flagged invalid, at its last valid position (never zeros)
    i = int(np.argmax(missing))
    f = vicon.frame(i, seq=i)
    assert f.bones["right_wrist"].valid is False
    assert np.all(np.isfinite(f.bones["right_wrist"].p)) and np.linalg.norm(f.bones["right_wrist"].p) > 0.1


def test_vicon_joint_centres_are_marker_midpoints(vicon, c3d_dir):
    path = c3d_dir / VICON
    el = 0.5 * (_raw_marker(path, "Daphnee:EPICl") + _raw_marker(path, "Daphnee:EPICm"))
    assert np.allclose(vicon.world_positions("right_elbow"), el, atol=1e-9, equal_nan=True)


def test_qualisys_full_body(c3d_dir):
    clip = load_clip(c3d_dir / QUALISYS)
    assert clip.meta["marker_map"] == "qualisys_isb" and clip.fps == 200.0
    for s, sign in (("left", 1), ("right", -1)):
        assert clip.valid[f"{s}_wrist"].all()
        assert sign * np.median(clip.positions[f"{s}_shoulder"][:, 1]) > 0.1
        fore = np.linalg.norm(clip.positions[f"{s}_wrist"] - clip.positions[f"{s}_elbow"], axis=1)
        assert 0.18 < fore.mean() < 0.32 and fore.std() < 0.01
    assert np.median(clip.positions["head"][:, 2]) > 0.4
    # walking: the pelvis moves forward along its own x axis
    from services.ingest.rotations import quats_to_matrices

    x_axis = quats_to_matrices(clip.root_q)[:, :, 0]
    travel = clip.root_p[-1] - clip.root_p[0]
    assert np.linalg.norm(travel) > 1.0
    assert np.dot(travel / np.linalg.norm(travel), x_axis.mean(axis=0)) > 0.8


#: Qualisys ISB label -> the Vicon full-body (Plug-in Gait) marker on the same landmark; the pelvis keys are filled in
#: per set. The medial epicondyles and fifth metacarpals have no Plug-in Gait marker: they are renamed out of the way.
ISB_TO_VICON = {
    "SNJ": "CLAV", "SXS": "STRN", "CV7": "C7", "TV8": "T10", "L_HDF": "LFHD", "L_HDB": "LBHD", "R_HDF": "RFHD",
    "R_HDB": "RBHD",
    **{f"{S}_{isb}": f"{S}{pig}" for S in "LR" for isb, pig in
       (("SAJ", "SHO"), ("HLE", "ELB"), ("RSP", "WRA"), ("UHE", "WRB"), ("HM2", "FIN"), ("HME", "XME"),
        ("HM5", "XM5"))},
}  # fmt: skip


@pytest.mark.parametrize("name, front, back", [("plug_in_gait", "ASI", "PSI"), ("cmu_41", "FWT", "BWT")])
def test_vicon_full_body_marker_sets(tmp_path, c3d_dir, name, front, back):
    """The Qualisys walk relabelled as a Vicon full-body set reads back with that set's map: the same root and wrists
    (the same markers), and the elbow centre from its lateral epicondyle marker alone near the ISB one, the mean of
    both epicondyles (measured: median 1.5 / 0.9 cm left / right; the marker itself is 4.5 / 4.2 cm off)."""
    c = ezc3d.c3d(str(c3d_dir / QUALISYS))
    rename = ISB_TO_VICON | {f"{S}_IAS": f"{S}{front}" for S in "LR"} | {f"{S}_IPS": f"{S}{back}" for S in "LR"}
    labels = [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]]
    c["parameters"]["POINT"]["LABELS"]["value"] = [rename.get(lb, lb) for lb in labels]
    out = tmp_path / f"{name}.c3d"
    c.write(str(out))
    isb, vicon = load_clip(c3d_dir / QUALISYS), load_clip(out)
    mmap = next(m for m in BUILTIN_MARKER_MAPS if m.name == name)
    marker = load_clip(out, skeleton_map=replace(mmap, elbow_offset=0.0))
    assert vicon.meta["marker_map"] == name and vicon.meta["root_from"] == isb.meta["root_from"] == "pelvis"
    assert np.allclose(vicon.root_p, isb.root_p, equal_nan=True)
    for s in ("left", "right"):
        ok = isb.valid[f"{s}_wrist"] & vicon.valid[f"{s}_elbow"] & isb.valid[f"{s}_elbow"]
        assert ok.mean() > 0.9
        assert np.allclose(vicon.positions[f"{s}_wrist"][ok], isb.positions[f"{s}_wrist"][ok])
        ref = isb.positions[f"{s}_elbow"][ok]
        centre = np.median(np.linalg.norm(vicon.positions[f"{s}_elbow"][ok] - ref, axis=1))
        lateral = np.median(np.linalg.norm(marker.positions[f"{s}_elbow"][ok] - ref, axis=1))
        assert centre < 0.02 and lateral > 0.035, (centre, lateral)


def test_custom_marker_map_and_errors(tmp_path, c3d_dir):
    mp = tmp_path / "map.toml"
    mp.write_text(
        'name = "mine"\nshoulder_drop = 0.0\n[joints]\nright_elbow = ["EPICl", "EPICm"]\n'
        'right_wrist = "WRIST"\n[thorax]\ntop = ["STER", "T1"]\nbottom = ["XIPH", "T10"]\n'
    )
    clip = load_clip(c3d_dir / VICON, skeleton_map=mp)
    assert clip.meta["marker_map"] == "mine" and clip.meta["root_from"] == "thorax"
    assert set(clip.bones) == {"pelvis", "right_elbow", "right_wrist"}
    assert np.nanmedian(clip.positions["right_elbow"][:, 1]) < -0.1  # thorax frame: y still points left
    mp.write_text('[joints]\nright_elbow = "NOPE1"\nright_wrist = "NOPE2"\n')
    with pytest.raises(C3dError, match=r"no elbow\+wrist pair.*Labels in the file"):
        load_clip(c3d_dir / VICON, skeleton_map=mp)
    mp.write_text('[joints]\nleft_toe = "X"\n')
    with pytest.raises(C3dError, match="unknown joints"):
        load_clip(c3d_dir / VICON, skeleton_map=mp)
    mp.write_text('elbow_offset = 4.2\n[joints]\nright_elbow = "EPICl"\nright_wrist = "WRIST"\n')
    with pytest.raises(C3dError, match=r"elbow_offset must be a number of metres in \[0, 0.1\], got 4.2"):
        load_clip(c3d_dir / VICON, skeleton_map=mp)
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x00" * 100)
    with pytest.raises(C3dError, match="ezc3d cannot read"):
        load_clip(bad)
