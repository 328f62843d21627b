"""Why a fidelity goal is missed: what held the arm on the ticks over the goal's bar.

A goal on a per-tick figure (the wrist or elbow error, the wrist rotation error, the time stuck) is missed because
some ticks are over its bar. On each such tick, per arm, this names what the target asked and what held the robot
back, each a flag of its own (a tick can have several):

* ``target_unreachable``: the IK check could not reach the frame's wrist target (``reachability``);
* ``target_at_body``: the target puts the hand inside the body or within the solver's safety distance of it;
* ``target_too_fast``: reachable in place but not in time, the arm's IK posture change beyond the joint speed cap;
* ``self_collision``: a self-collision damper row held the arm (the hand kept off the body or the other arm);
* ``speed_cap``, ``joint_stop``, ``acceleration``: an arm joint's planned velocity at its speed cap, braking to a
  position stop, or at its acceleration band (``SolverCore.tick_holds``);
* ``frame_step``: within :data:`FRAME_STEP_TICKS` of a frame's arrival, where the extrapolated reference steps by
  what the last frames did not tell (at 30 fps, up to a few cm at a wave's turn).

A tick with none of these is the solver's own trade (``none``: for a level-2 figure, the elbows against the wrist
orientations). Each flag's share of the over-bar ticks is reported beside its share of all the scored ticks
(``base``), since a limit the arm touches all the time explains nothing: the main cause is the flag whose share is
furthest above its base. The waist joints carry both arms, so they are in neither arm's flags.

A goal against a peer's mean (the elbow behind the WQP's or mink's, the wrist behind mink's) is explained the same way
on the ticks where the judged error is above the peer's on the same tick, each weighed by that excess.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from services.evaluation.goals import GOALS
from services.evaluation.metrics import (
    STUCK_ERR,
    per_tick,
    position_errors,
    rotation_errors,
    rotation_ok,
    tick_inside,
    tick_reachable,
)
from services.evaluation.reachability import ReachabilityReport
from services.evaluation.runner import Trace
from services.solver.core import HOLD_ACCELERATION, HOLD_SPEED, HOLD_STOP
from shared.mirror import arm_joints
from shared.robot.pinocchio_model import RobotModel
from shared.targets import SIDES

#: Ticks after a frame's arrival counted as its step (6 ms at 500 Hz: the closing of a step at the wrist gain).
FRAME_STEP_TICKS = 3
#: The causes, in the order they are reported.
CAUSES = (
    "target_unreachable",
    "target_at_body",
    "target_too_fast",
    "self_collision",
    "speed_cap",
    "joint_stop",
    "acceleration",
    "frame_step",
)
#: The name of a tick over the bar that none of :data:`CAUSES` flags.
NONE = "none"


def _position(target: str) -> Callable:
    def figure(trace: Trace, side: str) -> np.ndarray:
        n = f"{side}_{target}"
        err = np.full(len(trace.t), np.nan)
        ok = trace.ref_ok.get(n, np.zeros(len(trace.t), bool))
        err[ok] = 100.0 * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, [n])
        return err

    return figure


def _rotation(trace: Trace, side: str) -> np.ndarray:
    n = f"{side}_wrist"
    err = np.full(len(trace.t), np.nan)
    ok = rotation_ok(trace).get(n, np.zeros(len(trace.t), bool))
    err[ok] = rotation_errors({n: trace.ref_R[n]}, {n: trace.kin_R[n]}, {n: ok})
    return err


#: Per-tick figure name (``Goal.ticks``) -> (trace, side) -> (K,) that arm's error on each tick in the goal's unit
#: ([cm], [deg]), NaN where the figure scores no error. ``stuck`` is the wrist's, scored on reachable targets only.
FIGURES: dict[str, Callable] = {
    "wrist_cm": _position("wrist"),
    "elbow_cm": _position("elbow"),
    "rotation_deg": _rotation,
    "stuck": _position("wrist"),
}
#: Per-tick bars of the figures whose goal's bar is not per tick: ``stuck_s`` counts the ticks over STUCK_ERR [cm].
TICK_BARS = {"stuck": 100.0 * STUCK_ERR}


def tick_causes(trace: Trace, robot: RobotModel, report: ReachabilityReport | None) -> dict[str, dict[str, np.ndarray]]:
    """side -> cause -> (K,) bool, each of :data:`CAUSES` the trace has the data for (the target causes need the
    IK check's report; the solver's, its ``holds``)."""
    k = len(trace.t)
    step = np.zeros(k, bool)
    for start in trace.frame_tick:
        step[start : start + FRAME_STEP_TICKS] = True
    none = np.zeros(k, bool)
    if report is not None:
        reach, inside = tick_reachable(trace, report), tick_inside(trace, report)
        near, fast = per_tick(trace, report, report.near_body()), per_tick(trace, report, report.too_fast())
    out = {}
    for s in SIDES:
        c = {}
        if report is not None and s in reach:
            c = {
                "target_unreachable": ~reach[s] & ~inside.get(s, none),
                "target_at_body": near.get(s, none),
                "target_too_fast": fast.get(s, none),
            }
        if trace.holds.shape == (k, robot.nq):
            arm = arm_joints(robot, s)
            holds = trace.holds[:, arm]
            c["self_collision"] = trace.collision_held[:, arm].any(axis=1)
            c["speed_cap"] = (holds == HOLD_SPEED).any(axis=1)
            c["joint_stop"] = (holds == HOLD_STOP).any(axis=1)
            c["acceleration"] = (holds == HOLD_ACCELERATION).any(axis=1)
        c["frame_step"] = step
        out[s] = {name: c[name] for name in CAUSES if name in c}
    return out


def miss_causes(
    trace: Trace,
    robot: RobotModel,
    report: ReachabilityReport | None,
    figure: str,
    bar: float,
    peer: Trace | None = None,
    causes: dict[str, dict[str, np.ndarray]] | None = None,
) -> dict:
    """What held the arms where a goal on a per-tick figure (a key of :data:`FIGURES`) is missed, both arms.

    Without ``peer``: on the ticks over ``bar`` (the figure's :data:`TICK_BARS` where it has one), each counted
    once. With ``peer`` (a goal against its mean, e.g. ``elbow_behind_wqp_cm``): on the ticks where ``trace``'s
    error is above the peer's on the same tick, each weighed by that excess; ``bar`` is then unused. ``causes``:
    :func:`tick_causes` of ``trace`` when the caller has them (one clip's misses share them).

    Returns:
        ``{"ticks_over", "ticks_scored", "weighed_by", "shares": {cause: its share of the over-bar ticks, or of the
        excess}, "base": {cause: share of the scored ticks}, "main": of the causes with a share, the one furthest
        above its base (what the misses have most beyond the arm's usual; ``"none"`` when that is the ticks no cause
        flags; None when nothing was over)}``; ``shares`` and ``base`` hold ``"none"`` too.
    """
    causes = tick_causes(trace, robot, report) if causes is None else causes
    reachable = tick_reachable(trace, report) if report is not None and figure == "stuck" else {}
    bar = TICK_BARS.get(figure, bar)
    over_n, scored_n, total = 0, 0, 0.0
    hits = dict.fromkeys([*CAUSES, NONE], 0.0)
    base = dict.fromkeys([*CAUSES, NONE], 0)
    for s in SIDES:
        err = FIGURES[figure](trace, s)
        scored = np.isfinite(err) & reachable.get(s, True)
        if peer is None:
            weight = (scored & (np.nan_to_num(err) > bar)).astype(float)
        else:
            theirs = FIGURES[figure](peer, s)
            scored &= np.isfinite(theirs)
            weight = np.where(scored, np.maximum(np.nan_to_num(err - theirs), 0.0), 0.0)
        anything = np.zeros(len(trace.t), bool)
        for name, f in causes[s].items():
            hits[name] += float(np.sum(weight[f]))
            base[name] += int(np.sum(f & scored))
            anything |= f
        hits[NONE] += float(np.sum(weight[~anything]))
        base[NONE] += int(np.sum(scored & ~anything))
        over_n += int(np.sum(weight > 0))
        scored_n += int(scored.sum())
        total += float(weight.sum())
    known = [*(n for n in CAUSES if any(n in causes[s] for s in SIDES)), NONE]
    shares = {n: hits[n] / total if total else 0.0 for n in known}
    return {
        "ticks_over": over_n,
        "ticks_scored": scored_n,
        "weighed_by": "ticks over the bar" if peer is None else f"excess over {peer.algo}'s error",
        "shares": shares,
        "base": {n: base[n] / scored_n if scored_n else 0.0 for n in known},
        "main": max((n for n in known if shares[n] > 0), key=lambda n: shares[n] - base[n] / scored_n, default=None),
    }


def explain_misses(goals: dict, traces: dict[str, Trace], robot: RobotModel, report: ReachabilityReport | None) -> None:
    """Add ``causes`` (:func:`miss_causes`) to each missed check of a clip's goals (``goals.clip_goals``) whose
    goal has a per-tick figure; ``traces``: algorithm -> its trace on the clip (the judged one's, and the peer's of
    a goal against a peer; a goal whose traces are missing is left unexplained)."""
    judged = traces.get(goals["algo"])
    if judged is None:
        return
    goal = {g.key: g for g in GOALS if g.ticks}
    causes = None  # the judged trace's flags, computed once for all of the clip's misses
    for key in goals["unmet"]:
        g = goal.get(key)
        if g is None or (g.peer is not None and g.peer not in traces):
            continue
        causes = tick_causes(judged, robot, report) if causes is None else causes
        check = goals["checks"][key]
        peer = traces[g.peer] if g.peer is not None else None
        check["causes"] = miss_causes(judged, robot, report, g.ticks, check["bar"], peer, causes)
