"""``mimic log``: record every message of the session with Rerun.

Always writes an ``.rrd`` (default ``runs/<session>.rrd``); ``--spawn`` also starts a
native viewer, ``--serve`` serves gRPC (``--grpc-port``) and the web viewer
(``--web-port``) for a remote browser, ``--connect-viewer URL`` streams to a viewer
already running elsewhere.
"""

from __future__ import annotations

import argparse
import logging
import urllib.parse
from pathlib import Path

from services.logger.config import LoggerConfig, RecordingConfig
from services.logger.rerun_server import RerunServer
from shared.bus import add_bus_args
from shared.config import add_dataclass_arguments, config_from_args
from shared.paths import unused_path
from shared.robot.profile import DEFAULT_PROFILE

log = logging.getLogger("mimic.log")
#: Batcher flush period when the recording goes only to a file [s] (Rerun's default: 0.2 s).
FILE_FLUSH_TICK_S = 2.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_dataclass_arguments(p.add_argument_group("recording (RecordingConfig)"), RecordingConfig)
    g = p.add_argument_group("content (LoggerConfig)")
    g.add_argument("--robot", default=DEFAULT_PROFILE, help="robot profile name or TOML path")
    add_dataclass_arguments(g, LoggerConfig)
    add_bus_args(p)


def configs(args: argparse.Namespace) -> tuple[RecordingConfig, LoggerConfig]:
    """The two configs from parsed flags (each validates itself: ValueError)."""
    return config_from_args(RecordingConfig, args), config_from_args(LoggerConfig, args)


def open_recording(
    rc: RecordingConfig,
    operator_offset: tuple[float, float, float],
    session: str,
    rrd: Path,
    server: RerunServer | None = None,
):
    """Recording stream with its sinks (file, and optionally a spawned viewer, ``server``, a remote viewer)
    and the blueprint."""
    import rerun as rr

    from services.logger.rerun_logger import blueprint

    # Rerun's default batcher flushes every 0.2 s: with ~120 entities logged at 30-60 Hz that is a
    # chunk of ~3 rows per entity and tick (a demo recording: 4 845 chunks, "over-chunked", slow to
    # open). Written only to a file, rows wait up to FILE_FLUSH_TICK_S (what a crash can lose).
    batcher = None if rc.live else rr.ChunkBatcherConfig(flush_tick=FILE_FLUSH_TICK_S, flush_num_bytes=8 << 20)
    rec = rr.RecordingStream("mimic", batcher_config=batcher)
    rec.send_recording_name(session)
    sinks: list = [rr.FileSink(str(rrd))]
    if rc.spawn:
        rr.spawn(port=rc.grpc_port, connect=False)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{rc.grpc_port}/proxy"))
    elif server is not None:
        sinks.append(rr.GrpcSink(server.sink_url))
    if rc.connect_viewer:
        sinks.append(rr.GrpcSink(rc.connect_viewer))
    bp = blueprint(operator_offset)
    rec.set_sinks(*sinks, default_blueprint=bp)
    rec.send_blueprint(bp)
    if server is not None:
        url = urllib.parse.quote(f"rerun+http://{rc.advertise_host}:{rc.grpc_port}/proxy", safe="")
        page = f"http://{rc.advertise_host}:{rc.web_port}/?url={url}"
        log.info("web viewer: open %s (both ports listen on %s)", page, rc.bind_host)
    return rec


def main(args: argparse.Namespace) -> int:
    from services.logger.robot_visual import RobotVisual
    from shared.robot.profile import ProfileError
    from shared.robot.wheeled import is_wheeled_profile

    try:
        rc, lc = configs(args)
        rrd = rc.rrd or Path("runs") / f"{args.session}.rrd"
        if not rc.overwrite:
            rrd = unused_path(rrd)
        rrd.parent.mkdir(parents=True, exist_ok=True)
        if not lc.meshes:
            visual = None
        elif is_wheeled_profile(args.robot):  # no meshes: its MJCF primitives
            from services.logger.wheeled_visual import WheeledVisual

            visual = WheeledVisual(args.robot)
        else:
            visual = RobotVisual(args.robot)
    except (ProfileError, OSError, ValueError) as exc:
        log.error("%s", exc)
        return 2
    server = None
    if rc.serve and not rc.spawn:
        try:
            server = RerunServer(rc.bind_host, rc.grpc_port, rc.web_port).start()
        except (OSError, RuntimeError) as exc:
            log.error("--serve: %s", exc)
            return 2
    try:
        return _record(args, rc, lc, rrd, visual, server)
    finally:
        if server is not None:
            server.close()


def _record(args, rc: RecordingConfig, lc: LoggerConfig, rrd: Path, visual, server: RerunServer | None) -> int:
    """Log the session into ``rrd`` (and ``server``) until stopped; compact it after."""
    from services.logger.node import LoggerNode
    from services.logger.rerun_logger import RerunLogger
    from shared.bus import ServiceRunner

    rec = open_recording(rc, lc.operator_offset, args.session, rrd, server)
    logger = RerunLogger(rec, visual, lc.operator_offset, lc.robot_rate, lc.skeleton_rate, lc.follow)
    logger.setup()
    instance = rc.id or ("viewer" if rc.serve else "main")
    with ServiceRunner("logger", args, instance=instance) as svc:
        node = LoggerNode(logger, svc, queue_size=lc.queue)
        node.update_status()
        svc.before_status = node.update_status  # every status carries figures of its own moment
        svc.log.info("recording %s to %s", svc.keys.everything, rrd)
        svc.wait()
        svc.before_status = None
        node.close()
        logger.flush_error()
        node.update_status()
        svc.log.info("logged %s, skipped %d, rejected %s", logger.counts, node.skipped, logger.rejects)
    rec.flush()
    rec.disconnect()
    log.info("recording written: %s", rrd)
    if rc.compact:
        from services.logger.compact import compact

        compact(rrd)
    return 0
