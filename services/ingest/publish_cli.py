"""``mimic publish FILE``: play a recorded clip onto ``mimic/<s>/mocap/frame`` in real time.

Frames go out at the clip's rate times ``--rate`` on a monotonic-clock
schedule (deadlines from the start, no sleep drift), exactly as a live
publisher: ``hdr.seq`` +1 per frame, ``hdr.stamp`` = clip time (monotonic
across loops), ``hdr.t0`` = ``time.time_ns()`` at publish.
"""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

from services.ingest.clip import ClipError, load_clip
from services.ingest.demo_motion import DEMO_MOTIONS, demo_clip_paths
from services.ingest.playback import Playback
from services.ingest.variants import mirrored
from shared.bus import ServiceRunner, add_bus_args
from shared.report import emit_json
from shared.wrist_only import wrists_only


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("file", type=Path, nargs="?", help="clip to play (.bvh or .c3d)")
    src.add_argument(
        "--demo", choices=sorted(DEMO_MOTIONS), default=None, help="play a bundled demo motion instead of a file"
    )
    parser.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1 = real time)")
    parser.add_argument("--loop", action="store_true", help="loop until stopped")
    parser.add_argument(
        "--mirror",
        action="store_true",
        help="play the operator's mirror image (left and right swapped, reflected through the sagittal plane)",
    )
    parser.add_argument("--start", type=float, default=None, help="clip time to start at [s]")
    parser.add_argument("--end", type=float, default=None, help="clip time to end at [s]")
    parser.add_argument("--skeleton-map", default=None, help="BVH skeleton map / C3D marker map file (TOML/JSON)")
    parser.add_argument("--units", default="auto", help="BVH length unit: auto, m, cm, mm, in")
    parser.add_argument("--up", default="auto", help="file up axis: auto, y, z")
    parser.add_argument(
        "--wait-subscriber", type=float, default=2.0, help="wait up to this long [s] for a subscriber before starting"
    )
    parser.add_argument(
        "--wrist-only",
        action="store_true",
        help="send the hand bones only, as a VR controller or hand tracker would (no shoulders, no elbows)",
    )
    parser.add_argument("--instance", default="main", help="status instance name")
    add_bus_args(parser)


def load_for_playback(args: argparse.Namespace):
    """Load and slice the clip named by ``args``, mirrored with ``--mirror`` (raises ClipError)."""
    if args.file is None:
        args.file = demo_clip_paths([args.demo])[0]
    opts = {"up": args.up}
    if Path(args.file).suffix.lower() == ".bvh":
        opts["units"] = args.units
    clip = load_clip(args.file, skeleton_map=args.skeleton_map, **opts)
    if args.start is not None or args.end is not None:
        clip = clip.slice(args.start, args.end)
    return mirrored(clip) if getattr(args, "mirror", False) else clip


class NoReceiverError(RuntimeError):
    """No router or no subscriber: the frames would reach nobody."""


def run(args: argparse.Namespace, stop_event: threading.Event | None = None) -> dict:
    """Publish the clip; returns a summary (frames, late frames, wall duration)."""
    clip = load_for_playback(args)
    player = Playback(clip, rate=args.rate, loop=args.loop)
    with ServiceRunner("publish", args, instance=args.instance) as svc:
        stop = stop_event or svc.stop_event
        pub = svc.publisher(svc.keys.mocap_frame)
        t_wait = time.monotonic() + max(0.0, args.wait_subscriber)
        while not pub.matching_status.matching and time.monotonic() < t_wait and not stop.is_set():
            stop.wait(0.02)
        if pub.matching_status.matching:
            # The first match is often the router alone; give the routes to every subscriber
            # behind it a moment so the opening frames are not lost.
            stop.wait(min(0.5, args.wait_subscriber))
        elif not stop.is_set():
            # Nobody can receive a frame: playing the clip into the void and exiting 0 would tell
            # the user it worked.
            connected = list(svc.session.info.routers_zid()) or list(svc.session.info.peers_zid())
            where = ", ".join(args.connect or []) or "$MIMIC_CONNECT / tcp/127.0.0.1:7447"
            if not connected:
                raise NoReceiverError(f"no router reachable at {where}: start the stack (mimic up) or pass --connect")
            raise NoReceiverError(
                f"nothing subscribes to {svc.keys.mocap_frame} within {args.wait_subscriber:g} s: is the stack up on "
                f"session {svc.keys.session!r}? (--session / $MIMIC_SESSION)"
            )
        svc.status.extra.update({"clip_fps": clip.fps, "clip_frames": clip.n_frames, "rate": args.rate})
        svc.log.info(
            "playing %s: %d frames at %.1f Hz x %.2f%s",
            clip.name,
            clip.n_frames,
            clip.fps,
            args.rate,
            " (loop)" if args.loop else "",
        )
        n = late = 0
        worst = 0.0
        start = time.monotonic()
        while not player.done and not stop.is_set():
            due = player.deadline(start)
            wait = due - time.monotonic()
            if wait > 0 and stop.wait(wait):
                break
            lag = time.monotonic() - due
            if lag > 0.5 / (clip.fps * args.rate):
                late += 1
            worst = max(worst, lag)
            frame = player.step(time.time_ns())
            svc.publish(pub, wrists_only(frame) if args.wrist_only else frame, stream="frames")
            n += 1
            svc.status.extra["late_frames"] = late
        wall = time.monotonic() - start
    return {
        "clip": clip.name,
        "frames": n,
        "late_frames": late,
        "worst_lag_ms": round(1e3 * worst, 3),
        "wall_s": round(wall, 3),
        "fps": clip.fps,
        "rate": args.rate,
        "wrist_only": bool(args.wrist_only),
    }


def main(args: argparse.Namespace) -> int:
    try:
        summary = run(args)
    except (ClipError, ValueError, OSError, NoReceiverError) as exc:
        import logging

        logging.getLogger("mimic.publish").error("%s", exc)
        return 2
    emit_json(summary, indent=None)
    return 0
