"""Elbow targets the robot can reach together with its wrist target ("swivel" placement).

Eqs. (1)-(3) map the wrist and the elbow independently per axis, so the distance
between the two targets follows the operator's forearm scaled by the workspace
ratios (0.10-0.15 m on the recorded clips), not the robot's (0.18 m on the G1): no
configuration meets both, and any solver that holds the wrist misses the elbow by
the length mismatch (about 6 cm), whatever its priorities.

The swivel placement keeps what the elbow target is for, the arm's swivel (where
the elbow points around the shoulder-wrist axis), and takes the lengths from the
robot: the elbow target is the point at the robot's upper-arm length from its
shoulder centre and at its forearm length from the wrist target, on the side the
operator's elbow points to. Shoulder centre and lengths are measured once on the
robot model (the shoulder joints of the G1 do not intersect exactly: the centre is
the least-squares sphere centre of the elbow over random arm configurations,
residual about 0.5 cm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from shared.mirror import mirror_points, mirrored_arms
from shared.robot.pinocchio_model import RobotModel
from shared.targets import elbow_of, wrist_of

#: Swivel direction used when the operator's arm is straight [m]: blended in with this weight,
#: so the direction stays continuous when the elbow crosses the shoulder-wrist line.
_STRAIGHT_BLEND = 0.01
#: Weight [m] of the previous frame's swivel direction (``place(prior=...)``) against the operator's elbow offset
#: from their shoulder-wrist line, up to an offset of this size, then falling as its square (a 4 cm offset, an elbow
#: bent about 15 deg, turns by 7 deg at most; 8 cm by 2): an operator's straight arm has an offset of millimetres,
#: mostly noise, while the robot's arm, its wrist target short of full stretch, is bent and needs a direction.
#: Without it, on byebye_happy's straight right arm the elbow target swung up to 7 cm a frame with the operator's
#: elbow and wrist still within 1 cm. The default direction's 1 cm blend stays under it: with the prior in its place
#: the bent arms' elbows moved too (bye_normal HQP elbow 0.235 -> 0.350 cm).
SWIVEL_PRIOR = 0.02
#: Kept inside the reach shell [m], so the elbow target stays clear of the elbow joint's stops.
REACH_MARGIN = 0.005


@dataclass(frozen=True)
class ArmGeometry:
    """One robot arm: shoulder centre c (3,) [m] (base frame, waist at rest), lengths [m].

    Attributes:
        centre: shoulder centre (3,) [m].
        upper: shoulder centre -> elbow frame distance [m].
        fore: elbow frame -> wrist frame distance with the wrist joints at zero [m].
        default_swivel: (3,) unit swivel direction of the rest pose.
        reach: (min, max) shoulder centre -> wrist distance over the elbow joint's range, wrist
            joints at zero, with ``REACH_MARGIN`` inside [m].
    """

    centre: np.ndarray
    upper: float
    fore: float
    default_swivel: np.ndarray
    reach: tuple[float, float] = (0.0, np.inf)

    @classmethod
    def measure(cls, robot: RobotModel, side: str, samples: int = 400, seed: int = 0) -> ArmGeometry:
        """Measure one arm (a side of ``SIDES``) on the robot model (arms at random, waist at rest).

        The joint roles (waist, this arm's wrist and elbow joints) come from the robot profile.
        """
        rng = np.random.default_rng(seed)
        elbow, wrist = elbow_of(side), wrist_of(side)
        roles = robot.profile.arms[side]
        qs = robot.random_configurations(samples, rng)
        waist = robot.indices(robot.profile.waist)  # empty on an arms-only model
        qs[:, waist] = robot.q_rest[waist]  # the targets are for the waist at rest
        E = np.array([robot.frame_poses(q, names=(elbow,))[elbow][0] for q in qs])
        # Sphere fit |E - c|^2 = r^2  <=>  2 E.c + (r^2 - |c|^2) = |E|^2 (linear least squares).
        A = np.c_[2.0 * E, np.ones(len(E))]
        sol = np.linalg.lstsq(A, (E**2).sum(axis=1), rcond=None)[0]
        c = sol[:3]
        upper = float(np.sqrt(sol[3] + c @ c))
        q0 = robot.q_rest.copy()
        q0[robot.indices(roles.wrist)] = 0.0
        poses = robot.frame_poses(q0, names=(elbow, wrist))
        fore = float(np.linalg.norm(poses[wrist][0] - poses[elbow][0]))
        rest = robot.frame_poses(robot.q_rest, names=(elbow, wrist))
        n0 = _perp(rest[elbow][0] - c, rest[wrist][0] - c)
        if np.linalg.norm(n0) < 1e-6:
            n0 = np.array([-1.0, 0.0, 0.0])
        # The elbow joint's limits bound how far the wrist can be from the shoulder (G1: it folds
        # to about 140 deg only, so a wrist target at the shoulder is out of reach).
        k = robot.joint_names.index(roles.elbow)
        dist = []
        for e in np.linspace(robot.lower[k], robot.upper[k], 201):
            q0[k] = e
            dist.append(np.linalg.norm(robot.frame_poses(q0, names=(wrist,))[wrist][0] - c))
        reach = (min(dist) + REACH_MARGIN, max(dist) - REACH_MARGIN)
        return cls(c, upper, fore, n0 / np.linalg.norm(n0), reach)

    @classmethod
    def measure_arms(cls, robot: RobotModel) -> dict[str, ArmGeometry]:
        """Both arms (side -> geometry); a robot whose arms are mirror images (:func:`shared.mirror.mirrored_arms`)
        gets the left arm's measure mirrored for the right one.

        Why: each side's sphere fit is over its own random postures, and the G1's shoulder axes do not meet,
        so two fits put the centres about a millimetre off each other's mirror image, and a mirror-image
        operator's elbow targets then differed from the mirror image of the operator's (``mimic eval --mirror``).
        """
        left = cls.measure(robot, "left")
        if mirrored_arms(robot) is None:
            return {"left": left, "right": cls.measure(robot, "right")}
        right = replace(left, centre=mirror_points(left.centre), default_swivel=mirror_points(left.default_swivel))
        return {"left": left, "right": right}

    def reachable(self, wrist: np.ndarray) -> np.ndarray:
        """The wrist target (3,) [m] moved radially into the reach shell around the shoulder centre."""
        c = _xyz(self.centre)
        a = _diff(_xyz(wrist), c)
        d = _norm(a)
        if d < 1e-9:
            return self.centre + self.reach[0] * self.default_swivel
        k = min(max(d, self.reach[0]), self.reach[1]) / d
        return np.array([c[0] + a[0] * k, c[1] + a[1] * k, c[2] + a[2] * k])

    def place(self, wrist: np.ndarray, swivel: np.ndarray, prior: np.ndarray | None = None) -> np.ndarray:
        """Elbow target (3,) [m] for a wrist target (3,) [m] and a swivel direction (3,).

        ``swivel`` is the operator's elbow offset from their shoulder-wrist line [m]; its direction perpendicular to
        the robot's shoulder-wrist line is used, blended with the default direction weighted ``_STRAIGHT_BLEND`` and
        with ``prior`` (3,), a unit swivel direction (the previous frame's), weighted :data:`SWIVEL_PRIOR` on a
        straight operator arm.
        """
        c = _xyz(self.centre)
        a = _diff(_xyz(wrist), c)
        d = _norm(a)
        if d < 1e-9:
            return self.centre + self.upper * self.default_swivel
        u = (a[0] / d, a[1] / d, a[2] / d)
        x, r = elbow_circle(self.upper, self.fore, d)
        s, n0 = _xyz(swivel), _xyz(self.default_swivel)
        b, p0 = 0.0, n0
        if prior is not None:  # full weight on a straight arm's millimetres, fading as (SWIVEL_PRIOR / offset)^2
            s2 = max(s[0] * s[0] + s[1] * s[1] + s[2] * s[2], 1e-18)
            b, p0 = SWIVEL_PRIOR * min(1.0, SWIVEL_PRIOR * SWIVEL_PRIOR / s2), _xyz(prior)
        k = _STRAIGHT_BLEND
        n = _perp3((s[0] + k * n0[0] + b * p0[0], s[1] + k * n0[1] + b * p0[1], s[2] + k * n0[2] + b * p0[2]), a)
        nn = _norm(n)
        if nn < 1e-9:
            n = _perp3((n0[0], n0[1], n0[2] - 1.0), a)
            nn = _norm(n)
        m = max(nn, 1e-12)
        return np.array([c[i] + x * u[i] + r * (n[i] / m) for i in range(3)])


def swivel_direction(centre: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray | None:
    """Unit direction (3,) of an elbow (3,) [m] from its shoulder (``centre``)-wrist line, or None on the line.
    (Plain floats, as :meth:`ArmGeometry.place`: it runs after every placement.)"""
    c = _xyz(centre)
    v = _perp3(_diff(_xyz(elbow), c), _diff(_xyz(wrist), c))
    n = _norm(v)
    return np.array([v[0] / n, v[1] / n, v[2] / n]) if n > 1e-9 else None


def elbow_circle(upper: float, fore: float, d: float) -> tuple[float, float]:
    """The circle of elbows that reach a wrist at distance d [m] from the shoulder centre (d > 0).

    Returns (x, r) [m]: the circle's centre lies at x along the shoulder-wrist axis, its radius is r
    (upper-arm length ``upper`` from the shoulder centre, forearm length ``fore`` from the wrist). A
    wrist out of reach is taken on the stretched (or folded) arm: d clamped into the lengths' range.
    """
    lo, hi = abs(upper - fore) + 1e-4, upper + fore - 1e-6
    d = min(max(d, lo), hi)
    x = (upper**2 - fore**2 + d**2) / (2.0 * d)
    return x, math.sqrt(max(upper**2 - x**2, 0.0))


# Plain floats for the 3-vectors here: numpy's per-call overhead was most of the retarget step (two
# placements a frame, at up to 1 kHz); the arithmetic is the same.
def _xyz(v) -> tuple[float, float, float]:
    x, y, z = v.tolist() if isinstance(v, np.ndarray) else (float(e) for e in v)
    return x, y, z


def _diff(a: tuple, b: tuple) -> tuple[float, float, float]:
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


def _norm(a: tuple) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _perp3(v: tuple, axis: tuple) -> tuple[float, float, float]:
    m = max(_norm(axis), 1e-12)
    u = (axis[0] / m, axis[1] / m, axis[2] / m)
    k = v[0] * u[0] + v[1] * u[1] + v[2] * u[2]
    return v[0] - k * u[0], v[1] - k * u[1], v[2] - k * u[2]


def _perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Component of v (3,) perpendicular to axis (3,)."""
    return np.array(_perp3(_xyz(v), _xyz(axis)))


def human_swivel(shoulder: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
    """Operator elbow offset (3,) [m] from their shoulder-wrist line (pelvis frame)."""
    sh = _xyz(shoulder)
    return np.array(_perp3(_diff(_xyz(elbow), sh), _diff(_xyz(wrist), sh)))
