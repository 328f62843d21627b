"""The fidelity bar: which of issue 12's goals each clip of a ``mimic eval`` run meets.

The goals are on the strict HQP (``hqp-nullspace``, the shipped solver) with the kinematic errors of the
commanded joints on all ticks, the safety figures of its run (the MuJoCo run's contacts and clearance when the sim
ran) and, where the run has them, the peers' errors on the same targets. Each goal is data (:data:`GOALS`): a key,
what it reads from the clip's metrics, a comparison and a bar; ``mimic eval --goals FILE`` sets other bars (a TOML
table ``[bars]`` of key = value). A goal whose figure the run did not produce (no mink in ``--algos``, no
orientation in a marker clip's targets) is not judged, and is listed as such.
"""

from __future__ import annotations

import operator
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from services.evaluation.metrics import ELBOW_TIE_CM
from services.evaluation.runner import REFERENCE_ALGO

#: The algorithm the goals judge: the shipped strict HQP.
JUDGED = REFERENCE_ALGO
_OPS: dict[str, Callable[[float, float], bool]] = {"<=": operator.le, ">=": operator.ge, "<": operator.lt}


@dataclass(frozen=True)
class Goal:
    """One goal: ``value(algos) op bar``.

    Attributes:
        key: its name in the JSON and in ``--goals`` files.
        text: what it says, with its unit.
        bar: the default bar.
        op: ``"<="``, ``">="`` or ``"<"`` (value against bar).
        value: the clip's ``algos`` block (algorithm -> metrics) -> the figure, or None when the run has none.
        ticks: the per-tick figure a miss is explained on (``causes.FIGURES``): the ticks over the bar, or with a
            ``peer`` those where the judged algorithm's error is above the peer's; None: a goal on counts.
        peer: the algorithm a goal compares against, or None.
    """

    key: str
    text: str
    bar: float
    op: str
    value: Callable[[dict], float | None]
    ticks: str | None = None
    peer: str | None = None


def _stat(metric: str, stat: str) -> Callable[[dict], float | None]:
    return lambda algos: (algos[JUDGED].get(metric) or {}).get(stat)


def _scalar(metric: str) -> Callable[[dict], float | None]:
    return lambda algos: algos[JUDGED].get(metric)


def _behind(peer: str, metric: str) -> Callable[[dict], float | None]:
    """The judged algorithm's mean of ``metric`` minus the peer's [cm] (None without the peer)."""

    def value(algos: dict) -> float | None:
        ours = (algos[JUDGED].get(metric) or {}).get("mean")
        theirs = (algos.get(peer, {}).get(metric) or {}).get("mean")
        return None if ours is None or theirs is None else ours - theirs

    return value


def _behind_goal(part: str, peer: str, whose: str, bar: float, op: str) -> Goal:
    """``<part>_behind_<peer>_cm``: the judged algorithm's ``part`` (wrist or elbow) error mean minus the peer's."""
    return Goal(
        f"{part}_behind_{peer}_cm",
        f"{part} mean minus {whose} [cm]",
        bar,
        op,
        _behind(peer, f"{part}_err_cm"),
        ticks=f"{part}_cm",
        peer=peer,
    )


GOALS: tuple[Goal, ...] = (
    Goal("wrist_mean_cm", "wrist error mean [cm]", 0.1, "<=", _stat("wrist_err_cm", "mean"), ticks="wrist_cm"),
    Goal("wrist_p99_cm", "wrist error p99 [cm]", 1.0, "<=", _stat("wrist_err_cm", "p99"), ticks="wrist_cm"),
    Goal("elbow_mean_cm", "elbow error mean [cm]", 1.5, "<=", _stat("elbow_err_cm", "mean"), ticks="elbow_cm"),
    Goal("elbow_p99_cm", "elbow error p99 [cm]", 6.0, "<=", _stat("elbow_err_cm", "p99"), ticks="elbow_cm"),
    Goal(
        "wrist_rotation_p99_deg",
        "wrist rotation error p99 [deg]",
        10.0,
        "<=",
        _stat("wrist_rot_err_deg", "p99"),
        ticks="rotation_deg",
    ),
    Goal("stuck_s", "longest time 2 cm off a reachable wrist target [s]", 0.1, "<=", _scalar("stuck_s"), ticks="stuck"),
    Goal("reachable_fraction", "wrist targets an IK check reaches", 0.995, ">=", _scalar("reachable_fraction")),
    Goal("limit_violations", "commands past a position or velocity limit", 0, "<=", _scalar("limit_violations")),
    Goal("acceleration_violations", "commands past an acceleration limit", 0, "<=", _scalar("acceleration_violations")),
    Goal("self_collisions", "steps with an arm in penetration", 0, "<=", _scalar("self_collisions")),
    Goal("min_clearance_cm", "smallest arm clearance [cm]", 1.0, ">=", _scalar("min_clearance_cm")),
    _behind_goal("elbow", "wqp", "the WQP's", ELBOW_TIE_CM, "<="),
    _behind_goal("elbow", "mink", "mink's", ELBOW_TIE_CM, "<="),
    _behind_goal("wrist", "mink", "mink's", 0.0, "<"),
)
GOAL_KEYS = tuple(g.key for g in GOALS)


