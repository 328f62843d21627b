"""A minimal two-role service used by the bus integration test (run as a real process)."""

from __future__ import annotations

import argparse
import logging
import sys
import time

import numpy as np

from shared.bus import ServiceRunner, add_bus_args, setup_logging
from shared.messages import HUMAN_BONES, Bone, Header, HumanFrame, Pose

log = logging.getLogger("peer")


def talker(svc: ServiceRunner) -> None:
    pub = svc.publisher(svc.keys.mocap_frame)
    seq = 0
    q = np.array([1.0, 0, 0, 0])
    while not svc.stop_event.is_set():
        bones = {n: Bone(np.full(3, seq * 1e-3), q) for n in HUMAN_BONES}
        svc.publish(pub, HumanFrame(Header(seq, seq / 100), "peer", Pose(np.zeros(3), q), bones), "frames")
        seq += 1
        time.sleep(0.01)


def listener(svc: ServiceRunner) -> None:
    slot = svc.subscribe_latest(svc.keys.mocap_frame, HumanFrame.decode, "frames")

    def on_alive(sample):
        log.info("LIVELINESS %s %s", sample.kind, sample.key_expr)

    svc.session.liveliness().declare_subscriber(svc.keys.all_alive, on_alive, history=True)
    last = -1
    while not svc.stop_event.is_set():
        msg = slot.take(timeout=0.1)
        if msg is not None and msg.hdr.seq > last:
            last = msg.hdr.seq
            svc.status.extra["last_seq"] = float(last)


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("role", choices=("talker", "listener"))
    add_bus_args(p)
    args = p.parse_args()
    setup_logging("INFO")
    with ServiceRunner(args.role, args) as svc:
        (talker if args.role == "talker" else listener)(svc)
    sys.exit(0)
