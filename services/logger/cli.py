"""``mimic log``: record every message of the session with Rerun.

Always writes an ``.rrd`` (default ``runs/<session>.rrd``); ``--spawn`` also starts a
native viewer, ``--serve`` serves gRPC (``--grpc-port``) and the web viewer
(``--web-port``) for a remote browser, ``--connect-viewer URL`` streams to a viewer
already running elsewhere.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from shared.bus import add_bus_args
from shared.paths import unused_path
from shared.robot.profile import DEFAULT_PROFILE

log = logging.getLogger("mimic.log")
#: Batcher flush period when the recording goes only to a file [s] (Rerun's default: 0.2 s).
FILE_FLUSH_TICK_S = 2.0


def _vec3(text: str) -> tuple[float, float, float]:
    parts = [float(x) for x in text.split(",")]
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}")
    return parts[0], parts[1], parts[2]


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("recording")
    g.add_argument(
        "--rrd",
        type=Path,
        default=None,
        help="recording file (default runs/<session>.rrd); an existing file is kept and the recording goes to "
        "the first free <name>-<n>.rrd, unless --overwrite",
    )
    g.add_argument("--overwrite", action="store_true", help="replace an existing --rrd file")
    g.add_argument(
        "--no-compact",
        action="store_true",
        help="leave the recording as logged (many small chunks) instead of compacting it when it closes",
    )
    g.add_argument(
        "--id",
        default=None,
        help="instance id on the bus (default 'main', 'viewer' with --serve: a viewer started beside a stack is "
        "not mistaken for the stack's logger)",
    )
    g.add_argument("--spawn", action="store_true", help="also spawn a native Rerun viewer (needs a display)")
    g.add_argument("--serve", action="store_true", help="also serve gRPC + the web viewer for a remote browser")
    g.add_argument("--grpc-port", type=int, default=9876, help="gRPC port for --serve / --spawn")
    g.add_argument("--web-port", type=int, default=9090, help="web viewer port for --serve")
    g.add_argument(
        "--bind-host",
        default="127.0.0.1",
        help="interface the --serve gRPC server (the recording's data) listens on; it is unauthenticated, so "
        "loopback unless asked (0.0.0.0: every interface, for a browser on another machine)",
    )
    g.add_argument(
        "--advertise-host",
        default="localhost",
        help="host name the browser uses to reach the gRPC server (--serve); the machine's name or IP for remote use",
    )
    g.add_argument(
        "--connect-viewer", default=None, metavar="URL", help="stream to a running viewer (rerun+http://...)"
    )
    g = p.add_argument_group("content")
    g.add_argument("--robot", default=DEFAULT_PROFILE, help="robot profile name or TOML path")
    g.add_argument("--no-meshes", action="store_true", help="do not draw the robot meshes")
    g.add_argument("--robot-rate", type=float, default=30.0, help="robot mesh placements per second [Hz]")
    g.add_argument("--skeleton-rate", type=float, default=60.0, help="human skeletons per second [Hz] (0: all)")
    g.add_argument("--operator-offset", type=_vec3, default=(0.0, 1.0, 0.0), help="operator drawn at x,y,z [m]")
    g.add_argument("--follow", default="main", help="solver whose commands pose the 'command' robot")
    g.add_argument("--queue", type=int, default=4096, help="samples buffered before new ones are skipped")
    add_bus_args(p)


def open_recording(args: argparse.Namespace, rrd: Path):
    """Recording stream with its sinks (file, and optionally viewer/server) and the blueprint."""
    import rerun as rr

    from services.logger.rerun_logger import blueprint

    live = bool(args.spawn or args.serve or args.connect_viewer)
    # Rerun's default batcher flushes every 0.2 s: with ~120 entities logged at 30-60 Hz that is a
    # chunk of ~3 rows per entity and tick (a demo recording: 4 845 chunks, "over-chunked", slow to
    # open). Written only to a file, rows wait up to FILE_FLUSH_TICK_S (what a crash can lose).
    batcher = None if live else rr.ChunkBatcherConfig(flush_tick=FILE_FLUSH_TICK_S, flush_num_bytes=8 << 20)
    rec = rr.RecordingStream("mimic", batcher_config=batcher)
    rec.send_recording_name(getattr(args, "session", "mimic"))
    sinks: list = [rr.FileSink(str(rrd))]
    if args.spawn:
        rr.spawn(port=args.grpc_port, connect=False)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{args.grpc_port}/proxy"))
    elif args.serve:
        sinks.append(rr.GrpcServerSink(bind_ip=args.bind_host, port=args.grpc_port))
    if args.connect_viewer:
        sinks.append(rr.GrpcSink(args.connect_viewer))
    bp = blueprint(args.operator_offset)
    rec.set_sinks(*sinks, default_blueprint=bp)
    rec.send_blueprint(bp)
    if args.serve and not args.spawn:
        url = f"rerun+http://{args.advertise_host}:{args.grpc_port}/proxy"
        rr.serve_web_viewer(web_port=args.web_port, open_browser=False, connect_to=url)
        log.info("web viewer on http://%s:%d (data from %s)", args.advertise_host, args.web_port, url)
    return rec


def main(args: argparse.Namespace) -> int:
    from services.logger.node import LoggerNode
    from services.logger.rerun_logger import RerunLogger
    from services.logger.robot_visual import RobotVisual
    from shared.bus import ServiceRunner
    from shared.robot.profile import ProfileError
    from shared.robot.wheeled import is_wheeled_profile

    rrd = args.rrd or Path("runs") / f"{args.session}.rrd"
    if not args.overwrite:
        rrd = unused_path(rrd)
    try:
        rrd.parent.mkdir(parents=True, exist_ok=True)
        if args.no_meshes:
            visual = None
        elif is_wheeled_profile(args.robot):  # no meshes: its MJCF primitives
            from services.logger.wheeled_visual import WheeledVisual

            visual = WheeledVisual(args.robot)
        else:
            visual = RobotVisual(args.robot)
    except (ProfileError, OSError, ValueError) as exc:
        log.error("%s", exc)
        return 2
    rec = open_recording(args, rrd)
    logger = RerunLogger(
        rec,
        visual,
        operator_offset=args.operator_offset,
        robot_rate=args.robot_rate,
        skeleton_rate=args.skeleton_rate,
        follow=args.follow,
    )
    logger.setup()
    instance = args.id or ("viewer" if args.serve else "main")
    with ServiceRunner("logger", args, instance=instance) as svc:
        node = LoggerNode(logger, svc, queue_size=args.queue)
        svc.log.info("recording %s to %s", svc.keys.everything, rrd)
        while not svc.stop_event.wait(0.5):
            node.update_status()
        node.close()
        logger.flush_error()
        node.update_status()
        svc.log.info("logged %s, skipped %d, rejected %s", logger.counts, node.skipped, logger.rejects)
    rec.flush()
    rec.disconnect()
    log.info("recording written: %s", rrd)
    if not args.no_compact:
        from services.logger.compact import compact

        compact(rrd)
    return 0
