"""Bad input never crashes: only the documented error types come out."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from services.ingest.clip import ClipError, load_clip
from services.ingest.live import LiveIngest
from services.ingest.sanitizer import FrameSanitizer, decode_lenient
from services.ingest.xsens import MvnDecoder, MvnError
from shared.messages import HumanFrame, MessageError


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_random_datagrams(data):
    core = LiveIngest()
    for source in ("udp", "xsens"):
        frame, _issues = core.step(source, data, 0)
        assert frame is None or isinstance(frame, HumanFrame)
    try:
        decode_lenient(data)
    except MessageError:
        pass
    try:
        MvnDecoder().step(b"MXTP02" + data, 0)
    except MvnError:
        pass


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.floats(0.3, 1.0), flip=st.integers(0, 10**6), junk=st.sampled_from(["", "x", "}", "{", "nan", "-"]))
def test_damaged_bvh_files(tmp_path_factory, bvh_clips, cut, flip, junk):
    text = bvh_clips[3].read_text()
    k = int(cut * len(text))
    j = flip % max(1, len(text))
    body = text[:k]
    body = body[:j] + junk + body[j + 1 :] if j < len(body) else body
    p = tmp_path_factory.mktemp("dmg") / "d.bvh"
    p.write_text(body)
    try:
        clip = load_clip(p)
    except ClipError:
        return
    # if it loads, what it gives is finite where valid and encodes to valid messages
    for b in clip.bones:
        assert np.all(np.isfinite(clip.positions[b][clip.valid[b]]))
    HumanFrame.decode(clip.frame(clip.n_frames - 1, 0).encode())


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 50), st.floats(allow_nan=True, allow_infinity=True, width=32), st.floats(0.0, 2.0)),
        min_size=1,
        max_size=30,
    )
)
def test_sanitizer_output_always_encodes(events):
    from shared.messages import Bone, Header, Pose

    s = FrameSanitizer()
    for seq, x, qn in events:
        q = np.array([qn, 0.0, 0.0, 0.0])
        f = HumanFrame(
            Header(seq, 0.1, 1),
            "h",
            Pose(np.array([x, 0.0, 0.0]), np.array([1.0, 0, 0, 0])),
            {"pelvis": Bone(np.zeros(3), np.array([1.0, 0, 0, 0])), "left_wrist": Bone(np.array([x, 0.1, 0.0]), q)},
        )
        out, _ = s.step(f)
        if out is not None:
            HumanFrame.decode(out.encode())
