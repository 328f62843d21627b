"""Fig. 9-style plots and a Markdown report of an evaluation run."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from services.evaluation.goals import GOALS, missed_goal_labels, unmet_labels
from services.evaluation.runner import Trace
from shared.targets import SIDES, elbow_of, wrist_of

AXES = "xyz"


def _rpy(R: np.ndarray) -> np.ndarray:
    """(K, 3, 3) rotations -> (K, 3) roll, pitch, yaw [deg] (ZYX convention), unwrapped."""
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    pitch = -np.arcsin(np.clip(R[:, 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    return np.degrees(np.unwrap(np.stack([roll, pitch, yaw], axis=1), axis=0))


def _finish(fig, axs, path: Path, title: str) -> None:
    """Legend on the top panel, time axis on the bottom one, title; save as PNG and free the figure."""
    axs[0].legend(fontsize=7, ncol=2)
    axs[-1].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _xyz_plot(path: Path, traces: dict[str, Trace], target: str, title: str) -> None:
    fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    ref = next(iter(traces.values()))
    for i, ax in enumerate(axs):
        ax.plot(ref.t, ref.ref_p[target][:, i] * 100, "k--", lw=1.5, label="input (target)")
        for algo, tr in traces.items():
            ax.plot(tr.t, tr.kin_p[target][:, i] * 100, lw=1, label=f"output {algo}")
        ax.set_ylabel(f"{AXES[i]} [cm]")
    _finish(fig, axs, path, title)


def _rpy_plot(path: Path, traces: dict[str, Trace], target: str, title: str, use_ref: bool) -> None:
    fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    ref = next(iter(traces.values()))
    if use_ref and target in ref.ref_R:
        rr = _rpy(ref.ref_R[target])
        for i in range(3):
            axs[i].plot(ref.t, rr[:, i], "k--", lw=1.5, label="input (target)")
    for algo, tr in traces.items():
        R = tr.kin_R.get(target)
        if R is None:
            continue
        r = _rpy(R)
        for i in range(3):
            axs[i].plot(tr.t, r[:, i], lw=1, label=f"output {algo}")
    for i, name in enumerate(("roll", "pitch", "yaw")):
        axs[i].set_ylabel(f"{name} [deg]")
    _finish(fig, axs, path, title)


def _elbow_3d(path: Path, traces: dict[str, Trace], target: str, title: str) -> None:
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ref = next(iter(traces.values()))
    p = ref.ref_p[target] * 100
    ax.plot(p[:, 0], p[:, 1], p[:, 2], "k--", lw=1.5, label="input (target)")
    for algo, tr in traces.items():
        q = tr.kin_p[target] * 100
        ax.plot(q[:, 0], q[:, 1], q[:, 2], lw=1, label=algo)
    ax.set_xlabel("x [cm]")
    ax.set_ylabel("y [cm]")
    ax.set_zlabel("z [cm]")
    ax.legend(fontsize=7)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _solve_bar(path: Path, summary: dict, paper: dict[str, float]) -> None:
    algos = list(summary)
    ours = [summary[a]["solve_ms"]["mean"] for a in algos]
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(algos))
    ax.bar(x - 0.2, ours, 0.4, label="mimic (this machine)")
    ax.bar(x + 0.2, [paper.get(a, np.nan) for a in algos], 0.4, label="paper Fig. 9(f)")
    ax.set_xticks(x, algos, rotation=20)
    ax.set_yscale("log")
    ax.set_ylabel("mean solve time per tick [ms]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


PAPER_MS = {"hqp-nullspace": 38.9, "hqp-original": 83.9, "wqp": 136.0}


def _fmt(d: dict | None, key: str = "mean") -> str:
    if not d or d.get(key) is None:
        return "n/a"
    return f"{d[key]:.3f}"


def _goals_section(result: dict) -> list[str]:
    """The fidelity goals (``summary.goals``, :mod:`.goals`) as Markdown: per goal what it asks (with the bar the run
    used), the clips it was met on and those it was not, with the main cause of each miss (:mod:`.causes`); nothing
    when the run judged none."""
    g = result["summary"].get("goals")
    if not g:
        return []
    lines = [f"## Fidelity goals ({g['algo']}): {g['all_met']} of {g['clips']} clips meet every one", ""]
    bars = {k: check["bar"] for c in result["clips"] for k, check in c.get("goals", {}).get("checks", {}).items()}
    goals = {goal.key: goal for goal in GOALS}
    lines += ["| goal | what | met on | not met on |", "|---|---|---|---|"]
    for key, row in g["goals"].items():
        what = f"{goals[key].text} {goals[key].op} {bars[key]:g}"
        missed = ", ".join(unmet_labels(row)) or "-"
        lines.append(f"| {key} | {what} | {row['met']} of {row['judged']} | {missed} |")
    return [*lines, ""]


def write_report(result: dict, traces: dict[tuple[str, str], Trace], out: Path) -> Path:
    """PNG figures per clip (Fig. 9 a-e), the solve-time bar chart (9 f) and ``report.md``."""
    out.mkdir(parents=True, exist_ok=True)
    clips = [c["clip"] for c in result["clips"]]
    figs: dict[str, list[str]] = {}
    for clip in clips:
        per = {a: tr for (c, a), tr in traces.items() if c == clip}
        if not per:
            continue
        ref_p = next(iter(per.values())).ref_p
        side = max(SIDES, key=lambda s: np.ptp(ref_p[wrist_of(s)], axis=0).sum())  # the arm that moves most
        names = [f"{clip}_{kind}.png" for kind in ("wrist_xyz", "elbow_xyz", "wrist_rpy", "elbow_3d")]
        _xyz_plot(out / names[0], per, wrist_of(side), f"{clip}: {side} wrist x/y/z")
        _xyz_plot(out / names[1], per, elbow_of(side), f"{clip}: {side} elbow x/y/z")
        _rpy_plot(out / names[2], per, wrist_of(side), f"{clip}: {side} wrist r/p/y", True)
        _elbow_3d(out / names[3], per, elbow_of(side), f"{clip}: {side} elbow 3D")
        figs[clip] = names
    # the summary's per-algorithm rows (it also holds cross-algorithm blocks: hqp_vs, goals, ...)
    s = {a: result["summary"][a] for a in result["settings"]["algos"] if a in result["summary"]}
    _solve_bar(out / "solve_time.png", s, PAPER_MS)

    lines = [
        "# mimic evaluation report",
        "",
        f"Settings: `{result['settings']}`",
        "",
        "## Summary over all clips (errors in cm, solve time in ms)",
        "",
        "| algo | wrist mean | wrist max | elbow mean | elbow max | wrist mean (reachable) | wrist max (reachable)"
        " | wrist sim mean | elbow sim mean | wrist rot mean [deg] | solve mean | p99 | limit violations |",
        "|---" * 13 + "|",
    ]
    for a, m in s.items():
        lines.append(
            f"| {a} | {_fmt(m.get('wrist_err_cm'))} | {_fmt(m.get('wrist_err_cm'), 'max')} | "
            f"{_fmt(m.get('elbow_err_cm'))} | {_fmt(m.get('elbow_err_cm'), 'max')} | "
            f"{_fmt(m.get('wrist_err_cm_reachable'))} | {_fmt(m.get('wrist_err_cm_reachable'), 'max')} | "
            f"{_fmt(m.get('wrist_err_cm_sim'))} | {_fmt(m.get('elbow_err_cm_sim'))} | "
            f"{_fmt(m.get('wrist_rot_err_deg'))} | {_fmt(m.get('solve_ms'))} | {_fmt(m.get('solve_ms'), 'p99')} | "
            f"{m.get('limit_violations')} |"
        )
    lines += ["", "Paper (seed 000, section 4.3): HQP-Nullspace wrist 0.12 / 0.65 cm, elbow 0.75 / 2.10 cm;"]
    lines += ["traditional QP wrist 0.22 / 2.50 cm, elbow 5.58 / 9.53 cm; solve 38.9 / 83.9 / 136.0 ms.", ""]
    lines += ["![solve time](solve_time.png)", ""]
    lines += _goals_section(result)
    lines += ["## Per clip", ""]
    for c in result["clips"]:
        lines.append(f"### {c['clip']} ({c['frames']} frames)")
        lines.append("")
        if "goals" in c:
            lines += [f"Fidelity goals not met: {', '.join(missed_goal_labels(c['goals'])) or 'none'}", ""]
        for a, m in c["algos"].items():
            lines.append(
                f"- {a}: wrist {_fmt(m['wrist_err_cm'])} / {_fmt(m['wrist_err_cm'], 'max')} cm, elbow "
                f"{_fmt(m['elbow_err_cm'])} / {_fmt(m['elbow_err_cm'], 'max')} cm, solve {_fmt(m['solve_ms'])} ms, "
                f"limit violations {m['limit_violations']}"
            )
        lines.append("")
        for name in figs.get(c["clip"], []):
            lines.append(f"![{name}]({name})")
        lines.append("")
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path
