"""Figures of seed 000 section 4.1: Fig. 6 (workspaces) and Fig. 7 (trajectories), as PNG.

Matplotlib runs on the Agg backend (no display needed).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from services.retarget.calibration import Calibration
from services.retarget.workspace import Workspace
from shared.targets import SIDES, elbow_of, wrist_of

#: Paper colours: operator left/right (orange-red, cyan-green), robot left/right (blue, yellow).
OPERATOR_COLOURS = {"left": "#e8602c", "right": "#2ab7a9"}
ROBOT_COLOURS = {"left": "#2653c9", "right": "#e3b505"}
_MAX_POINTS = 2500


def operator_reach_points(
    shoulder: np.ndarray, radius: float, lower: np.ndarray, upper: np.ndarray, n: int, rng: np.random.Generator
) -> np.ndarray:
    """Monte Carlo operator workspace: uniform points in the ball of the arm's reach around the
    shoulder, kept inside the calibration box. (n', 3) [m], operator pelvis frame."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = shoulder + d * radius * rng.uniform(size=(n, 1)) ** (1 / 3)
    keep = np.all((pts >= lower) & (pts <= upper), axis=1)
    return pts[keep]


def _robot_cloud(ws: Workspace, target: str, rng: np.random.Generator) -> np.ndarray:
    pts = ws.points[target]
    pts = pts[np.all((pts >= ws.lower[target]) & (pts <= ws.upper[target]), axis=1)]
    if len(pts) > _MAX_POINTS:
        pts = pts[rng.choice(len(pts), _MAX_POINTS, replace=False)]
    return pts


def plot_workspaces(
    ws: Workspace,
    cal: Calibration,
    shoulders: dict[str, np.ndarray],
    out: Path,
    operator_paths: dict[str, np.ndarray] | None = None,
    seed: int = 0,
) -> Path:
    """Fig. 6: (a) restricted robot wrist workspace; (b) operator vs robot wrists; (c) same for elbows.

    Args:
        ws: robot workspace (points in the robot base frame).
        cal: operator calibration (its extents bound the operator clouds).
        shoulders: side -> (3,) operator shoulder in the rest frame [m].
        out: PNG path.
        operator_paths: optional target -> (T, 3) operator trajectory drawn over panel (b)/(c).
    """
    rng = np.random.default_rng(seed)
    fig = plt.figure(figsize=(16, 5.6))
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    for side in SIDES:
        p = _robot_cloud(ws, wrist_of(side), rng)
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=1, alpha=0.35, c=ROBOT_COLOURS[side], label=f"robot {side} wrist")
    ax.set_title(f"(a) robot wrist workspace\n{ws.meta.get('samples', '?')} samples, shrink {ws.shrink.to_dict()}")
    for k, (joint, target_of) in enumerate((("wrist", wrist_of), ("elbow", elbow_of))):
        ax = fig.add_subplot(1, 3, 2 + k, projection="3d")
        for side in SIDES:
            t = target_of(side)
            if side in shoulders:
                # reach of the wrist = whole arm; of the elbow = upper arm (shoulder to elbow at rest)
                upper_arm = float(np.linalg.norm(cal.rest[elbow_of(side)] - shoulders[side]))
                radius = cal.arm_length.get(side, 2 * upper_arm) if joint == "wrist" else upper_arm
                h = operator_reach_points(shoulders[side], radius, cal.lower[t], cal.upper[t], 4000, rng)
                ax.scatter(
                    h[:, 0], h[:, 1], h[:, 2], s=2, alpha=0.3, c=OPERATOR_COLOURS[side], label=f"operator {side}"
                )
            u = _robot_cloud(ws, t, rng)
            ax.scatter(u[:, 0], u[:, 1], u[:, 2], s=1, alpha=0.35, c=ROBOT_COLOURS[side], label=f"robot {side}")
            if operator_paths and t in operator_paths:
                path = operator_paths[t]
                ax.plot(path[:, 0], path[:, 1], path[:, 2], c="k", lw=1.0)
        ax.set_title(f"({'bc'[k]}) operator vs robot {joint}s")
    for ax in fig.axes:
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.set_box_aspect((1, 1, 1))
        ax.legend(loc="upper left", fontsize=7, markerscale=6)
    fig.suptitle("Fig. 6: operator and (restricted) robot workspaces, pelvis frames")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_trajectories(
    times: np.ndarray, H: dict[str, np.ndarray], U: dict[str, np.ndarray], side: str, out: Path, title: str = ""
) -> Path:
    """Fig. 7: operator (dashed) and mapped robot (solid) wrist and elbow x/y/z over time.

    Args:
        times: (T,) [s]. H, U: target -> (T, 3) [m] (NaN where invalid).
        side: "left" or "right". out: PNG path.
    """
    fig, axes = plt.subplots(2, 3, figsize=(14, 6.5), sharex=True)
    for row, (joint, t) in enumerate((("wrist", wrist_of(side)), ("elbow", elbow_of(side)))):
        for ax_i, axis in enumerate("xyz"):
            ax = axes[row, ax_i]
            ax.plot(times, H[t][:, ax_i], "--", c=OPERATOR_COLOURS[side], label="operator")
            ax.plot(times, U[t][:, ax_i], "-", c=ROBOT_COLOURS[side], label="robot target")
            ax.set_title(f"{side} {joint} {axis}")
            ax.set_ylabel(f"{axis} [m]")
            ax.grid(alpha=0.3)
        axes[row, 0].legend(fontsize=8)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(title or f"Fig. 7: {side} arm, operator (dashed) vs mapped robot target (solid)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
