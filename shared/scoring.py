"""How close the robot got to the retargeted targets: one scorer for the monitor and the logger.

A mocap frame is identified by ``hdr.t0`` (wall clock [ns] at which it entered the
bus), not by ``hdr.seq``: a new clip or a restarted source starts ``seq`` again at 0,
and scoring by ``seq`` would then compare the robot with the targets of an older
frame. Every message derived from a frame (TaskTargets, JointCommand, RobotState)
carries the frame's header unchanged.

The score of a frame is the error of the robot's *last* state on it (just before the
next frame's first state), i.e. how close the robot got, not where it was when the
command arrived.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from shared.messages import RobotState, TaskTargets


class TargetScorer:
    """Targets of recent frames keyed by ``hdr.t0`` and the position error of robot states against them.

    Args:
        max_pending: frames whose targets are kept (oldest forgotten first).
    """

    def __init__(self, max_pending: int = 4096):
        self._targets: OrderedDict[int, TaskTargets] = OrderedDict()
        self._max_pending = max_pending
        self._last_t0 = 0
        self._last_state: RobotState | None = None
        #: The state the last returned score is of (its ``hdr`` names the frame).
        self.scored: RobotState | None = None

    def add_targets(self, tt: TaskTargets) -> None:
        self._targets[tt.hdr.t0] = tt
        while len(self._targets) > self._max_pending:
            self._targets.popitem(last=False)

    def errors(self, st: RobotState) -> dict[str, float] | None:
        """|achieved - target| [m] per valid target of ``st``'s frame; None if that frame's targets are unknown."""
        tt = self._targets.get(st.hdr.t0)
        if tt is None:
            return None
        out = {}
        for name, pose in st.frames.items():
            tgt = tt.targets.get(name)
            if tgt is not None and tgt.valid:
                out[name] = float(np.linalg.norm(pose.p - tgt.p))
        return out

    def add_state(self, st: RobotState) -> tuple[bool, dict[str, float] | None]:
        """Feed every RobotState in arrival order.

        Returns:
            (new_frame, errors): ``new_frame`` when ``st`` is the first state on a newer frame
            (its arrival is that frame's end-to-end latency); ``errors`` is then the score of
            the previous frame's last state (None when there is nothing to score). States
            without a frame behind them (``t0 <= 0``) or of an older frame are ignored.
        """
        t0 = st.hdr.t0
        if t0 <= 0 or t0 < self._last_t0:
            return False, None
        if t0 == self._last_t0:
            self._last_state = st
            return False, None
        errors = self.flush()
        self._last_t0 = t0
        self._last_state = st
        return True, errors

    def flush(self) -> dict[str, float] | None:
        """Score the last state held (at the end of a run); None if there is none or no targets."""
        st, self._last_state = self._last_state, None
        self.scored = st
        return None if st is None else self.errors(st)
