"""The retargeter as it was before its step was batched (one target at a time): a test oracle only.

:class:`PerTargetRetargeter` overrides the batched ``Retargeter._targets`` with the former per-target
code (copied unchanged but for names), keeping its own per-target velocity filters and history, so
a test can feed both the same frames and compare every published number.
"""

from __future__ import annotations

import numpy as np

from services.retarget.mapping import IncrementalMap
from services.retarget.orientation import ForearmOrientationMap, angular_velocity, arm_alignment
from services.retarget.retargeter import Retargeter
from services.retarget.velocity import LowPassVelocity
from shared.messages import HumanFrame, Target
from shared.rotations import matrix_to_quat, quat_to_matrix
from shared.targets import ELBOWS, TARGET_NAMES, WRISTS, side_of, wrist_of


class PerTargetRetargeter(Retargeter):
    """Retargeter whose targets are computed one at a time, as before the batched step."""

    def _reset_stream(self) -> None:
        super()._reset_stream()
        self._o_prev: dict[str, tuple[np.ndarray, np.ndarray] | None] = dict.fromkeys(TARGET_NAMES)
        self._o_held = {t: (p.copy(), R.copy()) for t, (p, R) in self.robot_rest.items()}
        self._o_vfilt = {t: LowPassVelocity(self.config.velocity_tau, self.config.max_gap) for t in TARGET_NAMES}
        self._o_wfilt = {t: LowPassVelocity(self.config.velocity_tau, self.config.max_gap) for t in TARGET_NAMES}

    def _targets(self, frame: HumanFrame, dt: float | None) -> dict[str, Target]:
        targets: dict[str, Target] = {}
        for t in TARGET_NAMES:
            targets[t] = self._target(t, frame, dt, targets)
        return targets

    def _target(self, t: str, frame: HumanFrame, dt: float | None, done: dict[str, Target]) -> Target:
        use_rot = frame.oriented and (t in WRISTS or self.config.elbow_rotation)
        bone = frame.bones.get(self.bone_of[t])
        if bone is None or not bone.valid or (t in ELBOWS and self._swivel_occluded(side_of(t), frame)):
            self.counts[f"invalid_{t}"] += 1
            self._o_prev[t] = None
            self._o_vfilt[t].reset()
            self._o_wfilt[t].reset()
            pos_map = self._pos_map[t]
            if isinstance(pos_map, IncrementalMap):
                pos_map.reanchor()
            p, R = self._o_held[t]
            return Target(p.copy(), matrix_to_quat(R), np.zeros(3), np.zeros(3), valid=False, use_rotation=use_rot)
        side = side_of(t)
        p = None
        if t in ELBOWS:
            wrist = done.get(wrist_of(side))
            placed = self._place_elbow(side, frame, wrist.p) if wrist is not None and wrist.valid else None
            if placed is not None:
                p = self._elbow_in_box(t, placed[0])
        if p is None and side in self.reach:
            p = self._reach_target(t, side, frame)
        if p is None:
            p, clamped = self._pos_map[t](np.asarray(bone.p, dtype=float))
            if clamped.any():
                self.counts[f"clamped_{t}"] += 1
            if side in self.reach and t.endswith("wrist"):
                p = self.reach[side].project(p)
            arm = self.arms.get(side)
            if t in WRISTS and arm is not None and self.config.mode != "incremental":
                q = arm.reachable(p)
                if np.any(np.abs(q - p) > 1e-9):
                    self.counts[f"reach_clamped_{t}"] += 1
                p = q
        rot_map = self._rot_map[t]
        R = None
        if isinstance(rot_map, ForearmOrientationMap):
            placed = self._place_elbow(side, frame, p)
            if placed is not None:
                elbow, h_sh, h_el = placed
                c = self.arms[side].centre
                fore_H = np.asarray(bone.p, dtype=float) - h_el
                A = arm_alignment(h_el - h_sh, fore_H, elbow - c, p - elbow, self.config.forearm_blend)
                R = rot_map.with_alignment(quat_to_matrix(bone.q), A)
        if R is None:
            R = rot_map(quat_to_matrix(bone.q))
        prev = self._o_prev[t]
        if prev is None or dt is None or dt <= 0:
            v = self._o_vfilt[t].update(None, 1.0)
            w = self._o_wfilt[t].update(None, 1.0)
        else:
            v = self._o_vfilt[t].update((p - prev[0]) / dt, dt)
            w = self._o_wfilt[t].update(angular_velocity(prev[1], R, dt), dt)
        self._o_prev[t] = (p, R)
        self._o_held[t] = (p, R)
        return Target(p, matrix_to_quat(R), v, w, valid=True, use_rotation=use_rot)


# The swivel geometry of services/retarget/elbow.py as it was in numpy (before it went to plain floats).
def _norm3(a: np.ndarray) -> float:
    return float(np.sqrt(a @ a))


def perp_numpy(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    u = axis / max(_norm3(axis), 1e-12)
    return v - (v @ u) * u


def human_swivel_numpy(shoulder: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
    return perp_numpy(np.asarray(elbow, dtype=float) - shoulder, np.asarray(wrist, dtype=float) - shoulder)


def reachable_numpy(arm, wrist: np.ndarray) -> np.ndarray:
    a = np.asarray(wrist, dtype=float) - arm.centre
    d = _norm3(a)
    if d < 1e-9:
        return arm.centre + arm.reach[0] * arm.default_swivel
    return arm.centre + a * (min(max(d, arm.reach[0]), arm.reach[1]) / d)


def place_numpy(arm, wrist: np.ndarray, swivel: np.ndarray) -> np.ndarray:
    a = np.asarray(wrist, dtype=float) - arm.centre
    d = _norm3(a)
    if d < 1e-9:
        return arm.centre + arm.upper * arm.default_swivel
    u = a / d
    lo, hi = abs(arm.upper - arm.fore) + 1e-4, arm.upper + arm.fore - 1e-6
    d = min(max(d, lo), hi)
    x = (arm.upper**2 - arm.fore**2 + d**2) / (2.0 * d)
    r = np.sqrt(max(arm.upper**2 - x**2, 0.0))
    n = perp_numpy(np.asarray(swivel, dtype=float) + 0.01 * arm.default_swivel, a)
    nn = _norm3(n)
    if nn < 1e-9:
        n = perp_numpy(arm.default_swivel + np.array([0.0, 0.0, -1.0]), a)
        nn = _norm3(n)
    return arm.centre + x * u + r * (n / max(nn, 1e-12))
