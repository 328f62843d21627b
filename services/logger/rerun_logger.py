"""Message -> Rerun translation: the pure core of the logger (no bus).

:meth:`RerunLogger.step` takes one bus sample (key, payload, receive time), decodes
it by its type tag and logs it on three timelines: ``session`` (seconds since the first
message, from ``hdr.t0``: keeps increasing across clips and source restarts; the one to
browse a whole run on), ``stamp`` (the mocap source time, ``hdr.stamp`` [s]) and ``seq``
(``hdr.seq``), which both start again with each clip. Entity layout (robot base = pelvis
frame, x forward, y left, z up):

* ``world/operator/skeleton`` (LineStrips3D) and ``world/operator/joints`` (Points3D):
  the human bones, drawn beside the robot (``world/operator`` is offset to the side);
* ``world/robot/targets/<wrist>`` (Transform3D + axes) and ``world/robot/targets/elbows``
  (Points3D): retargeted targets;
* ``world/robot/command/<mesh>`` and ``world/robot/sim/<mesh>``: the robot meshes posed
  by the commanded and by the simulated joints (meshes logged once, placements at
  ``robot_rate`` Hz of source time); ``world/robot/achieved``: achieved wrists/elbows;
* ``metrics/error_cm`` (one series per target): achieved position of the sim's last
  state on a frame vs the targets of the same frame (``hdr.t0``) [cm];
  ``metrics/residual/<solver>/level<k>``, ``metrics/solve_ms/<solver>``,
  ``metrics/latency_ms/<stream>`` (receive time - ``hdr.t0``),
  from each service's ServiceStatus, as rates [1/s] between two statuses (cumulative counts
  only ever climb, and a newcomer reads "1 397 dropped" as a fault):
  ``metrics/lost_or_rejected/<service>/{lost,rejected}`` (samples lost on the bus, i.e. gaps,
  and bad or out-of-order inputs: worth a look whenever above 0) apart from
  ``metrics/skipped_by_design/<service>`` (newest-wins mailboxes skipping superseded samples:
  normal); ``metrics/logger/skipped``.

Rerun is imported only inside :mod:`services.logger` (this module, ``cli``, ``bench_cli`` and
``rrd_summary``); no other service depends on it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from services.logger.robot_visual import RobotVisual
from shared.messages import (
    MESSAGE_TYPES,
    HumanFrame,
    JointCommand,
    MessageError,
    RobotState,
    ServiceStatus,
    TaskTargets,
    peek,
    peek_type,
)
from shared.rotations import quat_xyzw
from shared.scoring import TargetScorer
from shared.targets import ELBOWS, TARGET_NAMES, WRISTS

log = logging.getLogger("mimic.log")

#: Bone chains drawn as line strips (canonical names of shared.messages.HUMAN_BONES).
SKELETON_CHAINS: tuple[tuple[str, ...], ...] = (
    ("pelvis", "spine", "chest", "neck", "head"),
    ("chest", "left_clavicle", "left_shoulder", "left_elbow", "left_wrist", "left_hand"),
    ("chest", "right_clavicle", "right_shoulder", "right_elbow", "right_wrist", "right_hand"),
)
COMMAND_RGBA = (0.35, 0.55, 0.95, 0.3)  # translucent blue: what the solver asked
OPERATOR_RGB = (240, 160, 40)


def _xyzw(q_wxyz: np.ndarray) -> list[float]:
    return [float(q_wxyz[1]), float(q_wxyz[2]), float(q_wxyz[3]), float(q_wxyz[0])]


def blueprint(operator_offset: Iterable[float] = (0.0, 1.0, 0.0)) -> rrb.Blueprint:
    """3D view (operator beside the robot, seen from the front) and the time-series panels."""
    mid = 0.5 * np.asarray(list(operator_offset), dtype=float)
    eye = rrb.EyeControls3D(
        position=(mid[0] + 3.2, mid[1] - 0.4, 0.9), look_target=(mid[0], mid[1], -0.1), eye_up=(0.0, 0.0, 1.0)
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="operator | robot", eye_controls=eye),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="metrics/error_cm", name="wrist/elbow error [cm]"),
                rrb.TimeSeriesView(origin="metrics/latency_ms", name="end-to-end latency [ms]"),
                rrb.TimeSeriesView(origin="metrics/solve_ms", name="solve time [ms]"),
                rrb.TimeSeriesView(origin="metrics/residual", name="residual per level"),
                rrb.TimeSeriesView(
                    origin="metrics/lost_or_rejected", name="lost on the bus + rejected [1/s]: should stay at 0"
                ),
                rrb.TimeSeriesView(
                    origin="metrics/skipped_by_design", name="skipped by design [1/s]: newest wins, normal"
                ),
                rrb.TextLogView(origin="status", name="service problems"),
            ),
            column_shares=[3, 2],
        ),
        # The monotonic timeline: stamp/seq start again with each clip and would overlay them.
        rrb.TimePanel(state="collapsed", timeline="session"),
        collapse_panels=True,
    )


class RerunLogger:
    """Translate bus messages into Rerun log calls.

    Args:
        rec: recording stream to log into (its sinks decide where data goes).
        visual: robot meshes and FK (None: no robot meshes).
        operator_offset: (3,) where the operator's pelvis is drawn, robot base frame [m].
        robot_rate: robot mesh placements per second of source time [Hz] (<= 0: every message).
        skeleton_rate: human skeletons per second of source time [Hz] (<= 0: every frame);
            decoding a HumanFrame alone costs ~0.5 ms here, so it is skipped before decoding.
        follow: solver id whose commands pose the "command" robot, until a RobotState
            says which solver the sim follows.
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        visual: RobotVisual | None = None,
        operator_offset: Iterable[float] = (0.0, 1.0, 0.0),
        robot_rate: float = 30.0,
        skeleton_rate: float = 60.0,
        follow: str = "main",
    ):
        self.rec = rec
        self.visual = visual
        self.operator_offset = np.asarray(list(operator_offset), dtype=float)
        self.robot_period = 1.0 / robot_rate if robot_rate > 0 else 0.0
        self.skeleton_period = 1.0 / skeleton_rate if skeleton_rate > 0 else 0.0
        self.follow = follow
        self.counts: dict[str, int] = {}
        self.rejects: dict[str, int] = {}
        self._scorer = TargetScorer(512)
        self._last_state_key: tuple[int, bool] | None = None
        self._last_state_payload: bytes | None = None
        self._holding: bool | None = None
        self._last_cmd_seq: dict[str, int] = {}
        self._residual_levels: dict[str, int] = {}
        self._next_due: dict[str, float] = {}
        self._time = (0, 0.0)
        self._t0_first: int | None = None  # t0 [ns] of the first message with a header
        self._session_s = 0.0  # "session" timeline: seconds of bus time since that message
        #: service -> (uptime [s], dropped, gaps, rejected) of its previous status (for the rates)
        self._prev_counts: dict[str, tuple[float, int, int, int]] = {}
        self._said: dict[str, tuple[str, str]] = {}  # service -> (state, last_error) last put in the text log
        self._setup_done = False

    # ------------------------------------------------------------------ setup

    def setup(self) -> None:
        """Static content: axes convention, operator offset, meshes, target axes."""
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("world/operator", rr.Transform3D(translation=self.operator_offset), static=True)
        for w in WRISTS:
            rec.log(f"world/robot/targets/{w}", rr.TransformAxes3D(0.08), static=True)
        # Styles are static so that per-frame logs carry only the data (colour conversion
        # costs as much as the geometry).
        rec.log("world/operator/skeleton", rr.LineStrips3D.from_fields(colors=OPERATOR_RGB, radii=0.01), static=True)
        rec.log("world/operator/joints", rr.Points3D.from_fields(colors=OPERATOR_RGB, radii=0.02), static=True)
        rec.log("world/robot/targets/elbows", rr.Points3D.from_fields(colors=(40, 200, 90), radii=0.025), static=True)
        rec.log("world/robot/achieved", rr.Points3D.from_fields(colors=(220, 40, 40), radii=0.02), static=True)
        rec.log("metrics/error_cm", rr.SeriesLines(names=list(TARGET_NAMES)), static=True)
        if self.visual is not None:
            poses = self.visual.placements([], np.zeros(0))
            for robot, tint in (("sim", None), ("command", COMMAND_RGBA)):
                for mesh, (p, R) in zip(self.visual.meshes, poses):
                    path = f"world/robot/{robot}/{mesh.name}"
                    rgba = tint or mesh.rgba
                    # A mesh file (URDF robots), or a primitive that draws itself (services/logger/wheeled_visual.py).
                    shape = (
                        mesh.archetype(rgba)
                        if hasattr(mesh, "archetype")
                        else rr.Asset3D(path=mesh.path, albedo_factor=rgba)
                    )
                    rec.log(path, shape, static=True)
                    if not mesh.moving:
                        rec.log(path, rr.Transform3D(translation=p, mat3x3=R), static=True)
        self._setup_done = True

    # ------------------------------------------------------------------ entry point

    def _count(self, name: str, n: int = 1) -> None:
        self.counts[name] = self.counts.get(name, 0) + n

    def reject(self, reason: str, key: str = "") -> None:
        """Count a payload that could not be logged, by reason tag."""
        n = self.rejects.get(reason, 0) + 1
        self.rejects[reason] = n
        if n == 1:
            log.warning("cannot log a payload on %s (%s); counting further ones", key or "?", reason)

    def _decimate(self, kind: str, payload: bytes) -> bool:
        """Cheap pre-decode check (header only) for the high-rate streams."""
        if kind not in ("HumanFrame", "RobotState", "JointCommand"):
            return False
        try:
            d = peek(payload)
            seq, stamp, t0 = int(d["hdr"][0]), float(d["hdr"][1]), int(d["hdr"][2])
            sid = str(d.get("id", ""))
        except Exception:
            return False  # let the full decode say what is wrong
        if kind == "RobotState":
            # The sim publishes faster than commands arrive: one row per applied command for
            # the visuals and latency; the error waits for the last state of each frame (t0:
            # unlike seq, it does not start again with a new clip).
            key = (t0, bool(d.get("hold", False)))
            if self._last_state_key is not None and t0 != self._last_state_key[0]:
                self.flush_error()
            self._last_state_payload = payload
            if key == self._last_state_key:
                return True
            self._last_state_key = key
            return False
        if kind == "JointCommand":
            # Solvers tick faster than mocap frames (500 Hz on one frame's targets): one row
            # per solver and frame, the first solve on that frame's targets.
            if self._last_cmd_seq.get(sid) == seq:
                return True
            self._last_cmd_seq[sid] = seq
            return False
        return not self._due("skeleton", stamp, self.skeleton_period)

    def step(self, key: str, payload: bytes, recv_ns: int | None = None) -> str | None:
        """Log one bus sample.

        Args:
            key: key expression it arrived on (named in the first warning per reject reason).
            payload: msgpack payload.
            recv_ns: wall-clock receive time [ns] (default now), for latency.

        Returns:
            The message type logged, or None if rejected or decimated (both counted): a
            RobotState repeating the last one's frame (``t0``) and holding flag, a JointCommand
            repeating its solver's last ``seq``, or a HumanFrame within ``skeleton_rate``.
        """
        if not self._setup_done:
            self.setup()
        recv_ns = time.time_ns() if recv_ns is None else recv_ns
        kind = peek_type(payload)
        cls = MESSAGE_TYPES.get(kind) if isinstance(kind, str) else None
        if cls is None:
            self.reject("unknown_type", key)
            return None
        if self._decimate(kind, payload):
            self._count("decimated")
            return None
        try:
            msg = cls.decode(payload)
        except MessageError as exc:
            self.reject(exc.reason, key)
            return None
        if isinstance(msg, HumanFrame):
            self._human(msg, recv_ns)
        elif isinstance(msg, TaskTargets):
            self._targets_msg(msg, recv_ns)
        elif isinstance(msg, JointCommand):
            self._command(msg, recv_ns)
        elif isinstance(msg, RobotState):
            self._state(msg, recv_ns)
        elif isinstance(msg, ServiceStatus):
            self._status(msg)
        self._count(kind)
        return kind

    def flush_error(self) -> None:
        """Log the wrist/elbow error of the newest RobotState against the targets of its frame.

        Called when the sim moves on to the next frame (and once at the end): the error is
        that of the robot's last state on a frame, i.e. how close it got before the next
        frame, not of the instant the command arrived.
        """
        payload, self._last_state_payload = self._last_state_payload, None
        if payload is None:
            return
        try:
            msg = RobotState.decode(payload)
        except MessageError:
            return  # already counted when it was first seen
        errors = self._scorer.errors(msg)
        if errors is None:
            return
        # One row, one series per target (NaN where the target is missing or invalid).
        err = np.array([100.0 * errors.get(name, np.nan) for name in TARGET_NAMES])
        self._set_hdr(msg.hdr)
        self.rec.log("metrics/error_cm", rr.Scalars(err))

    def log_skipped(self, skipped: int) -> None:
        """Time series of messages the bus side dropped before they reached :meth:`step`."""
        self._set_time(*self._time)
        self.rec.log("metrics/logger/skipped", rr.Scalars([float(skipped)]))

    # ------------------------------------------------------------------ helpers

    def _set_hdr(self, hdr) -> None:
        """Timelines of a message header: ``seq``, ``stamp`` and the monotonic ``session``."""
        if hdr.t0 > 0:
            if self._t0_first is None:
                self._t0_first = hdr.t0
            # seq and stamp start again with every clip (the demo's two clips would lie on top of
            # each other); the bus-entry clock t0 does not, so "session" keeps increasing.
            self._session_s = max(self._session_s, (hdr.t0 - self._t0_first) * 1e-9)
        self._set_time(hdr.seq, hdr.stamp)

    def _set_time(self, seq: int, stamp: float) -> None:
        self._time = (seq, stamp)
        self.rec.set_time("seq", sequence=int(seq))
        self.rec.set_time("stamp", duration=float(stamp))
        self.rec.set_time("session", duration=self._session_s)

    def _latency(self, stream: str, t0: int, recv_ns: int) -> None:
        if t0 > 0:
            self.rec.log(f"metrics/latency_ms/{stream}", rr.Scalars([(recv_ns - t0) * 1e-6]))

    def _due(self, which: str, stamp: float, period: float) -> bool:
        """Throttle on source time: on average one log of ``which`` per ``period`` [s]."""
        due = self._next_due.get(which)
        if due is not None and due - 2 * period <= stamp < due - 1e-9:
            return False  # not yet due
        on_schedule = due is not None and due - 1e-9 <= stamp < due + period
        # Off schedule: first message, or source time jumped (new clip, gap): restart from here.
        self._next_due[which] = (due if on_schedule else stamp) + period
        return True

    def _pose_robot(self, which: str, joints: list[str], q: np.ndarray) -> None:
        if self.visual is None:
            return
        try:
            poses = self.visual.placements(joints, q)
        except KeyError as exc:
            self.reject("joints")
            log.debug("cannot pose robot: %s", exc)
            return
        for mesh, (p, R) in zip(self.visual.meshes, poses):
            if mesh.moving:
                rot = rr.Quaternion(xyzw=quat_xyzw(R))
                self.rec.log(f"world/robot/{which}/{mesh.name}", rr.Transform3D(translation=p, quaternion=rot))

    # ------------------------------------------------------------------ per message type

    def _human(self, msg: HumanFrame, recv_ns: int) -> None:
        self._set_hdr(msg.hdr)
        strips = []
        for chain in SKELETON_CHAINS:
            strip: list[np.ndarray] = []
            for bone in chain:
                b = msg.bones.get(bone)
                if b is None or not b.valid:
                    if len(strip) > 1:
                        strips.append(np.array(strip))
                    strip = []
                    continue
                strip.append(b.p)
            if len(strip) > 1:
                strips.append(np.array(strip))
        pts = [b.p for b in msg.bones.values() if b.valid]
        self.rec.log("world/operator/skeleton", rr.LineStrips3D(strips))
        self.rec.log("world/operator/joints", rr.Points3D(np.array(pts, dtype=np.float32).reshape(-1, 3)))
        self._latency("mocap", msg.hdr.t0, recv_ns)

    def _targets_msg(self, msg: TaskTargets, recv_ns: int) -> None:
        self._set_hdr(msg.hdr)
        self._scorer.add_targets(msg)
        for w in WRISTS:
            t = msg.targets.get(w)
            if t is not None and t.valid:
                rot = rr.Quaternion(xyzw=_xyzw(t.q))
                self.rec.log(f"world/robot/targets/{w}", rr.Transform3D(translation=t.p, quaternion=rot))
        elbows = [msg.targets[e].p for e in ELBOWS if e in msg.targets and msg.targets[e].valid]
        self.rec.log("world/robot/targets/elbows", rr.Points3D(np.array(elbows, dtype=np.float32).reshape(-1, 3)))
        self._latency("targets", msg.hdr.t0, recv_ns)

    def _command(self, msg: JointCommand, recv_ns: int) -> None:
        self._set_hdr(msg.hdr)
        sid = msg.solver_id
        if msg.residuals:
            n = len(msg.residuals)
            if self._residual_levels.get(sid) != n:
                self._residual_levels[sid] = n
                names = [f"level{k + 1}" for k in range(n)]
                self.rec.log(f"metrics/residual/{sid}", rr.SeriesLines(names=names), static=True)
            self.rec.log(f"metrics/residual/{sid}", rr.Scalars(np.asarray(msg.residuals, dtype=float)))
        self.rec.log(f"metrics/solve_ms/{sid}", rr.Scalars([float(msg.solve_ms)]))
        self._latency(f"command_{sid}", msg.hdr.t0, recv_ns)
        if sid == self.follow and self._due("command", msg.hdr.stamp, self.robot_period):
            self._pose_robot("command", msg.joints, msg.q)

    def _state(self, msg: RobotState, recv_ns: int) -> None:
        self.follow = msg.solver_id
        self._set_hdr(msg.hdr)
        pts = np.array([p.p for p in msg.frames.values()], dtype=np.float32).reshape(-1, 3)
        self.rec.log("world/robot/achieved", rr.Points3D(pts))
        if msg.holding != self._holding:
            self._holding = msg.holding
            self.rec.log("metrics/holding", rr.Scalars([1.0 if msg.holding else 0.0]))
        self._latency("state", msg.hdr.t0, recv_ns)
        if self._due("sim", msg.hdr.stamp, self.robot_period):
            self._pose_robot("sim", msg.joints, msg.q)

    def _status(self, msg: ServiceStatus) -> None:
        self._set_time(*self._time)
        name = msg.service if msg.instance == "main" else f"{msg.service}_{msg.instance}"
        c = msg.counts
        now = (msg.uptime, c.get("dropped", 0), c.get("gaps", 0), c.get("rejected", 0))
        prev, self._prev_counts[name] = self._prev_counts.get(name), now
        # Rates over the last status period; none on a service's first status or after it restarted
        # (uptime or a count went back).
        if prev is not None and now[0] > prev[0] and all(a >= b for a, b in zip(now[1:], prev[1:])):
            dt = now[0] - prev[0]
            dropped, lost, rejected = ((a - b) / dt for a, b in zip(now[1:], prev[1:]))
            self.rec.log(f"metrics/skipped_by_design/{name}", rr.Scalars([dropped]))
            self.rec.log(f"metrics/lost_or_rejected/{name}/lost", rr.Scalars([lost]))
            self.rec.log(f"metrics/lost_or_rejected/{name}/rejected", rr.Scalars([rejected]))
        # A service that is not "ok" (e.g. retarget throwing frames away while uncalibrated) says
        # why in the viewer's log panel, once per change, not only in its process log.
        said = (msg.state, msg.last_error)
        if msg.state != "ok" and said != self._said.get(name):
            level = rr.TextLogLevel.WARN if msg.state == "degraded" else rr.TextLogLevel.INFO
            self.rec.log(f"status/{name}", rr.TextLog(f"{name} {msg.state}: {msg.last_error or '-'}", level=level))
        self._said[name] = said
