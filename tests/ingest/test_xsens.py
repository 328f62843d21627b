"""Xsens MVN network streaming (type 02) datagrams built from the public spec layout."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from services.ingest.live import LiveIngest
from services.ingest.xsens import SEGMENTS, MvnDecoder, MvnError, build_datagrams, parse_datagram


def spec_datagram(sample, time_ms, items, char=0, dgc=0x80, mtype=b"02", n_body=23):
    """Hand-packed per the spec: 24-byte big-endian header, then 32-byte items."""
    payload = b"".join(struct.pack(">i", sid) + struct.pack(">7f", *p, *q) for sid, p, q in items)
    header = (
        b"MXTP" + mtype
        + struct.pack(">I", sample) + bytes([dgc, len(items)]) + struct.pack(">I", time_ms)
        + bytes([char, n_body, 0, 0]) + b"\x00\x00" + struct.pack(">H", len(payload))
    )  # fmt: skip
    assert len(header) == 24
    return header + payload


def wxyz(R):
    return Rotation.from_matrix(R).as_quat(scalar_first=True)


def pose_items(yaw_deg=30.0):
    """Pelvis at (100, 50, 95) cm turned by yaw; right forearm 25 cm in front and right of the pelvis."""
    Rp = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    root = np.array([100.0, 50.0, 95.0])
    local = {10: np.array([25.0, -20.0, 30.0]), 15: np.array([20.0, 25.0, 0.0]), 5: np.array([0.0, 0.0, 25.0])}
    items = [(1, root, wxyz(Rp))]
    for sid, pl in local.items():
        items.append((sid, root + Rp @ pl, wxyz(Rp @ Rotation.from_euler("x", 20, degrees=True).as_matrix())))
    return items, Rp, root, local


def test_spec_table_names():
    assert SEGMENTS[1] == "Pelvis" and SEGMENTS[5] == "T8" and SEGMENTS[7] == "Head"
    assert SEGMENTS[10] == "RightForeArm" and SEGMENTS[15] == "LeftHand" and SEGMENTS[23] == "LeftToe"


def test_decode_spec_datagram_to_pelvis_frame():
    items, _Rp, root, local = pose_items()
    dg = spec_datagram(1234, 5678, items)
    hdr, segs = parse_datagram(dg)
    assert set(segs) == {1, 5, 10, 15}
    assert (hdr.sample_counter, hdr.time_code_ms, hdr.last, hdr.n_items) == (1234, 5678, True, 4)
    f = MvnDecoder().step(dg, t0_ns=42)
    assert f.hdr.seq == 1234 and f.hdr.stamp == pytest.approx(5.678) and f.hdr.t0 == 42
    assert np.allclose(f.root.p, root / 100, atol=1e-6)
    assert np.allclose(f.bones["right_elbow"].p, local[10] / 100, atol=1e-6)  # forearm origin = elbow
    assert np.allclose(f.bones["left_wrist"].p, local[15] / 100, atol=1e-6)  # hand origin = wrist
    assert np.allclose(f.bones["chest"].p, local[5] / 100, atol=1e-6)  # T8 -> chest
    rel = Rotation.from_quat(f.bones["right_elbow"].q, scalar_first=True).as_euler("xyz", degrees=True)
    assert np.allclose(rel, [20, 0, 0], atol=1e-4)
    assert set(f.bones) == {"pelvis", "chest", "right_elbow", "left_wrist"}


def test_units_metres_option():
    items, _Rp, _root, local = pose_items()
    items_m = [(sid, p / 100, q) for sid, p, q in items]
    f = MvnDecoder(units="m").step(spec_datagram(1, 0, items_m), 0)
    assert np.allclose(f.bones["right_elbow"].p, local[10] / 100, atol=1e-6)


def test_split_datagrams_assembled():
    items, *_ = pose_items()
    segs = {sid: (p, q) for sid, p, q in items}
    parts = build_datagrams(7, 100, segs, max_items=3)
    assert len(parts) == 2 and parts[0] != parts[1]
    dec = MvnDecoder()
    assert dec.step(parts[0], 0) is None
    f = dec.step(parts[1], 0)
    assert f is not None and {"right_elbow", "left_wrist", "chest"} <= set(f.bones)
    # our encoder matches the hand-packed spec bytes
    assert build_datagrams(1234, 5678, segs)[0] == spec_datagram(
        1234, 5678, sorted(items, key=lambda x: x[0]), n_body=4
    )


def test_bad_datagrams():
    items, *_ = pose_items()
    good = spec_datagram(1, 0, items)
    with pytest.raises(MvnError, match="MXTP"):
        parse_datagram(b"XXXX" + good[4:])
    with pytest.raises(MvnError, match="only 02"):
        parse_datagram(spec_datagram(1, 0, items, mtype=b"01"))
    with pytest.raises(MvnError) as exc:
        parse_datagram(good[:-5])
    assert exc.value.reason == "mvn_size"
    with pytest.raises(MvnError, match="no Pelvis"):
        MvnDecoder().step(spec_datagram(1, 0, items[1:]), 0)


def test_live_path_sanitizes_xsens():
    items, *_ = pose_items()
    core = LiveIngest()
    assert core.step("xsens", spec_datagram(1, 0, items), 0)[0] is not None
    out, issues = core.step("xsens", spec_datagram(1, 0, items), 0)
    assert out is None and issues[0].reason == "duplicate_seq"
    bad = [(sid, p, q * (1.05 if sid == 10 else 1.0)) for sid, p, q in items]
    out, issues = core.step("xsens", spec_datagram(2, 10, bad), 0)
    assert out is not None and [i.reason for i in issues] == ["quat_normalised"]
    nan = [(sid, p * (np.nan if sid == 15 else 1.0), q) for sid, p, q in items]
    out, issues = core.step("xsens", spec_datagram(3, 20, nan), 0)
    assert out.bones["left_wrist"].valid is False and "nan_bone" in [i.reason for i in issues]
    out, issues = core.step("xsens", b"MXTP02" + b"\0" * 5, 0)
    assert out is None and issues[0].reason == "mvn_short"
