"""Settings of ``mimic log`` (and ``mimic bench logger``): one dataclass per concern.

The flags are built from these classes (:func:`shared.config.add_dataclass_arguments`), so the
defaults, units and validation live here only.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path


def parse_vec3(text: str) -> tuple[float, float, float]:
    """``"x,y,z"`` -> (x, y, z); an argparse type (one-line error on bad text)."""
    try:
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}")
    return parts[0], parts[1], parts[2]


@dataclass(frozen=True)
class LoggerConfig:
    """What the logger draws and how much it buffers.

    Attributes:
        meshes: draw the robot meshes.
        robot_rate: robot mesh placements per second of source time [Hz] (<= 0: every message).
        skeleton_rate: human skeletons per second of source time [Hz] (<= 0: every frame).
        operator_offset: where the operator's pelvis is drawn, x,y,z in the robot base frame [m].
        follow: solver whose commands pose the 'command' robot.
        queue: samples buffered before new ones are skipped.
    """

    meshes: bool = True
    robot_rate: float = 30.0
    skeleton_rate: float = 60.0
    operator_offset: tuple[float, float, float] = field(
        default=(0.0, 1.0, 0.0), metadata={"cli": {"type": parse_vec3, "shown_default": "0,1,0"}}
    )
    follow: str = "main"
    queue: int = 4096

    def __post_init__(self) -> None:
        if not (math.isfinite(self.robot_rate) and math.isfinite(self.skeleton_rate)):
            raise ValueError(f"robot_rate ({self.robot_rate}) and skeleton_rate ({self.skeleton_rate}) must be finite")
        if len(self.operator_offset) != 3 or not all(math.isfinite(x) for x in self.operator_offset):
            raise ValueError(f"operator_offset must be 3 finite numbers [m], got {self.operator_offset}")
        if self.queue < 1:
            raise ValueError(f"queue must be >= 1 sample, got {self.queue}")


@dataclass(frozen=True)
class RecordingConfig:
    """Where the recording goes: the ``.rrd`` file, and optionally viewers.

    Attributes:
        rrd: recording file (default runs/<session>.rrd).
        overwrite: replace an existing rrd file.
        compact: compact the recording (few large chunks) when it closes.
        id: instance id on the bus (default 'main', 'viewer' with serve).
        spawn: also spawn a native Rerun viewer (needs a display).
        serve: also serve gRPC + the web viewer for a remote browser.
        grpc_port: gRPC port for serve / spawn.
        web_port: web viewer port for serve.
        bind_host: interface the serve gRPC server (the recording's data) and web viewer listen on.
        advertise_host: host name the browser uses to reach the gRPC server (serve).
        connect_viewer: stream to a running viewer (rerun+http://...).
    """

    rrd: Path | None = field(
        default=None,
        metadata={
            "cli": {
                "type": Path,
                "shown_default": "runs/<session>.rrd",
                "help": "recording file; an existing file is kept and the recording goes to the first free "
                "<name>-<n>.rrd, unless --overwrite",
            }
        },
    )
    overwrite: bool = False
    compact: bool = field(
        default=True,
        metadata={
            "cli": {"help": "leave the recording as logged (many small chunks) instead of compacting it when it closes"}
        },
    )
    id: str | None = field(
        default=None,
        metadata={
            "cli": {
                "shown_default": "'main', 'viewer' with --serve",
                "help": "instance id on the bus (a viewer started beside a stack is not mistaken for the stack's "
                "logger)",
            }
        },
    )
    spawn: bool = False
    serve: bool = False
    grpc_port: int = 9876
    web_port: int = 9090
    bind_host: str = field(
        default="127.0.0.1",
        metadata={
            "cli": {
                "help": "interface the --serve servers (gRPC, the recording's data; HTTP, the web viewer) listen on; "
                "they are unauthenticated, so loopback unless asked (0.0.0.0: every interface, for a browser on "
                "another machine)"
            }
        },
    )
    advertise_host: str = field(
        default="localhost",
        metadata={
            "cli": {
                "help": "host name the browser uses to reach the gRPC server (--serve); the machine's name or IP "
                "for remote use"
            }
        },
    )
    connect_viewer: str | None = field(default=None, metadata={"cli": {"metavar": "URL", "shown_default": "none"}})

    def __post_init__(self) -> None:
        for name in ("grpc_port", "web_port"):
            port = getattr(self, name)
            if not 0 < port < 65536:
                raise ValueError(f"{name} must be a TCP port (1-65535), got {port}")

    @property
    def live(self) -> bool:
        """Whether a viewer reads the recording while it is written."""
        return bool(self.spawn or self.serve or self.connect_viewer)
