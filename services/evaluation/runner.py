"""Offline evaluation: the services' own code path (retarget -> solve -> sim), no bus.

For each clip the retargeter is calibrated the way the live service does it
(from the operator's first frame, arms hanging), every mocap frame is
retargeted once, and the solver runs at its control rate between frames
exactly as the node does (targets delivered on arrival, extrapolated with
their velocities in between). Optionally the MuJoCo sim follows the commands
in lock-step, its joints fed back as the measured state (the node's robot state,
without its transport delay), so the command stays within ``max_command_lead``
of where the robot is, as in the live stack.

Errors are measured at every control tick against the reference the solver
was given at that tick (the retargeted target, extrapolated from its frame
with its velocity) at the instant the tick's command is for (t + dt):
"kinematic" uses the forward kinematics of the commanded joints, "sim" the
poses MuJoCo reached after the tick. A tick counts as *reachable* when the
strict hierarchy (``hqp-nullspace``) meets the wrist level there (level-1
residual below tolerance); the same tick mask is applied to every algorithm.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from services.evaluation.mink_peer import MINK_LIMITED, PEERS, MinkPeer
from services.ingest.clip import Clip, load_clip
from services.ingest.variants import mirrored, played_at
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.solver.core import SolverConfig, SolverCore
from services.solver.qp import make_backend
from services.solver.targets import TargetTracker
from services.solver.wqp import WeightedQp
from shared.messages import TaskTargets
from shared.robot.pinocchio_model import RobotModel, build_robot_model
from shared.rotations import quat_to_matrix
from shared.targets import ELBOWS, TARGET_NAMES, WRISTS, side_of

log = logging.getLogger("mimic.eval")
REFERENCE_ALGO = "hqp-nullspace"
#: Seconds the first frame is held before a clip plays (``run_algorithm``'s ``settle``; ``mimic eval --settle``).
SETTLE = 0.5
#: (3,) "no value" for a tick's missing position (read-only: shared by every row it fills).
_NAN3 = np.full(3, np.nan)
_NAN3.flags.writeable = False
#: Sim ticks between two clearance measurements (mj_geomDistance over every pair costs ~ms).
CLEARANCE_EVERY = 10


@dataclass
class Trace:
    """Per-tick record of one algorithm on one clip.

    Attributes:
        t: (K,) solver time [s]. seq: (K,) seq of the latest frame.
        ref_p: target -> (K, 3) reference [m]; ref_R: wrist -> (K, 3, 3).
        kin_p / sim_p: target -> (K, 3) achieved [m]; kin_R / sim_R: wrist -> (K, 3, 3).
        ref_ok: target -> (K,) reference valid (not held).
        ref_rot: wrist -> (K,) the reference carries an orientation to track (``use_rotation``; False for a
            source without measured orientations): the rotation error is scored on these ticks only.
        q, qd: (K, n) commanded joints [rad], [rad/s]. solve_ms: (K,). status: (K,) str.
        res1: (K,) level-1 residual.
        collide: (K,) bool, an arm in penetration (sim contacts; kinematic clearance < 0 without sim,
            on the clearance ticks only). clearance: (K,) smallest arm clearance [m] (NaN between
            clearance ticks). dt: control period [s].
        frame_tick: (F,) index of the scored tick each frame arrived on; frame_seq: (F,) its seq;
            frame_p: target -> (F, 3) the frame's own target position [m] (no extrapolation); frame_ok:
            target -> (F,) valid. frame_R: wrist -> (F, 3, 3) the frame's own wrist orientation; frame_rot: wrist ->
            (F,) valid and carrying an orientation to track.
        holds: (K, n) int8, what held each joint's raw velocity on each tick (``SolverCore.tick_holds`` codes:
            free, acceleration band, speed cap, braking to a stop); collision_held: (K, n) bool, the joints a
            binding self-collision damper row acted on. Both empty for a peer without them (mink).
        policy_p: elbow -> (K, 3) [m] the elbow target an elbow-kind posture policy gave that arm's elbow task,
            advanced to the instant the tick's command is for (NaN on ticks the arm was not policy-driven);
            empty when no tick was.
    """

    algo: str
    t: np.ndarray
    seq: np.ndarray
    ref_p: dict[str, np.ndarray]
    ref_R: dict[str, np.ndarray]
    ref_ok: dict[str, np.ndarray]
    kin_p: dict[str, np.ndarray]
    kin_R: dict[str, np.ndarray]
    q: np.ndarray
    qd: np.ndarray
    solve_ms: np.ndarray
    status: np.ndarray
    res1: np.ndarray
    sim_p: dict[str, np.ndarray] = field(default_factory=dict)
    sim_R: dict[str, np.ndarray] = field(default_factory=dict)
    collide: np.ndarray | None = None
    clearance: np.ndarray | None = None
    frame_tick: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    frame_seq: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    frame_p: dict[str, np.ndarray] = field(default_factory=dict)
    frame_ok: dict[str, np.ndarray] = field(default_factory=dict)
    frame_R: dict[str, np.ndarray] = field(default_factory=dict)
    frame_rot: dict[str, np.ndarray] = field(default_factory=dict)
    ref_rot: dict[str, np.ndarray] = field(default_factory=dict)
    dt: float = 0.002
    counts: dict[str, int] = field(default_factory=dict)
    policy_p: dict[str, np.ndarray] = field(default_factory=dict)
    holds: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int8))
    collision_held: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))


def clip_targets(clip: Clip, retargeter: Retargeter) -> list[TaskTargets]:
    """Retarget every frame of a clip (frames the retargeter drops are left out)."""
    out = []
    for i in range(clip.n_frames):
        tt = retargeter.step(clip.frame(i, seq=i, t0_ns=0))
        if tt is not None:
            out.append(tt)
    return out


def run_algorithm(
    robot: RobotModel,
    targets: list[TaskTargets],
    algo: str,
    qp: str = "piqp",
    rate: float = 500.0,
    sim: bool = False,
    settle: float = SETTLE,
    solver: dict | None = None,
    wqp_weights: tuple[float, ...] | None = None,
    collisions: bool = True,
    wrist_only: bool = False,
) -> Trace:
    """Solve a target stream at ``rate`` Hz; returns the per-tick trace.

    Args:
        targets: retargeted frames; ``hdr.stamp`` [s] is their arrival time.
        settle: seconds the first frame is held before the clip plays, so the robot
            can move from its rest pose to the operator's start pose (not scored).
        solver: further :class:`SolverConfig` fields (e.g. ``wrist_orientation_level``).
        wqp_weights: level weights of ``wqp`` (default: :class:`WeightedQp`'s); e.g. ``(1, 0.01, 1)``
            for a "traditional QP" that all but ignores the elbows.
        collisions: record self-collisions and clearances (:mod:`.collisions`).
        wrist_only: the solver gets the wrist targets only (:func:`wrist_only_targets`); errors are
            still measured against the full targets (the operator's retargeted elbows).
    """
    if algo in PEERS:
        core = MinkPeer(robot, rate, limited=algo == MINK_LIMITED, config=SolverConfig(**(solver or {})))
    else:
        core = _solver_core(robot, algo, qp, rate, solver, wqp_weights)
    simcore = _sim_core(robot) if sim else None
    dt = 1.0 / rate
    coll = None
    if collisions:
        from services.evaluation.collisions import SelfCollision

        coll = SelfCollision(robot.profile, simcore.joint_names if simcore is not None else robot.joint_names)
    # The reference the errors are measured against: the full targets, even when the solver sees less.
    reference = TargetTracker.for_solver(core.config)
    fed = {id(tt): w for tt, w in zip(targets, wrist_only_targets(targets))} if wrist_only else None
    rec = _Recorder(robot, core, simcore, reference, coll)
    # The sim's joints go back to the solver as the node's robot state does (``max_command_lead``): open loop, a
    # sim lagging a dash at 1.25x by 8-9 cm touched the torso where the command kept 4.4 cm (session 25).
    measured = [simcore.joint_names.index(n) for n in robot.joint_names] if simcore is not None else None
    for t, msg in _arrivals(targets, settle, dt):
        if msg is not None:
            if t >= settle:
                rec.frame(msg)
            reference.update(msg, t)
            if fed is not None:
                msg = fed.get(id(msg)) or wrist_only_targets([msg])[0]
        cmd = core.step(msg, None if simcore is None else simcore.q[measured], t)
        if simcore is not None:
            simcore.advance(cmd, dt)  # the sim maps commands by joint name
        if t >= settle:
            rec.tick(t, settle, dt, cmd)
    return rec.trace(algo, dt)


def _solver_core(
    robot: RobotModel,
    algo: str,
    qp: str,
    rate: float,
    solver: dict | None,
    wqp_weights: tuple[float, ...] | None,
) -> SolverCore:
    """The solver as the node builds it, at the rest pose (``wqp`` with ``wqp_weights`` if given)."""
    core = SolverCore(robot, SolverConfig(algo=algo, qp=qp, rate=rate, solver_id="eval", **(solver or {})))
    if algo == "wqp" and wqp_weights is not None:
        core.algorithm = WeightedQp(make_backend(qp), level_weights=wqp_weights, eps=core.config.damping)
    core.reset(robot.q_rest)
    return core


def _sim_core(robot: RobotModel):
    """The MuJoCo sim of the robot, following the commands in lock-step."""
    from services.sim.sim_core import SimConfig, SimCore

    return SimCore(robot.profile, SimConfig(solver_id="eval"))


def _arrivals(targets: list[TaskTargets], settle: float, dt: float) -> Iterator[tuple[float, TaskTargets | None]]:
    """(tick time [s], frame arriving at that tick or None) for every control tick of the clip.

    The first frame is given at rest (zero velocities) on tick 0 and held through ``settle``; then
    each frame arrives on the first tick at or after ``stamp + settle``; the ticks run one 30 fps
    frame period past the last arrival.
    """
    stamps = np.array([tt.hdr.stamp for tt in targets]) + settle
    n_ticks = int(np.ceil((stamps[-1] + 1.0 / 30.0) / dt))
    k_next = 0
    for tick in range(n_ticks):
        t = tick * dt
        msg = None
        if t < settle:
            msg = _at_rest(targets[0]) if tick == 0 else None  # held: no extrapolation away from it
        else:
            while k_next < len(targets) and stamps[k_next] <= t + 1e-12:
                msg = targets[k_next]
                k_next += 1
        yield t, msg


class _Recorder:
    """Collects one scored tick at a time: references, kinematic and sim poses, commands."""

    def __init__(
        self, robot: RobotModel, core, simcore=None, reference: TargetTracker | None = None, coll=None
    ) -> None:
        self.robot, self.core, self.simcore, self.coll = robot, core, simcore, coll
        self.reference = core.tracker if reference is None else reference
        self.rec: dict[str, list] = {k: [] for k in ("t", "seq", "q", "qd", "ms", "status", "res1", "collide", "clear")}
        self.ref_p = {n: [] for n in TARGET_NAMES}
        self.ref_R = {n: [] for n in WRISTS}
        self.ref_rot = {n: [] for n in WRISTS}
        self.ref_ok = {n: [] for n in TARGET_NAMES}
        self.kin_p = {n: [] for n in TARGET_NAMES}
        self.kin_R = {n: [] for n in WRISTS}
        self.sim_p = {n: [] for n in TARGET_NAMES}
        self.sim_R = {n: [] for n in WRISTS}
        self.frame_tick: list[int] = []
        self.frame_seq: list[int] = []
        self.frame_p = {n: [] for n in TARGET_NAMES}
        self.frame_ok = {n: [] for n in TARGET_NAMES}
        self.frame_R = {n: [] for n in WRISTS}
        self.frame_rot = {n: [] for n in WRISTS}
        self.policy_p: dict[str, list] = {n: [] for n in ELBOWS}
        #: the solver's own account of what held each joint, per tick (a peer without ``tick_holds`` has none)
        self.holds: list[tuple[np.ndarray, np.ndarray]] | None = [] if hasattr(core, "tick_holds") else None

    def frame(self, msg: TaskTargets) -> None:
        """A frame arriving on the tick about to be recorded: its own targets, for the frame errors."""
        self.frame_tick.append(len(self.rec["t"]))
        self.frame_seq.append(msg.hdr.seq)
        for n in TARGET_NAMES:
            tg = msg.targets.get(n)
            self.frame_ok[n].append(tg is not None and tg.valid)
            self.frame_p[n].append(tg.p if tg is not None else _NAN3)
            if n in self.frame_R:
                self.frame_rot[n].append(tg is not None and tg.valid and tg.use_rotation)
                self.frame_R[n].append(quat_to_matrix(tg.q) if tg is not None else np.eye(3))

    def tick(self, t: float, settle: float, dt: float, cmd) -> None:
        """Record the command of tick ``t`` [s] (clip time ``t - settle``)."""
        poses = self.robot.frame_poses(cmd.q)
        for n in TARGET_NAMES:
            # The command of tick t is the pose for t + dt (the sim reaches it over the next tick,
            # the solver's feed-forward aims there): score it against the reference at t + dt as
            # the solver saw it (no newer frame). Sampling at t would add |v| dt of pure time shift.
            s = self.reference.sample(n, t + dt)
            self.ref_ok[n].append(s is not None and not s.held)
            self.ref_p[n].append(s.p if s is not None else _NAN3)
            self.kin_p[n].append(poses[n][0])
            if n in self.ref_R:
                self.ref_R[n].append(s.R if s is not None else np.eye(3))
                self.ref_rot[n].append(s is not None and s.use_rotation)
                self.kin_R[n].append(poses[n][1])
        # The elbow-kind policy's target of this tick (p, v), at t + dt like the reference: the prediction's own
        # error and the robot's distance from it split the elbow error (metrics.trace_metrics).
        aimed = getattr(self.core, "policy_elbow", {})
        for n in ELBOWS:
            e = aimed.get(side_of(n))
            self.policy_p[n].append(e[0] + dt * e[1] if e is not None else _NAN3)
        if self.simcore is not None:
            for n, pose in self.simcore.frame_poses().items():
                self.sim_p[n].append(pose.p)
                if n in self.sim_R:
                    self.sim_R[n].append(quat_to_matrix(pose.q))
        for key, value in (
            ("t", t - settle),
            ("seq", cmd.hdr.seq),
            ("q", cmd.q),
            ("qd", cmd.qd),
            ("ms", cmd.solve_ms),
            ("status", cmd.status),
            ("res1", cmd.residuals[0] if cmd.residuals else np.nan),
        ):
            self.rec[key].append(value)
        if self.holds is not None:
            self.holds.append(self.core.tick_holds())
        if self.coll is not None:
            c = np.nan
            if (len(self.rec["t"]) - 1) % CLEARANCE_EVERY == 0:
                # the sim's reached joints when it runs (what a camera would see), else the command
                c = self.coll.clearance(self.simcore.q if self.simcore is not None else cmd.q)
            self.rec["clear"].append(c)
            hit = self.coll.penetrating(self.simcore.robot.data) if self.simcore is not None else bool(c < 0)
            self.rec["collide"].append(hit)

    def trace(self, algo: str, dt: float) -> Trace:
        def arr(d):
            return {k: np.asarray(v) for k, v in d.items() if len(v)}

        rec = {k: np.asarray(v) for k, v in self.rec.items()}
        return Trace(
            algo=algo,
            t=rec["t"],
            seq=rec["seq"],
            ref_p=arr(self.ref_p),
            ref_R=arr(self.ref_R),
            ref_ok=arr(self.ref_ok),
            ref_rot=arr(self.ref_rot),
            kin_p=arr(self.kin_p),
            kin_R=arr(self.kin_R),
            q=rec["q"],
            qd=rec["qd"],
            solve_ms=rec["ms"],
            status=rec["status"],
            res1=rec["res1"],
            sim_p=arr(self.sim_p),
            sim_R=arr(self.sim_R),
            collide=rec["collide"].astype(bool) if self.coll is not None else None,
            clearance=rec["clear"].astype(float) if self.coll is not None else None,
            frame_tick=np.asarray(self.frame_tick, dtype=int),
            frame_seq=np.asarray(self.frame_seq, dtype=int),
            frame_p=arr(self.frame_p),
            frame_ok=arr(self.frame_ok),
            frame_R=arr(self.frame_R),
            frame_rot=arr(self.frame_rot),
            dt=dt,
            counts=dict(self.core.counts),
            policy_p={n: np.asarray(v) for n, v in self.policy_p.items() if np.isfinite(v).any()},
            **self._holds(),
        )

    def _holds(self) -> dict[str, np.ndarray]:
        """The ``holds`` and ``collision_held`` arrays of the trace (none when the algorithm has no account)."""
        if not self.holds:
            return {}
        holds, collision = zip(*self.holds)
        return {"holds": np.array(holds, dtype=np.int8), "collision_held": np.array(collision, dtype=bool)}


def wrist_only_targets(targets: list[TaskTargets]) -> list[TaskTargets]:
    """What a wrist-only source gives the solver: the same wrist targets, elbows invalid, no upper arms, no waist."""
    out = []
    for tt in targets:
        tg = {n: (replace(t, valid=False, v=np.zeros(3), w=np.zeros(3)) if n in ELBOWS else t)
              for n, t in tt.targets.items()}  # fmt: skip
        out.append(replace(tt, targets=tg, upper_arms={}, waist=np.zeros(0)))
    return out


def _at_rest(tt: TaskTargets) -> TaskTargets:
    """The same targets with zero linear and angular velocity."""
    zero = np.zeros(3)
    targets = {n: replace(t, v=zero.copy(), w=zero.copy()) for n, t in tt.targets.items()}
    return replace(tt, targets=targets)


def load_and_retarget(
    path: Path,
    robot: RobotModel,
    mode: str | None = None,
    retarget: dict | None = None,
    skeleton_map: str | Path | None = None,
    mirror: bool = False,
    speed: float = 1.0,
) -> tuple[Clip, list[TaskTargets]]:
    """Load a clip and retarget it with a freshly calibrated retargeter (as the live service does).

    Args:
        mode: mapping mode (None: the service default, ``RetargetConfig().mode``).
        retarget: further :class:`RetargetConfig` fields (default: none, the service's own settings).
        skeleton_map: BVH skeleton map / C3D marker map file, as ``mimic publish --skeleton-map``.
        mirror: retarget the clip's mirror image (:func:`~services.ingest.variants.mirrored`).
        speed: play the clip this many times as fast (:func:`~services.ingest.variants.played_at`).

    Raises:
        ClipError (incl. SkeletonMapError): unreadable clip or a rig no map fits; one-line text.
        ValueError: ``speed`` not a finite number > 0.
    """
    clip = load_clip(path, skeleton_map=skeleton_map)
    if mirror:
        clip = mirrored(clip)
    if speed != 1.0:
        clip = played_at(clip, speed)
    fields = dict(retarget or {})
    if mode is not None:
        fields["mode"] = mode
    cfg = RetargetConfig(robot=str(robot.profile.source), **fields)
    retargeter = Retargeter(cfg, robot=_arms_model(robot))
    t0 = time.perf_counter()
    targets = clip_targets(clip, retargeter)
    log.debug("%s: %d frames retargeted in %.2f s", clip.name, len(targets), time.perf_counter() - t0)
    if not targets:
        raise RuntimeError(f"{path}: no frame could be retargeted (rejects: {dict(retargeter.rejects)})")
    return clip, targets


_ARMS: dict[str, RobotModel] = {}


def _arms_model(robot: RobotModel) -> RobotModel:
    """The retargeter samples its workspace over the arms only (waist at rest), like the service."""
    key = str(robot.profile.source)
    if key not in _ARMS:
        _ARMS[key] = build_robot_model(robot.profile, with_waist=False)
    return _ARMS[key]
