"""Mocap ingest: recorded clips (BVH, C3D) and live sources in, HumanFrames out.

Public API used by other services::

    from services.ingest import Clip, load_clip, generate_demo_clips
    clip = load_clip("motion.bvh")          # or .c3d
    frame = clip.frame(i, seq=i)            # HumanFrame for the bus
"""

from services.ingest.clip import Clip, ClipError, load_clip


def generate_demo_clips(outdir):
    from services.ingest.demo_motion import generate_demo_clips as _gen

    return _gen(outdir)


__all__ = ["Clip", "ClipError", "generate_demo_clips", "load_clip"]
