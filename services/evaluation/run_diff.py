"""Two ``mimic eval`` runs side by side: per clip and algorithm, what a change of settings or code moved.

A change to the solver moves some clips one way and others the other (the HQP's elbow is path dependent: a
different start-up or damping puts an arm on another branch for the whole clip), so a summary mean alone hides
what happened. :func:`diff_runs` pairs the clips of two JSON reports by name and gives, for every algorithm both
ran, each headline metric before and after, the clips that moved by more than a threshold, and the settings
that differ (what was changed between the runs).
"""

from __future__ import annotations

import math

from services.evaluation.goals import GOAL_KEYS, JUDGED, clip_goals, main_cause, unmet_labels

#: Compared metrics: (name in the report, statistic or None for a number, unit, the smallest change [unit] that
#: counts as a move, so that the threshold's share of a near-zero value does not). All are lower-is-better.
METRICS: tuple[tuple[str, str | None, str, float], ...] = (
    ("wrist_err_cm", "mean", "cm", 0.01),
    ("wrist_err_cm", "p99", "cm", 0.01),
    ("elbow_err_cm", "mean", "cm", 0.01),
    ("elbow_err_cm", "p99", "cm", 0.01),
    ("wrist_rot_err_deg", "p99", "deg", 0.5),
    ("wrist_err_cm_sim", "mean", "cm", 0.01),
    ("elbow_err_cm_sim", "mean", "cm", 0.01),
    ("wrist_rot_err_deg_sim", "p99", "deg", 0.5),
    ("stuck_s", None, "s", 0.01),
    ("self_collisions", None, "ticks", 0.5),
    ("limit_violations", None, "ticks", 0.5),
    ("jerk_rms", None, "rad/s^3", 100.0),
    ("waist_speed_rms", None, "rad/s", 0.01),
)

#: The metrics whose moves are counted per clip (``moved``): the ones issue-level goals are stated in.
HEADLINE = ("wrist_err_cm.mean", "elbow_err_cm.mean", "wrist_rot_err_deg.p99", "wrist_err_cm_sim.mean",
            "elbow_err_cm_sim.mean")  # fmt: skip


class RunDiffError(ValueError):
    """A report that is not a ``mimic eval`` JSON, or algorithms neither run has; one-line text."""


def metric_key(name: str, stat: str | None) -> str:
    """``elbow_err_cm.mean`` for a statistic of an error block, the name alone for a number."""
    return f"{name}.{stat}" if stat else name


def _value(m: dict, name: str, stat: str | None) -> float | None:
    v = m.get(name)
    if stat is not None:
        v = v.get(stat) if isinstance(v, dict) else None
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        return None
    return float(v)


def _clips(report: dict, label: str) -> dict[str, dict]:
    """Clip name -> {algorithm: metrics} of a report (``label`` names it in errors)."""
    clips = report.get("clips") if isinstance(report, dict) else None
    if not isinstance(clips, list) or not all(isinstance(c, dict) and "clip" in c and "algos" in c for c in clips):
        raise RunDiffError(f"{label}: not a mimic eval report (no clips[] with clip and algos)")
    return {c["clip"]: c["algos"] for c in clips}


def _flat(d: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat(v, f"{key}."))
        else:
            out[key] = v
    return out


def settings_diff(base: dict, new: dict) -> dict[str, list]:
    """Settings that differ between the runs: flattened key -> [base, new] (absent: None); the wall time left out."""
    a, b = _flat(base.get("settings") or {}), _flat(new.get("settings") or {})
    keys = [k for k in dict.fromkeys([*a, *b]) if k != "wall_s" and a.get(k) != b.get(k)]
    return {k: [a.get(k), b.get(k)] for k in keys}


def diff_runs(base: dict, new: dict, algos: list[str] | None = None, threshold: float = 0.05) -> dict:
    """Compare two ``mimic eval`` reports.

    Args:
        base, new: the parsed JSON reports (``clips[]`` with ``clip`` and ``algos``).
        algos: algorithms to compare (None: every one both runs have, in the base run's order).
        threshold: a headline metric counts as moved on a clip when it changed by more than this share of its
            base value and by more than its floor in :data:`METRICS`.

    Returns:
        ``clips``: clip -> algorithm -> metric key -> [base, new, new - base] (None where either run lacks it);
        ``moved``: algorithm -> headline metric -> {"better": [clips], "worse": [clips]};
        ``means``: algorithm -> metric key -> [base, new], plain means over the clips both runs have with a value;
        ``only_base`` / ``only_new``: clips one run has; ``settings``: :func:`settings_diff`; ``goals``:
        :func:`goals_diff` (None unless both runs have the judged algorithm on a shared clip).

    Raises:
        RunDiffError: a report is not an eval report, they share no clip, or an asked algorithm is missing.
    """
    a, b = _clips(base, "base"), _clips(new, "new")
    shared = [c for c in a if c in b]
    if not shared:
        raise RunDiffError("the two reports have no clip in common")
    common = [x for x in a[shared[0]] if all(x in a[c] and x in b[c] for c in shared)]
    if algos is None:
        algos = common
    missing = [x for x in algos if x not in common]
    if missing:
        raise RunDiffError(f"algorithm(s) {missing} not run on every shared clip by both reports; both have {common}")
    clips: dict = {}
    moved = {x: {k: {"better": [], "worse": []} for k in HEADLINE} for x in algos}
    sums: dict = {x: {} for x in algos}
    for c in shared:
        clips[c] = {}
        for x in algos:
            row = {}
            for name, stat, _, floor in METRICS:
                key = metric_key(name, stat)
                u, v = _value(a[c][x], name, stat), _value(b[c][x], name, stat)
                row[key] = [u, v, None if u is None or v is None else v - u]
                if u is None or v is None:
                    continue
                s = sums[x].setdefault(key, [0.0, 0.0, 0])
                s[0], s[1], s[2] = s[0] + u, s[1] + v, s[2] + 1
                if key in moved[x] and abs(v - u) > max(threshold * abs(u), floor):
                    moved[x][key]["better" if v < u else "worse"].append(c)
            clips[c][x] = row
    means = {x: {k: [s[0] / s[2], s[1] / s[2]] for k, s in sums[x].items()} for x in algos}
    return {
        "clips": clips,
        "moved": moved,
        "means": means,
        "only_base": [c for c in a if c not in b],
        "only_new": [c for c in b if c not in a],
        "settings": settings_diff(base, new),
        "threshold": threshold,
        "goals": goals_diff({c: a[c] for c in shared}, {c: b[c] for c in shared}, _stored_goals(new)),
    }


