"""A real mocap clip through the wheeled robot's stack logic, without the bus: the reference filter measured.

``python -m services.wbc.clip_replay --robot models/tita_piper.toml --clip FILE [--json OUT]``

Per clip frame (at its own time stamp) the :class:`~services.retarget.mobile.MobileRetargeter`
makes the hand target; :class:`~services.solver.wbqp_core.WbqpCore` ticks at its rate on the
newest targets; :class:`~services.wbc.sim_core.WheeledSimCore` follows each command in MuJoCo
(balancing). The very same code the services run, on one simulated clock, so the figures do
not depend on the machine's load. Run twice, with the solver's reference filter (the shipped
default) and without (``ref_omega = 0``); prints both as JSON:

* ``plan``: ``torso_acc_rms`` [m/s^2] and ``arm_acc_rms`` [rad/s^2] of the planned motion,
  ``torso_vx_reversals`` (sign changes of the planned torso velocity beyond ±2 cm/s) and
  ``torso_hf_share`` (share of the planned torso velocity's energy above 2 Hz): the torso/arm
  oscillation the filter is for;
* ``sim``: the simulated hand vs the raw target (``hand_err_mm`` mean/p95/max), torso pitch
  (``pitch_max_rad``), how far the torso rolled forward (``torso_dx_m``), ``fell``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from services.retarget.mobile import MobileRetargeter
from services.retarget.retargeter import RetargetConfig
from services.solver.wbqp_accel import WbqpConfig
from services.solver.wbqp_core import WbqpCore, WbqpCoreConfig
from services.wbc.runner import FALLEN_Z
from services.wbc.sim_core import WheeledSimCore
from shared.report import emit_json

log = logging.getLogger("mimic.wbc.clip")

#: Torso velocity [m/s] a sign change must exceed on both sides to count as a reversal.
REVERSAL_V = 0.02
#: Frequency above which torso velocity counts as oscillation [Hz].
HF_HZ = 2.0


def _plan_metrics(t: np.ndarray, qd: np.ndarray, dt: float) -> dict:
    """Oscillation figures of the planned velocities qd (n, 7) at the tick period dt [s]."""
    acc = np.diff(qd, axis=0) / dt
    vx = qd[:, 0]
    signs = np.sign(np.where(np.abs(vx) > REVERSAL_V, vx, 0.0))
    signs = signs[signs != 0]
    spec = np.abs(np.fft.rfft(vx - vx.mean())) ** 2
    freqs = np.fft.rfftfreq(len(vx), dt)
    total = float(spec.sum())
    return {
        "torso_acc_rms": float(np.sqrt(np.mean(acc[:, 0] ** 2))),
        "arm_acc_rms": float(np.sqrt(np.mean(acc[:, 4:] ** 2))),
        "torso_vx_reversals": int(np.count_nonzero(np.diff(signs))),
        "torso_hf_share": float(spec[freqs > HF_HZ].sum() / total) if total > 0 else 0.0,
    }


def replay(robot: str, clip: Path, core_config: WbqpCoreConfig | None = None, tail: float = 1.0) -> dict:
    """Run one clip (plus ``tail`` [s] after its last frame); returns {"plan": {...}, "sim": {...}, "trace": {...}}."""
    from services.ingest.clip import load_clip

    c = load_clip(clip)
    rt = MobileRetargeter(RetargetConfig(robot=robot))
    sim = WheeledSimCore(robot)
    core = WbqpCore(sim.wheeled, core_config or WbqpCoreConfig(planner=WbqpConfig(dt=0.002)))
    n_phys = max(1, round(core.dt / sim.dt))
    start_x = float(sim.state().q[0])
    t_first = float(c.times[0])
    t_end = float(c.times[-1]) - t_first + tail
    k, t = 0, 0.0
    target = None
    rows = []
    while t <= t_end:
        msg = None
        while k < c.n_frames and float(c.times[k]) - t_first <= t + 1e-9:
            out = rt.step(c.frame(k, k + 1, t0_ns=k + 1))
            k += 1
            if out is not None:
                msg = out
                target = out.targets[rt.map.target]
        cmd = core.step(msg, t)
        sim.apply(cmd, now=sim.time)
        sim.step_physics(n_phys)
        st = sim.state()
        hand = st.frames[rt.map.target].p
        err = np.nan if target is None or not target.valid else float(np.linalg.norm(hand - target.p))
        rows.append((t, *cmd.qd, err, sim.pitch(), float(st.q[0]), float(st.q[2])))
        if st.q[2] < FALLEN_Z:
            break
        t += core.dt
    a = np.asarray(rows)
    err = a[:, 8][np.isfinite(a[:, 8])] * 1e3
    return {
        "plan": _plan_metrics(a[:, 0], a[:, 1:8], core.dt),
        "sim": {
            "hand_err_mm": {
                "mean": float(err.mean()),
                "p95": float(np.percentile(err, 95)),
                "max": float(err.max()),
            },
            "pitch_max_rad": float(np.max(np.abs(a[:, 9]))),
            "torso_dx_m": float(a[:, 10].max() - start_x),
            "fell": bool(a[-1, 11] < FALLEN_Z),
        },
        "trace": {"t": a[:, 0], "qd": a[:, 1:8], "hand_err_m": a[:, 8], "pitch": a[:, 9], "x": a[:, 10]},
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m services.wbc.clip_replay", description=__doc__.split("\n")[0])
    p.add_argument("--robot", default="models/tita_piper.toml", help="wheeled robot profile")
    p.add_argument("--clip", required=True, type=Path, help="mocap clip (BVH, C3D)")
    p.add_argument("--json", default=None, help="also write the JSON here")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        base = WbqpCoreConfig(planner=WbqpConfig(dt=0.002))
        report = {"clip": args.clip.name}
        for name, cfg in (("filtered", base), ("unfiltered", replace(base, ref_omega=0.0))):
            out = replay(args.robot, args.clip, cfg)
            report[name] = {"plan": out["plan"], "sim": out["sim"]}
    except (ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2
    emit_json(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
