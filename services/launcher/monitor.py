"""Watch a running stack from the bus and summarise it.

The summary answers what a user asks after a run: did every frame come
through each service, what was dropped or rejected, how long did a mocap frame
take to show up in the simulated robot, and how close did the robot get to
the retargeted wrist and elbow targets.
"""

from __future__ import annotations

import bisect
import threading
import time

import numpy as np
import zenoh

from shared.keys import Keys
from shared.messages import JointCommand, MessageError, RobotState, ServiceStatus, TaskTargets
from shared.scoring import TargetScorer

#: Start-up of a stream [s]: its first STARTUP_S of frames (frame ``t0`` clock) after its first
#: target. The robot then moves from where it stood onto the operator's pose, an error of
#: decimetres that says nothing about tracking; it is summarised apart from the steady state.
STARTUP_S = 1.0
#: A target this long [s] after the previous one (the source was silent), or with an earlier
#: ``stamp`` (a new clip, a restarted source), starts a new stream.
STREAM_GAP_S = 1.0
#: How the summary says it (JSON ``error_split`` and the printed legend).
STARTUP_RULE = (
    f"start-up: the first {STARTUP_S:g} s of each stream (frame t0 after its first target; a stream starts "
    f"with the first target, a stamp going back, i.e. a new clip or restarted source, or {STREAM_GAP_S:g} s "
    "without targets); steady: every later frame"
)