def _stored_goals(report: dict) -> dict[str, dict]:
    """Clip -> the goals block the run wrote (``goals.clip_goals``, with its misses' causes), where it wrote one."""
    return {c["clip"]: c["goals"] for c in report["clips"] if isinstance(c.get("goals"), dict)}


def goals_diff(base: dict[str, dict], new: dict[str, dict], new_goals: dict[str, dict] | None = None) -> dict | None:
    """The fidelity goals (:mod:`.goals`, default bars, recomputed from each run's metrics, so reports written
    before the goals existed compare too) on the clips both runs judged: how many meet every goal before and after,
    and per goal the clips it is newly met and newly missed on.

    Args:
        base, new: clip -> its ``algos`` block, the same clips in both.
        new_goals: clip -> the goals block the new run wrote: a newly missed goal whose check there was judged at
            the same bar and explained (``causes``) gets its main cause in ``newly_missed_causes``.
    """
    before = {c: clip_goals(algos) for c, algos in base.items()}
    after = {c: clip_goals(new[c]) for c in base}
    both = [c for c in base if before[c] is not None and after[c] is not None]
    if not both:
        return None
    met: dict[str, list[str]] = {}
    missed: dict[str, list[str]] = {}
    for c in both:
        for key in GOAL_KEYS:
            u, v = before[c]["checks"].get(key), after[c]["checks"].get(key)
            if u is not None and v is not None and u["met"] != v["met"]:
                (met if v["met"] else missed).setdefault(key, []).append(c)
    why: dict[str, dict[str, dict]] = {}
    for key, clips in missed.items():
        for c in clips:
            stored = (new_goals or {}).get(c, {}).get("checks", {}).get(key, {})
            cause = main_cause(stored) if stored.get("bar") == after[c]["checks"][key]["bar"] else None
            if cause is not None:
                why.setdefault(key, {})[c] = cause
    return {
        "algo": JUDGED,
        "clips": len(both),
        "all_met": [sum(before[c]["all_met"] for c in both), sum(after[c]["all_met"] for c in both)],
        "newly_met": met,
        "newly_missed": missed,
        "newly_missed_causes": why,
    }


def _num(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3f}" if abs(v) < 100 else f"{v:.0f}"


def format_diff(diff: dict) -> str:
    """The diff as text: changed settings, one line per clip and algorithm with the headline metrics
    ``base -> new`` (``*`` where one moved past the threshold), the clips each run alone has, and the means."""
    lines = ["settings changed: " + (", ".join(f"{k} {v[0]!r} -> {v[1]!r}" for k, v in diff["settings"].items())
                                     or "none")]  # fmt: skip
    heads = ", ".join(HEADLINE)
    lines.append(f"per clip and algorithm, base -> new ({heads}); * moved by more than {diff['threshold']:.0%}")
    for c, per in diff["clips"].items():
        for x, row in per.items():
            cells = []
            for k in HEADLINE:
                u, v, _ = row[k]
                mark = "*" if c in diff["moved"][x][k]["better"] + diff["moved"][x][k]["worse"] else " "
                cells.append(f"{_num(u)}->{_num(v)}{mark}")
            lines.append(f"{c[:34]:34s} {x:16s} " + "  ".join(cells))
    for key in ("only_base", "only_new"):
        if diff[key]:
            lines.append(f"{key.replace('_', ' in ')}: {', '.join(diff[key])}")
    g = diff.get("goals")
    if g:
        u, v = g["all_met"]
        lines.append(f"fidelity goals ({g['algo']}): every goal met on {u} -> {v} of {g['clips']} shared clips")
        for goal, clips in g["newly_met"].items():
            lines.append(f"  newly met: {goal} on {', '.join(clips)}")
        for goal, clips in g["newly_missed"].items():
            row = {"unmet_clips": clips, "main_causes": g.get("newly_missed_causes", {}).get(goal, {})}
            lines.append(f"  newly missed: {goal} on {', '.join(unmet_labels(row))}")
    for x, ms in diff["means"].items():
        lines.append(f"{x}: means over clips, base -> new")
        for name, stat, unit, _ in METRICS:
            key = metric_key(name, stat)
            if key in ms:
                u, v = ms[key]
                mv = diff["moved"][x].get(key)
                counts = f"  better on {len(mv['better'])}, worse on {len(mv['worse'])}" if mv else ""
                lines.append(f"  {key:24s} {_num(u):>9s} -> {_num(v):>9s} {unit}{counts}")
    return "\n".join(lines)
