"""BVH variants (channel orders, 3/6 channels, units, up axis, rates, rig names), writer, errors, maps.

Variants are re-encodings of a real Bandai clip; each must read back to the
same canonical clip, which checks the reader against itself across formats.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from services.ingest import ClipError, load_clip
from services.ingest.body_frame import NOMINAL_ARM, arm_length
from services.ingest.bvh import BvhData, BvhJoint, parse_bvh, write_bvh
from services.ingest.errors import BvhError, SkeletonMapError
from services.ingest.rotations import Y_UP_TO_Z_UP, euler_to_matrix, matrix_to_euler

MIXAMO = {
    "Hips": "Hips", "Spine": "Spine1", "Chest": "Spine2", "Neck": "Neck", "Head": "Head",
    **{f"{b}_{s}": f"{S}{n}" for s, S in (("L", "Left"), ("R", "Right")) for b, n in
       (("Shoulder", "Shoulder"), ("UpperArm", "Arm"), ("LowerArm", "ForeArm"), ("Hand", "Hand"),
        ("UpperLeg", "UpLeg"), ("LowerLeg", "Leg"), ("Foot", "Foot"), ("Toes", "ToeBase"))},
}  # fmt: skip
CMU = {**MIXAMO, "Spine": "Spine", "Chest": "Spine1"}
XSENS = {
    "Hips": "Pelvis", "Spine": "L3", "Chest": "T8", "Neck": "Neck", "Head": "Head",
    **{f"{b}_{s}": f"{S}{n}" for s, S in (("L", "Left"), ("R", "Right")) for b, n in
       (("Shoulder", "Shoulder"), ("UpperArm", "UpperArm"), ("LowerArm", "ForeArm"), ("Hand", "Hand"),
        ("UpperLeg", "UpperLeg"), ("LowerLeg", "LowerLeg"), ("Foot", "Foot"), ("Toes", "Toe"))},
}  # fmt: skip
SIDES = (("L", "Left", "l"), ("R", "Right", "r"))
LIMBS = ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot", "Toes")


def _rig(root: str, trunk: str, limbs: str) -> dict[str, str]:
    """Bandai name -> another rig's. ``trunk``: the rig's Hips, Spine, Chest, Neck and Head, ``|``-separated;
    ``limbs``: its names for :data:`LIMBS`, with ``{S}`` (L/R), ``{Side}`` (Left/Right) or ``{s}`` (l/r)."""
    out = {"joint_Root": root, **dict(zip(("Hips", "Spine", "Chest", "Neck", "Head"), trunk.split("|")))}
    for S, Side, s in SIDES:
        out |= {f"{b}_{S}": n.format(S=S, Side=Side, s=s) for b, n in zip(LIMBS, limbs.split("|"))}
    return out


CMU_MAX = _rig(
    "root",
    "Hips|lowerback|Chest2|Neck|Head",
    "{Side}Collar|{Side}Shoulder|{Side}Elbow|{Side}Wrist|{Side}Hip|{Side}Knee|{Side}Ankle|{Side}Toe",
)
BIPED = _rig(
    "Bip01",
    "Bip01 Pelvis|Bip01 Spine|Bip01 Spine1|Bip01 Neck|Bip01 Head",
    "Bip01 {S} Clavicle|Bip01 {S} UpperArm|Bip01 {S} Forearm|Bip01 {S} Hand|Bip01 {S} Thigh|Bip01 {S} Calf"
    "|Bip01 {S} Foot|Bip01 {S} Toe0",
)
OPTITRACK = _rig(
    "Root", "Hip|Ab|Chest|Neck|Head", "{S}Shoulder|{S}UArm|{S}FArm|{S}Hand|{S}Thigh|{S}Shin|{S}Foot|{S}Toe"
)
SMPL = _rig(
    "root",
    "Pelvis|Spine1|Spine3|Neck|Head",
    "{S}_Collar|{S}_Shoulder|{S}_Elbow|{S}_Wrist|{S}_Hip|{S}_Knee|{S}_Ankle|{S}_Foot",
)
UNREAL = _rig(
    "root",
    "pelvis|spine_01|spine_03|neck_01|head",
    "clavicle_{s}|upperarm_{s}|lowerarm_{s}|hand_{s}|thigh_{s}|calf_{s}|foot_{s}|ball_{s}",
)
VROID = _rig(
    "Root",
    "J_Bip_C_Hips|J_Bip_C_Spine|J_Bip_C_Chest|J_Bip_C_Neck|J_Bip_C_Head",
    "|".join(
        f"J_Bip_{{S}}_{b}"
        for b in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot", "ToeBase")
    ),
)
UNITY = _rig("Root", "Hips|Spine|Chest|Neck|Head", "|".join(f"{{Side}}{b}" for b in LIMBS))


@pytest.fixture(scope="module")
def bandai(bvh_clips):
    # a clip whose hand End Sites are not zero-length, so the hand tip is covered too
    path = next(p for p in bvh_clips if p.name == "dataset-1_bye_normal_001.bvh")
    return path, parse_bvh(path), load_clip(path)


def reencode(
    data: BvhData,
    order: str = "XYZ",
    rename: dict[str, str] | None = None,
    prefix: str = "",
    scale: float = 1.0,
    z_up: bool = False,
    three_channels: bool = True,
    frame_time: float | None = None,
) -> BvhData:
    """Same motion as ``data`` (Bandai replace-mode), written as a conventional rig."""
    T = len(data.motion)
    joints, cols, ch = [], [], 0
    for j in data.joints:
        vals = data.motion[:, j.first_channel : j.first_channel + len(j.channels)]
        rot = "".join(c[0] for c in j.channels if c.endswith("rotation"))
        R = euler_to_matrix(rot, vals[:, [k for k, c in enumerate(j.channels) if c.endswith("rotation")]])
        t = np.tile(j.offset, (T, 1))
        for k, c in enumerate(j.channels):
            if c.endswith("position"):
                t[:, "XYZ".index(c[0])] = vals[:, k]
        if j.parent < 0 and z_up:
            R, t = Y_UP_TO_Z_UP @ R, t @ Y_UP_TO_Z_UP.T
        name = prefix + (rename or {}).get(j.name, j.name)
        angles = matrix_to_euler(order, R)
        is_root = j.parent < 0
        moving = is_root or not three_channels or j.name == "Hips"
        if moving:
            chans = [f"{a}position" for a in "XYZ"] + [f"{a}rotation" for a in order]
            block = np.concatenate([t * scale, angles], axis=1)
            off = np.zeros(3) if is_root else t[0] * 0.0  # add mode: offset + channels
            if not is_root:
                block[:, :3] -= off
        else:
            chans = [f"{a}rotation" for a in order]
            block = angles
            off = t[0] * scale
        end = None if j.end_site is None else j.end_site * scale
        joints.append(BvhJoint(name, j.parent, off, chans, end, ch))
        ch += len(chans)
        cols.append(block)
    return BvhData(joints, frame_time or data.frame_time, np.concatenate(cols, axis=1))


def assert_same_clip(a, b, tol=2e-6):
    assert a.n_frames == b.n_frames
    assert set(a.bones) == set(b.bones), (a.bones, b.bones)
    for bone in a.bones:
        assert np.allclose(a.positions[bone], b.positions[bone], atol=tol), bone
        dots = np.abs(np.sum(a.quats[bone] * b.quats[bone], axis=1))
        assert np.all(dots > 1 - 1e-6), bone
    assert np.allclose(a.root_p, b.root_p, atol=tol)


@pytest.mark.parametrize(
    "kwargs, expect",
    [
        ({"order": "XYZ"}, {"skeleton_map": "bandai", "units": "cm", "up": "y"}),
        ({"order": "YXZ", "three_channels": False}, {"skeleton_map": "bandai"}),
        ({"rename": MIXAMO, "prefix": "mixamorig:", "order": "ZYX"}, {"skeleton_map": "mixamo"}),
        ({"rename": CMU, "scale": 0.01, "z_up": True}, {"skeleton_map": "cmu", "units": "m", "up": "z"}),
        ({"rename": MIXAMO}, {"skeleton_map": "mixamo"}),
        ({"rename": XSENS, "scale": 10.0}, {"skeleton_map": "xsens_mvn", "units": "mm"}),
        ({"rename": CMU_MAX}, {"skeleton_map": "cmu_max"}),
        ({"rename": BIPED}, {"skeleton_map": "biped"}),
        ({"rename": OPTITRACK, "scale": 0.01}, {"skeleton_map": "optitrack", "units": "m"}),
        ({"rename": SMPL, "scale": 0.01, "z_up": True}, {"skeleton_map": "smpl", "up": "z"}),
        ({"rename": UNREAL, "z_up": True}, {"skeleton_map": "unreal", "up": "z"}),
        ({"rename": VROID, "scale": 0.01}, {"skeleton_map": "unity_humanoid"}),
        ({"rename": UNITY}, {"skeleton_map": "unity_humanoid"}),
    ],
)
def test_variants_read_back_identically(tmp_path, bandai, kwargs, expect):
    _path, data, ref = bandai
    p = write_bvh(tmp_path / "variant.bvh", reencode(data, **kwargs))
    clip = load_clip(p)
    for k, v in expect.items():
        assert clip.meta[k] == v, (k, clip.meta[k])
    assert clip.meta["position_mode"] == "add"
    assert_same_clip(clip, ref)


def test_a_rig_in_no_known_unit_is_scaled_to_a_nominal_arm(tmp_path, bandai):
    """CMU's 3ds Max BVH release measures in 1/0.45 inch (an arm of about 8 units): no unit makes that a human arm,
    so the clip is scaled to NOMINAL_ARM, the same motion at another size (was read as centimetres: an 8 cm arm the
    calibration rejected, not one frame retargeted)."""
    _path, data, ref = bandai
    clip = load_clip(write_bvh(tmp_path / "cmu.bvh", reencode(data, rename=CMU_MAX, scale=0.01 / 0.056444)))
    assert clip.meta["skeleton_map"] == "cmu_max" and clip.meta["units"] == "scaled"
    k = NOMINAL_ARM / arm_length(ref.positions)
    assert arm_length(clip.positions) == pytest.approx(NOMINAL_ARM, rel=1e-9)
    for bone in ("left_wrist", "right_elbow", "head"):
        assert np.allclose(clip.positions[bone], k * ref.positions[bone], atol=1e-6), bone


def test_frame_rate_from_frame_time(tmp_path, bandai):
    _path, data, _ref = bandai
    clip = load_clip(write_bvh(tmp_path / "fast.bvh", reencode(data, frame_time=1 / 120)))
    assert clip.fps == 120.0
    assert clip.times[1] == pytest.approx(1 / 120)


def test_writer_roundtrip(tmp_path, bandai):
    _path, data, ref = bandai
    out = write_bvh(tmp_path / "copy.bvh", data)
    back = parse_bvh(out)
    assert back.names == data.names
    assert [j.channels for j in back.joints] == [j.channels for j in data.joints]
    assert np.allclose([j.offset for j in back.joints], [j.offset for j in data.joints])
    assert np.allclose(back.motion, data.motion, atol=1e-6)
    assert_same_clip(load_clip(out), ref, tol=1e-6)


def test_explicit_options_override_detection(tmp_path, bandai):
    _path, data, ref = bandai
    p = write_bvh(tmp_path / "m.bvh", reencode(data, scale=0.01, z_up=True))
    clip = load_clip(p, units="m", up="z")
    assert_same_clip(clip, ref)
    wrong = load_clip(p, units="cm", up="z")
    assert np.allclose(wrong.positions["left_wrist"], ref.positions["left_wrist"] * 0.01, atol=1e-8)


def test_user_skeleton_map_file(tmp_path, bandai):
    _path, data, ref = bandai
    odd = {n: f"bone_{i:02d}" for i, n in enumerate(data.names)}
    p = write_bvh(tmp_path / "odd.bvh", reencode(data, rename=odd))
    with pytest.raises(SkeletonMapError) as exc:
        load_clip(p)
    msg = str(exc.value)
    assert "bone_07" in msg and "left_elbow" in msg and "--skeleton-map" in msg
    canon = {
        "pelvis": "Hips", "spine": "Spine", "chest": "Chest", "neck": "Neck", "head": "Head",
        **{f"{s}_{c}": f"{b}_{S}" for s, S in (("left", "L"), ("right", "R")) for c, b in
           (("clavicle", "Shoulder"), ("shoulder", "UpperArm"), ("elbow", "LowerArm"), ("wrist", "Hand"))},
    }  # fmt: skip
    lines = ['name = "odd"', "[bones]"]
    lines += [f'{c} = "{odd[j]}"' for c, j in canon.items()]
    lines += [f'left_hand = ["nothing_here", "{odd["Hand_L"]}/end"]', f'right_hand = "{odd["Hand_R"]}/end"']
    lines += ["[hips]", f'left = "{odd["UpperLeg_L"]}"', f'right = "{odd["UpperLeg_R"]}"']
    mp = tmp_path / "odd.toml"
    mp.write_text("\n".join(lines) + "\n")
    clip = load_clip(p, skeleton_map=mp)
    assert clip.meta["skeleton_map"] == "odd" and clip.meta["pelvis_frame_from"] == "hips"
    assert_same_clip(clip, ref)
    # the same map as JSON
    import json
    import tomllib

    jp = tmp_path / "odd.json"
    jp.write_text(json.dumps(tomllib.loads(mp.read_text())))
    assert_same_clip(load_clip(p, skeleton_map=jp), ref)


def test_bad_skeleton_map_file(tmp_path, bandai):
    path, _data, _ref = bandai
    mp = tmp_path / "bad.toml"
    mp.write_text('[bones]\nleft_toe = "Toes_L"\n')
    with pytest.raises(SkeletonMapError, match="unknown canonical bones"):
        load_clip(path, skeleton_map=mp)
    mp.write_text("[bones\n")
    with pytest.raises(SkeletonMapError, match="cannot read"):
        load_clip(path, skeleton_map=mp)


def test_broken_files_give_clear_errors(tmp_path, bandai):
    path, _data, _ref = bandai
    text = path.read_text()
    lines = text.splitlines()
    cases = {
        "no_motion": ("\n".join(lines[:40]), "no MOTION section"),
        "short_row": ("\n".join([*lines[:-1], "1 2 3"]), r"frame \d+ has 3 values, the hierarchy declares 132"),
        "nan_value": (text.replace(lines[-1], "nan " + " ".join(lines[-1].split()[1:])), "NaN or inf"),
        "bad_channel": (text.replace("Zrotation", "Wrotation", 1), "unknown channel 'Wrotation'"),
        # found by test_robustness's fuzzing: an Euler order with a repeated axis reached scipy's own ValueError
        "repeated_axis": (text.replace("Zrotation", "Xrotation", 1), "repeated rotation axis in channels"),
        "bad_offset": (text.replace("OFFSET 0.0408292", "OFFSET zero", 1), "expected a number, got 'zero'"),
        "not_bvh": ("hello\nMOTION\n", "expected HIERARCHY"),
        "zero_frame_time": (text.replace("Frame Time:\t0.0333333", "Frame Time: 0"), "Frame Time must be > 0"),
    }
    for name, (body, pattern) in cases.items():
        p = tmp_path / f"{name}.bvh"
        p.write_text(body)
        with pytest.raises(BvhError, match=pattern):
            load_clip(p)
    with pytest.raises(ClipError, match="cannot read"):
        load_clip(tmp_path / "missing.bvh")
    with pytest.raises(ClipError, match="unsupported file type"):
        load_clip(tmp_path / "clip.fbx")


def test_unbalanced_hierarchy(tmp_path, bandai):
    path, _data, _ref = bandai
    lines = path.read_text().splitlines()
    m = next(i for i, ln in enumerate(lines) if ln.startswith("MOTION"))
    body = "\n".join(lines[: m - 1] + lines[m:])  # drop the root's closing brace
    p = tmp_path / "unbalanced.bvh"
    p.write_text(body)
    with pytest.raises(BvhError, match="unclosed"):
        load_clip(p)


def test_zero_length_end_site_gives_no_hand(bvh_clips):
    happy = next(p for p in bvh_clips if p.name == "dataset-1_byebye_happy_001.bvh")
    clip = load_clip(happy)
    assert "left_hand" not in clip.positions  # its End Site is 0 0 0: no hand-tip information
    assert "left_wrist" in clip.positions


def test_reencode_helper_is_not_the_identity(bandai):
    """Guard: the variants really change the file layout."""
    _path, data, _ref = bandai
    v = reencode(copy.deepcopy(data), order="XYZ")
    assert v.n_channels < data.n_channels
    assert v.joints[2].channels == ["Xrotation", "Yrotation", "Zrotation"]
