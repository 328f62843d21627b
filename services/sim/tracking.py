"""Servo tracking measurement: how closely the simulated joints follow a sine.

Commands are real :class:`~shared.messages.JointCommand` messages (q and qd of the
sine) sent at a command rate, through :meth:`SimCore.apply`, so the whole servo path
is measured: validation, clipping, first-order hold, rate limit, feedforward,
gravity compensation, contacts. The error is taken at every physics step against
the continuous reference after a settling time.
"""

from __future__ import annotations

import numpy as np

from services.sim.sim_core import SimConfig, SimCore
from shared.messages import Header, JointCommand


def sine_amplitudes(core: SimCore, amplitude: float, moving: np.ndarray) -> np.ndarray:
    """Per-joint amplitude (n,) [rad]: ``amplitude`` on moving joints, capped to fit the joint range."""
    fit = 0.5 * (core.upper - core.lower) - 1e-3
    return np.where(moving, np.minimum(amplitude, fit), 0.0)


def sine_center(core: SimCore, amplitudes: np.ndarray) -> np.ndarray:
    """Centre pose (n,) [rad]: rest + the profile's ``arms_out`` offset (arms clear of the body),
    moved so centre +- amplitude fits the limits."""
    prof = core.robot.profile
    c = np.array([prof.rest.get(n, 0.0) + prof.arms_out.get(n, 0.0) for n in core.joint_names])
    return np.clip(c, core.lower + amplitudes, core.upper - amplitudes)


def measure_tracking(
    amplitude_deg: float = 30.0,
    frequency_hz: float = 1.0,
    duration: float = 2.0,
    settle: float = 0.5,
    command_rate: float = 100.0,
    include_waist: bool = False,
    config: SimConfig | None = None,
    profile: str | None = None,
) -> dict:
    """Track ``c + A sin(2 pi f t)`` on the arm joints (and the waist if asked).

    Args:
        amplitude_deg: A [deg]. frequency_hz: f [Hz]. duration: simulated time [s].
        settle: error is ignored before this time [s].
        command_rate: JointCommands per second [Hz].
        include_waist: move the waist joints too (otherwise they are commanded at rest);
            a joint whose range is narrower than 2 A moves over its whole range instead.
        config: servo settings (default :class:`SimConfig`).
        profile: robot profile (default ``DEFAULT_PROFILE``).

    Returns:
        JSON-able dict: ``max_error_deg`` over moving joints, ``rms_error_deg``,
        ``per_joint_max_deg``, ``max_contacts``, ``velocity_excess_steps`` and
        ``worst_velocity_ratio`` (the simulated joints' |qd| / vmax) and the servo configuration.
    """
    core = SimCore(profile, config)
    n = len(core.joint_names)
    waist = set(core.robot.profile.waist)
    moving = np.array([include_waist or n_ not in waist for n_ in core.joint_names])
    amp = np.deg2rad(amplitude_deg)
    a = sine_amplitudes(core, amp, moving)
    center = sine_center(core, a)
    w = 2.0 * np.pi * frequency_hz
    # Start at the centre so the transient is the servo's, not a jump to the first sample.
    core.robot.set_q(center)
    core.q_servo = center.copy()
    core._ref_q = center.copy()

    dt = core.dt
    steps = round(duration / dt)
    per_cmd = max(1, round(1.0 / (command_rate * dt)))
    errs = []
    seq = 0
    for k in range(steps):
        if k % per_cmd == 0:
            t = core.time
            cmd = JointCommand(
                hdr=Header(seq, t, 0),
                solver_id="tracking",
                algo="sine",
                joints=list(core.joint_names),
                q=center + a * np.sin(w * t),
                qd=a * w * np.cos(w * t),
            )
            if not core.apply(cmd):
                raise RuntimeError(f"tracking command rejected: {core.counters.last_reject}")
            seq += 1
        core.step_physics(1)
        t = core.time
        if t >= settle:
            errs.append(np.abs(core.q - (center + a * np.sin(w * t))))
    if not errs:
        raise ValueError(f"duration {duration} s leaves nothing after settle {settle} s")
    e = np.rad2deg(np.array(errs))
    em = e[:, moving]
    per_joint = {name: round(float(v), 4) for name, v in zip(core.joint_names, e.max(axis=0))}
    worst = int(np.argmax(e.max(axis=0) * moving))
    return {
        "amplitude_deg": amplitude_deg,
        "frequency_hz": frequency_hz,
        "command_rate_hz": command_rate,
        "duration_s": duration,
        "settle_s": settle,
        "moving_joints": int(moving.sum()),
        "include_waist": include_waist,
        "min_amplitude_deg": round(float(np.rad2deg(a[moving].min())), 3),
        "max_error_deg": round(float(em.max()), 4),
        "rms_error_deg": round(float(np.sqrt(np.mean(em**2))), 4),
        "worst_joint": core.joint_names[worst],
        "held_joints_max_error_deg": round(float(e[:, ~moving].max()), 4) if (~moving).any() else 0.0,
        "per_joint_max_deg": per_joint,
        "max_contacts": core.max_contacts,
        # the simulated joints' own speed: physics steps past vmax (+1 %) and the largest |qd| / vmax
        "velocity_excess_steps": core.counters.velocity_excess_steps,
        "worst_velocity_ratio": round(core.counters.worst_velocity_ratio, 4),
        "rejected": sum(core.counters.rejects.values()),
        "n_joints": n,
        "servo": core.info(),
    }