def load_bars(path: str | Path) -> dict[str, float]:
    """Bars from a TOML file's ``[bars]`` table (key = number; keys of :data:`GOALS`).

    Raises:
        ValueError: unreadable file, no ``[bars]`` table, an unknown key or a bar that is not a finite number;
            one line that says which.
    """
    try:
        raw = tomllib.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"goals file {str(path)!r}: {exc}") from None
    bars = raw.get("bars")
    if not isinstance(bars, dict) or not bars:
        raise ValueError(f"goals file {str(path)!r}: needs a [bars] table of goal = bar; goals: {list(GOAL_KEYS)}")
    unknown = sorted(set(bars) - set(GOAL_KEYS))
    if unknown:
        raise ValueError(f"goals file {str(path)!r}: unknown goals {unknown}; known: {list(GOAL_KEYS)}")
    bad = {k: v for k, v in bars.items() if isinstance(v, bool) or not isinstance(v, int | float) or v != v}
    if bad:
        raise ValueError(f"goals file {str(path)!r}: bars must be numbers, got {bad}")
    return {k: float(v) for k, v in bars.items()}


def clip_goals(algos: dict, bars: dict[str, float] | None = None) -> dict | None:
    """The goals of one clip from its ``algos`` block (None when :data:`JUDGED` did not run on it).

    Returns:
        ``{"algo", "checks": {key: {"value", "bar", "op", "met"}}, "unmet": [keys], "not_judged": [keys],
        "all_met"}``; ``all_met`` is over the judged goals.
    """
    if JUDGED not in algos:
        return None
    bars = bars or {}
    checks, unmet, not_judged = {}, [], []
    for g in GOALS:
        v = g.value(algos)
        if v is None:
            not_judged.append(g.key)
            continue
        bar = bars.get(g.key, g.bar)
        met = bool(_OPS[g.op](v, bar))
        checks[g.key] = {"value": float(v), "bar": bar, "op": g.op, "met": met}
        if not met:
            unmet.append(g.key)
    return {"algo": JUDGED, "checks": checks, "unmet": unmet, "not_judged": not_judged, "all_met": not unmet}


def goals_summary(per_clip: dict[str, dict]) -> dict:
    """Over clips (name -> :func:`clip_goals` result): how many meet every judged goal, and per goal how many
    clips it was judged on and met on, with the names of those it was not met on."""
    rows = {name: g for name, g in per_clip.items() if g is not None}
    per_goal = {}
    for key in GOAL_KEYS:
        judged = [name for name, g in rows.items() if key in g["checks"]]
        missed = [name for name in judged if not rows[name]["checks"][key]["met"]]
        if judged:
            per_goal[key] = {"judged": len(judged), "met": len(judged) - len(missed), "unmet_clips": missed}
            why = {name: main_cause(rows[name]["checks"][key]) for name in missed}
            if any(why.values()):  # the missed clips' main causes (causes.explain_misses), where explained
                per_goal[key]["main_causes"] = {name: w for name, w in why.items() if w}
    return {
        "algo": JUDGED,
        "clips": len(rows),
        "all_met": sum(g["all_met"] for g in rows.values()),
        "goals": per_goal,
    }


def goals_lines(summary: dict) -> list[str]:
    """A few lines for the log: clips meeting every goal, then each goal missed somewhere and on which clips."""
    out = [f"fidelity goals ({summary['algo']}): {summary['all_met']} of {summary['clips']} clips meet every one"]
    for key, g in summary["goals"].items():
        if g["unmet_clips"]:
            out.append(f"  {key}: met on {g['met']} of {g['judged']}; not on {', '.join(unmet_labels(g))}")
    return out


def unmet_labels(row: dict) -> list[str]:
    """The clips a goal was missed on (a ``summary.goals.goals`` row), each with its main cause where the miss was
    explained, that cause's share where the goal is missed and over all ticks: ``"clip [self_collision 83 % vs 26
    %]"``."""
    why = row.get("main_causes", {})
    return [f"{c} [{_cause_text(why[c])}]" if c in why else c for c in row["unmet_clips"]]


def missed_goal_labels(goals: dict) -> list[str]:
    """The goals one clip missed (a :func:`clip_goals` block), each with its main cause where it was explained:
    ``"wrist_rotation_p99_deg [acceleration 100 % vs 41 %]"``."""
    labels = []
    for key in goals["unmet"]:
        why = main_cause(goals["checks"][key])
        labels.append(f"{key} [{_cause_text(why)}]" if why else key)
    return labels


def _cause_text(why: dict) -> str:
    """``"self_collision 83 % vs 26 %"``: a main cause, its share where the goal is missed and over all ticks."""
    return f"{why['cause']} {100 * why['share']:.0f} % vs {100 * why['base']:.0f} %"


def main_cause(check: dict) -> dict | None:
    """``{"cause", "share", "base"}``: the main cause of a missed goal, its share where the goal is missed and its
    share of all scored ticks (None when the miss has no explanation)."""
    why = check.get("causes")
    if not why or why["main"] is None:
        return None
    return {"cause": why["main"], "share": why["shares"][why["main"]], "base": why["base"][why["main"]]}
