"""An intruder inside the secure stack's network: tries to publish commands and mocap frames.

Run in a container of the compose project (``intruder`` in tests/docker/compose.secure-test.yml)::

    docker compose ... run --rm intruder --cert none        # plain TCP, no certificate
    docker compose ... run --rm intruder --cert none --tls  # TLS without a client certificate
    docker compose ... run --rm intruder --cert logger      # the project CA, the wrong service's certificate
    docker compose ... run --rm intruder --cert solver --solver-id intruder   # control: may publish commands

Every forged message carries ``hdr.seq >= FORGED_SEQ`` so the observer can tell it from the real
stream. Commands go to ``solver/<--solver-id>/command`` (default ``main``, the one the sim follows)
with the rest pose; frames to ``mocap/frame``. Prints one JSON line: whether a session opened, why
not, and how many messages were put (a put that the router denies is not an error for the sender).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np
import zenoh

from shared.keys import Keys
from shared.messages import Header, JointCommand

#: hdr.seq of every forged message and above.
FORGED_SEQ = 999_000_000
ROUTER = "zenoh:7447"


def intruder_config(cert: str, tls: bool) -> zenoh.Config:
    """Client config: ``cert`` = a service's rendered config in /certs, or none (plain or TLS without a cert)."""
    if cert != "none":
        conf = zenoh.Config.from_file(f"/certs/{cert}.json5")
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", json.dumps([f"{'tls' if tls else 'tcp'}/{ROUTER}"]))
        if tls:  # trusts the router (the CA is public) but has no certificate of its own
            conf.insert_json5("transport/link/tls/root_ca_certificate", '"/certs/ca.pem"')
    # Give up instead of retrying forever when the router refuses the link.
    conf.insert_json5("connect/timeout_ms", "5000")
    conf.insert_json5("connect/exit_on_failure", "true")
    return conf


def forged_frames(n: int) -> list[bytes]:
    """``n`` valid HumanFrames of the demo motion with forged sequence numbers."""
    from services.ingest.clip import load_clip
    from services.ingest.demo_motion import generate_demo_clips

    clip = load_clip(generate_demo_clips(tempfile.mkdtemp(prefix="mimic-intruder-"))[0])
    return [clip.frame(i % clip.n_frames, seq=FORGED_SEQ + i).encode() for i in range(n)]


def forged_commands(n: int, solver_id: str) -> list[bytes]:
    """``n`` JointCommands to the rest pose with forged sequence numbers."""
    from shared.robot.pinocchio_model import build_robot_model

    robot = build_robot_model()
    return [
        JointCommand(
            hdr=Header(seq=FORGED_SEQ + i, stamp=0.0),
            solver_id=solver_id,
            algo="intruder",
            joints=list(robot.joint_names),
            q=np.asarray(robot.q_rest, dtype=float),
            qd=np.zeros(robot.nq),
        ).encode()
        for i in range(n)
    ]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    p.add_argument("--cert", default="none", help="service certificate to use (/certs/NAME.json5) or none")
    p.add_argument("--tls", action="store_true", help="with --cert none: TLS without a client certificate")
    p.add_argument("--solver-id", default="main", help="commands go to solver/<id>/command")
    p.add_argument("--duration", type=float, default=3.0, help="seconds of publishing [s]")
    p.add_argument("--rate", type=float, default=50.0, help="messages per second per stream [Hz]")
    a = p.parse_args()
    keys = Keys(os.environ.get("MIMIC_SESSION", "default"))
    out: dict = {"cert": a.cert, "tls": a.tls or a.cert != "none", "solver_id": a.solver_id}
    n = int(a.duration * a.rate)
    frames, commands = forged_frames(n), forged_commands(n, a.solver_id)
    t_open = time.monotonic()
    try:
        z = zenoh.open(intruder_config(a.cert, a.tls))
    except Exception as exc:  # the router refused the link: that is the expected outcome without a valid cert
        out.update(session_opened=False, error=f"{type(exc).__name__}: {exc}"[:300], open_s=time.monotonic() - t_open)
        sys.stdout.write(json.dumps(out) + "\n")
        return 0
    out.update(session_opened=True, open_s=time.monotonic() - t_open, routers=len(list(z.info.routers_zid())))
    put_frames = put_cmds = 0
    with z:
        pub_f = z.declare_publisher(keys.mocap_frame)
        pub_c = z.declare_publisher(keys.command(a.solver_id))
        time.sleep(0.5)  # routes settle, as any publisher would wait
        out["t_start"] = time.time()
        for f, c in zip(frames, commands):
            pub_f.put(f)
            put_frames += 1
            pub_c.put(c)
            put_cmds += 1
            time.sleep(1.0 / a.rate)
        out["t_end"] = time.time()
    out.update(put_frames=put_frames, put_commands=put_cmds)
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
