"""Learning-curve figure of ``mimic posture train`` (seed 004 Fig. 6 and the training losses)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def learning_curve(report: dict, path: str | Path) -> Path:
    """Three panels: closed-loop elbow error and action MSE on the held-out clips against demonstration
    time (plain BC vs online relabelling, rounds marked), and the per-epoch losses of the final fit."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    for key, style, label in (
        ("bc", "o-", "plain BC (expert demonstrations)"),
        ("relabel", "s-", "online relabelling"),
    ):
        rows = report[key]
        x = [r["demo_s"] for r in rows]
        ax[0].plot(x, [r["elbow_err_cm"] for r in rows], style, label=label)
        ax[1].plot(x, [r["action_mse"] for r in rows], style, label=label)
        if key == "relabel":
            for r in rows:
                ax[0].annotate(f"r{r['round']}", (r["demo_s"], r["elbow_err_cm"]), textcoords="offset points",
                               xytext=(4, 4), fontsize=8)  # fmt: skip
    ax[0].axhline(report["expert_test"]["elbow_err_cm"], color="k", ls="--", lw=1, label="expert (sees the upper arm)")
    ax[0].set(xlabel="demonstration time [s]", ylabel="elbow error, held-out clips [cm]",
              title="closed loop, policy drives")  # fmt: skip
    ax[1].set(xlabel="demonstration time [s]", ylabel="action MSE vs expert [(rad/s)$^2$]",
              title="on the policy's own trajectory")  # fmt: skip
    for side, rep in report["final_train"]["sides"].items():
        curve = rep["curve"]
        ax[2].semilogy([c[0] for c in curve], label=f"{side}: action (eq. 7)")
        ax[2].semilogy([c[1] for c in curve], ls="--", label=f"{side}: decoder")
    ax[2].set(xlabel="epoch", ylabel="training loss (normalised MSE)", title="final policy, training losses")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