def _pct(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def _stats_cm(v: list[float]) -> dict:
    """mean, p95, max [cm] and the number of samples of errors ``v`` [m]."""
    return {
        "mean": float(np.mean(v)) * 100 if v else None,
        "p95": float(np.percentile(v, 95)) * 100 if v else None,
        "max": float(np.max(v)) * 100 if v else None,
        "samples": len(v),
    }


class StackMonitor:
    """Pure accounting of what the bus carried (feed it decoded messages).

    Latency is measured from ``hdr.t0`` (frame entered the bus) to the arrival
    of the first RobotState that carries that frame's header, i.e. the frame
    has been retargeted, solved and applied in the simulation. Tracking error
    is the last RobotState of each frame (just before the next one) against
    that frame's targets. Joint positions are checked against the URDF limits.
    """

    def __init__(self, max_pending: int = 4096):
        self.status: dict[tuple[str, str], ServiceStatus] = {}
        self.frames_seen = 0
        self.scorer = TargetScorer(max_pending)
        self.max_command_excess = 0.0
        self.latency_ms: list[float] = []
        self.wrist_err: list[float] = []
        self.elbow_err: list[float] = []
        #: Per error above: seconds since its stream started (frame t0 clock), same order.
        self.wrist_age: list[float] = []
        self.elbow_age: list[float] = []
        self._stream_starts: list[int] = []  # t0 [ns] of each stream's first target, increasing
        self._last_target: tuple[int, float] | None = None  # (t0 [ns], stamp [s]) of the newest target
        self.max_joint_excess = 0.0
        self.states_seen = 0

    def on_status(self, st: ServiceStatus) -> None:
        self.status[(st.service, st.instance)] = st

    def on_frame(self) -> None:
        self.frames_seen += 1

    def on_targets(self, tt: TaskTargets) -> None:
        t0, stamp = tt.hdr.t0, tt.hdr.stamp
        last = self._last_target
        if last is None or stamp < last[1] or (t0 - last[0]) * 1e-9 > STREAM_GAP_S:
            self._stream_starts.append(t0)
        if last is None or t0 >= last[0]:
            self._last_target = (t0, stamp)
        self.scorer.add_targets(tt)

    def _age(self, t0: int) -> float:
        """Seconds between the start of the stream frame ``t0`` belongs to and that frame."""
        i = bisect.bisect_right(self._stream_starts, t0) - 1
        return (t0 - self._stream_starts[i]) * 1e-9 if i >= 0 else float("inf")

    def on_command(self, cmd: JointCommand, lower: np.ndarray | None, upper: np.ndarray | None) -> None:
        if lower is not None and upper is not None and len(cmd.q) == len(lower):
            excess = float(np.max(np.maximum(cmd.q - upper, lower - cmd.q)))
            self.max_command_excess = max(self.max_command_excess, excess)

    def on_state(
        self, st: RobotState, now_ns: int, lower: np.ndarray | None = None, upper: np.ndarray | None = None
    ) -> None:
        self.states_seen += 1
        if lower is not None and upper is not None and len(st.q) == len(lower):
            excess = float(np.max(np.maximum(st.q - upper, lower - st.q)))
            self.max_joint_excess = max(self.max_joint_excess, excess)
        new_frame, errors = self.scorer.add_state(st)
        if new_frame:
            # First state reflecting a new frame: that is the end-to-end latency.
            self.latency_ms.append((now_ns - st.hdr.t0) / 1e6)
        self._add_errors(errors)

    def _add_errors(self, errors: dict[str, float] | None) -> None:
        if not errors:
            return
        age = self._age(self.scorer.scored.hdr.t0)
        for name, err in errors.items():
            wrist = name.endswith("wrist")
            (self.wrist_err if wrist else self.elbow_err).append(err)
            (self.wrist_age if wrist else self.elbow_age).append(age)

    @staticmethod
    def _split(err: list[float], age: list[float]) -> dict:
        """All errors, and apart: start-up (age < STARTUP_S) and steady state [cm]."""
        e, a = np.asarray(err), np.asarray(age)
        return _stats_cm(err) | {
            "startup": _stats_cm(e[a < STARTUP_S].tolist()),
            "steady": _stats_cm(e[a >= STARTUP_S].tolist()),
        }

    def summary(self) -> dict:
        self._add_errors(self.scorer.flush())
        services = {}
        for (svc, inst), st in sorted(self.status.items()):
            c = st.counts
            services[f"{svc}/{inst}"] = {
                "in": c.get("received", 0),
                "out": c.get("published", 0),
                "dropped": c.get("dropped", 0),
                "rejected": c.get("rejected", 0),
                "state": st.state,
                "last_error": st.last_error,
                "counts": dict(c),
                "outcomes": dict(st.outcomes),
            }

        return {
            "frames_published": self.frames_seen,
            "robot_states": self.states_seen,
            "services": services,
            "latency_ms": {
                "p50": _pct(self.latency_ms, 50),
                "p99": _pct(self.latency_ms, 99),
                "max": max(self.latency_ms) if self.latency_ms else None,
                "samples": len(self.latency_ms),
            },
            "wrist_err_cm": self._split(self.wrist_err, self.wrist_age),
            "elbow_err_cm": self._split(self.elbow_err, self.elbow_age),
            "error_split": {"startup_s": STARTUP_S, "streams": len(self._stream_starts), "rule": STARTUP_RULE},
            "max_joint_limit_excess_rad": self.max_joint_excess,
            "max_command_limit_excess_rad": self.max_command_excess,
        }


class BusMonitor:
    """Feeds a :class:`StackMonitor` from a Zenoh session; tracks liveliness."""

    def __init__(self, session: zenoh.Session, keys: Keys, lower=None, upper=None):
        self.mon = StackMonitor()
        self.keys = keys
        self.alive: set[tuple[str, str]] = set()
        self.lost: list[tuple[str, str]] = []
        self._lock = threading.Lock()
        self._lower, self._upper = lower, upper
        self._subs = [
            session.declare_subscriber(keys.all_status, self._guard(ServiceStatus.decode, self.mon.on_status)),
            session.declare_subscriber(keys.targets, self._guard(TaskTargets.decode, self.mon.on_targets)),
            session.declare_subscriber(keys.mocap_frame, lambda _s: self._locked(self.mon.on_frame)),
            session.declare_subscriber(keys.sim_state, self._on_state),
            session.declare_subscriber(keys.all_commands, self._on_command),
            session.liveliness().declare_subscriber(keys.all_alive, self._on_alive, history=True),
        ]

    def _locked(self, fn, *a) -> None:
        with self._lock:
            fn(*a)

    def _guard(self, decode, sink):
        def cb(sample: zenoh.Sample) -> None:
            try:
                msg = decode(sample.payload.to_bytes())
            except MessageError:
                return
            self._locked(sink, msg)

        return cb

    def _on_state(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        try:
            st = RobotState.decode(sample.payload.to_bytes())
        except MessageError:
            return
        self._locked(self.mon.on_state, st, now, self._lower, self._upper)

    def _on_command(self, sample: zenoh.Sample) -> None:
        try:
            cmd = JointCommand.decode(sample.payload.to_bytes())
        except MessageError:
            return
        self._locked(self.mon.on_command, cmd, self._lower, self._upper)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        parsed = Keys.parse_alive(str(sample.key_expr))
        if parsed is None:
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(parsed)
            else:
                self.alive.discard(parsed)
                self.lost.append(parsed)

    def alive_services(self) -> set[str]:
        with self._lock:
            return {s for s, _ in self.alive}

    def summary(self) -> dict:
        with self._lock:
            return self.mon.summary()

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
