"""Position mapping operator -> robot, per axis p in {x, y, z} (seed 000, eqs. 1-3).

Notation (seed 000, Table 1): ``H_*`` operator, ``U_*`` robot; ``*_s`` rest ("initial")
value, ``*_min``/``*_max`` per-axis extents. Every array here is (3,) [m] (or any
shape broadcasting against it) and operations are element-wise, i.e. per axis.

* ``paper`` mode implements the equations literally:

  - (1) ``U_s = U_min + |H_s - H_min| / (H_max - H_min) * (U_max - U_min)``. The absolute
    value is kept as printed: it only matters when the operator's rest lies below
    ``H_min``, where it reflects the rest to the other side instead of going below
    ``U_min`` (a calibration normally has ``H_min < H_s`` and then it is a no-op);
  - (2) ``U = U_s + M * (H - H_s)`` with (3) ``M = (U_max - U_s) / (H_max - H_s)``.

  The single scale M is fitted to the upper side, so an excursion below the rest is
  scaled by the same M and can leave ``[U_min, U_max]`` (whenever
  ``(U_s - U_min) / (H_s - H_min) < M``). No clamping: exactly the paper.
* ``bounded`` mode fixes that: below the rest it scales by
  ``(U_s - U_min) / (H_s - H_min)``, so ``[H_min, H_max]`` maps piecewise linearly and
  continuously onto ``[U_min, U_max]``; anything outside is clamped to the box. (1) is
  used without the absolute value and with its ratio clipped to [0, 1].
* ``incremental`` mode (section 2.2.2, the alternative): ``U += k * dH``, see
  :class:`IncrementalMap`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Position mapping modes (first = default): "bounded", "paper" and "incremental" are the per-axis maps here;
#: "reach" is :mod:`.reach` (per direction from the shoulder onto the robot's sampled reachable set). "reach"
#: is not the default: on the 13 clips measured (``mimic eval --no-sim``, issue 12) it made every wrist + elbow pair
#: reachable and halved the vigorous clips' elbow errors, but the gestures' wrist errors grew (0.27 -> 0.32 cm
#: mean), since the operator's full stretch maps to the robot's and the arm then outran the 4 rad/s cap of the time
#: (8 rad/s since session 14).
MODES: tuple[str, ...] = ("bounded", "reach", "paper", "incremental")
#: Elbow target placement (first = default): see :class:`services.retarget.retargeter.RetargetConfig`.
ELBOW_PLACEMENTS: tuple[str, ...] = ("swivel", "mapped")
#: Eq. (4) robot reference orientation (first = default).
ORIENTATION_REFERENCES: tuple[str, ...] = ("forearm", "posture", "rest")
#: Spans below this are treated as degenerate [m].
_EPS = 1e-9
#: Clamps smaller than this are rounding, not counted [m].
_CLAMP_TOL = 1e-9


def rest_target(H_s, H_min, H_max, U_min, U_max, literal: bool = True) -> np.ndarray:
    """Robot rest position ``U_ps``, eq. (1).

    Args:
        H_s, H_min, H_max: operator rest and extents, (3,) [m].
        U_min, U_max: robot workspace box, (3,) [m].
        literal: paper form with ``|H_s - H_min|``; False clips the ratio to [0, 1] instead.
    """
    H_s, H_min, H_max = (np.asarray(a, dtype=float) for a in (H_s, H_min, H_max))
    U_min, U_max = np.asarray(U_min, dtype=float), np.asarray(U_max, dtype=float)
    span = H_max - H_min
    if np.any(span <= _EPS):
        raise ValueError(f"operator extents must satisfy H_min < H_max per axis, got {H_min} / {H_max}")
    ratio = np.abs(H_s - H_min) / span if literal else np.clip((H_s - H_min) / span, 0.0, 1.0)
    return U_min + ratio * (U_max - U_min)


def scale_up(U_s, U_max, H_s, H_max) -> np.ndarray:
    """Scale ``M_p`` of eq. (3): ``(U_max - U_s) / (H_max - H_s)``, (3,) [-]."""
    den = np.asarray(H_max, dtype=float) - np.asarray(H_s, dtype=float)
    if np.any(den <= _EPS):
        raise ValueError(f"eq. (3) needs H_s < H_max per axis, got H_s {H_s} / H_max {H_max}")
    return (np.asarray(U_max, dtype=float) - np.asarray(U_s, dtype=float)) / den


@dataclass(frozen=True)
class AbsoluteMap:
    """Absolute per-axis mapping of one target, precomputed at calibration.

    Attributes:
        H_s: (3,) operator rest [m]. U_s: (3,) robot rest target, eq. (1) [m].
        M_up: (3,) scale above the rest, eq. (3). M_down: (3,) scale below the rest
            (equal to M_up in paper mode).
        U_min, U_max: (3,) robot box [m]. clamp: clamp the result into the box.
    """

    H_s: np.ndarray
    U_s: np.ndarray
    M_up: np.ndarray
    M_down: np.ndarray
    U_min: np.ndarray
    U_max: np.ndarray
    clamp: bool

    @classmethod
    def build(cls, mode: str, H_s, H_min, H_max, U_min, U_max) -> AbsoluteMap:
        """Mapping for ``mode`` "paper" (eqs. 1-3 literally) or "bounded" (see module doc)."""
        if mode not in ("paper", "bounded"):
            raise ValueError(f"absolute mapping mode {mode!r}; known: paper, bounded")
        H_s, H_min, H_max, U_min, U_max = (np.asarray(a, dtype=float).copy() for a in (H_s, H_min, H_max, U_min, U_max))
        if np.any(U_max - U_min <= _EPS):
            raise ValueError(f"robot box must satisfy U_min < U_max per axis, got {U_min} / {U_max}")
        paper = mode == "paper"
        U_s = rest_target(H_s, H_min, H_max, U_min, U_max, literal=paper)
        M_up = scale_up(U_s, U_max, H_s, H_max)
        if paper:
            M_down = M_up
        else:
            below = H_s - H_min
            # rest at (or under) H_min: U_s == U_min, anything below is clamped anyway
            M_down = np.where(below > _EPS, (U_s - U_min) / np.maximum(below, _EPS), M_up)
        return cls(H_s, U_s, M_up, M_down, U_min, U_max, clamp=not paper)

    def __call__(self, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map operator position(s) H (..., 3) [m], eq. (2).

        Returns:
            U (..., 3) [m] robot target; clamped (..., 3) bool, True where the box clamp acted.
        """
        dH = np.asarray(H, dtype=float) - self.H_s
        U = self.U_s + np.where(dH >= 0.0, self.M_up, self.M_down) * dH
        if not self.clamp:
            return U, np.zeros(U.shape, dtype=bool)
        Uc = np.clip(U, self.U_min, self.U_max)
        # a sample exactly on H_max can land an ulp outside; that is not a clamp worth counting
        return Uc, np.abs(Uc - U) > _CLAMP_TOL


@dataclass
class IncrementalMap:
    """Incremental mapping ``U += k * dH`` (seed 000, section 2.2.2).

    Starts at ``U_start`` (the robot's rest pose of that target). While the source is
    invalid nothing accumulates; on the first valid sample after that the operator
    reference is re-anchored, so a tracking dropout never turns into a jump.

    Attributes:
        U: (3,) current target [m]. k: gain [-]. U_min, U_max: (3,) box the target is
        clamped to when ``clamp`` (incremental mapping can drift out of reach otherwise).
    """

    U: np.ndarray
    k: float
    U_min: np.ndarray
    U_max: np.ndarray
    clamp: bool = True
    H_prev: np.ndarray | None = None

    def __call__(self, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance with operator position H (3,) [m]; returns (U (3,), clamped (3,) bool)."""
        H = np.asarray(H, dtype=float)
        if self.H_prev is not None:
            self.U = self.U + self.k * (H - self.H_prev)
        self.H_prev = H.copy()
        if not self.clamp:
            return self.U.copy(), np.zeros(3, dtype=bool)
        Uc = np.clip(self.U, self.U_min, self.U_max)
        clamped = np.abs(Uc - self.U) > _CLAMP_TOL
        # clamping the state (not only the output) keeps the target from hiding outside the box
        self.U = Uc
        return Uc.copy(), clamped

    def reanchor(self) -> None:
        """Forget the operator reference (call when the source goes invalid)."""
        self.H_prev = None
