"""The ``swivel`` action kind: the operator's elbow as one angle on the circle of elbows that reach the wrist.

The wrist target ``p`` fixes the robot's elbow up to its swivel: the elbow lies on the circle at the robot's
upper-arm length from the shoulder centre ``c`` and its forearm length from ``p``
(:func:`services.retarget.elbow.elbow_circle`), around the axis ``u = (p - c) / |p - c|``. The swivel kind
predicts the elbow's angle ``φ`` on that circle as ``(cos φ, sin φ)`` and places the elbow there: it reaches
the wrist by construction, so the solver's elbow task can be met exactly, and the prediction error is one angle.

The angle is measured from a reference direction ``e1(u) ⊥ u`` (``e2 = u × e1``), which must be continuous
where the operators' arms go. A fixed direction projected onto the circle's plane is singular where ``u`` lies
along it either way: with gravity, at arms hanging straight down (5° from the training clips' shoulder-wrist
directions) and straight up (19°). Any continuous reference has a singular point (hairy ball theorem), but it
can have just one: here a fixed ``r0`` is carried from a pole ``a0`` to ``u`` by the smallest rotation,
``e1(u) = r0 - (u·r0) / (1 + u·a0) (a0 + u)`` (a unit vector ⊥ ``u``), singular at ``u = -a0`` only. That seam
is put where no hand goes: behind the back, towards the midline and up (left arm: ``-a0 ∝ (-0.87, -0.40,
0.30)`` in the robot base frame, x forward, y left, z up), 87° from every shoulder-wrist direction of the 14
validation-training clips (their mean direction is 29° from the pole). ``r0`` is "down" made normal to
the pole: at the pole ``φ = 0`` is the lowest elbow. The right arm's frame is the mirror image (y negated), so
a mirrored sample keeps ``cos φ`` and negates ``sin φ`` (``e2`` is a cross product, which a reflection flips).

Plain float arithmetic: the solver places both arms' elbows every tick (``PosturePolicy.act``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.retarget.elbow import elbow_circle

#: Left arm: the reference's single seam, direction ``-a0`` (unnormalised; robot base frame).
SEAM_LEFT = (-0.87, -0.40, 0.30)
#: Left arm: the direction ``r0`` is made from (normal to the pole): down.
REF_LEFT = (0.0, 0.0, -1.0)

Vec = tuple[float, float, float]


def _unit(v) -> Vec:
    x, y, z = (float(e) for e in v)
    n = math.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@dataclass(frozen=True)
class SwivelFrame:
    """One arm's circle and angle reference (robot base frame).

    Attributes:
        centre: shoulder centre c (3,) [m]. upper, fore: segment lengths [m].
        pole: unit a0 (3,), where the reference is r0 itself. ref: unit r0 (3,) ⊥ a0.
    """

    centre: Vec
    upper: float
    fore: float
    pole: Vec
    ref: Vec

    @classmethod
    def for_arm(cls, centre, upper: float, fore: float, side: str) -> SwivelFrame:
        """The frame of side ``"left"`` or ``"right"`` (the mirror image of the left's) for an arm's geometry."""
        m = 1.0 if side == "left" else -1.0
        a0 = _unit((-SEAM_LEFT[0], -m * SEAM_LEFT[1], -SEAM_LEFT[2]))
        r = (REF_LEFT[0], m * REF_LEFT[1], REF_LEFT[2])
        k = _dot(r, a0)
        r0 = _unit((r[0] - k * a0[0], r[1] - k * a0[1], r[2] - k * a0[2]))
        c = tuple(float(x) for x in centre)
        return cls(c, float(upper), float(fore), a0, r0)  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, d: dict) -> SwivelFrame:
        return cls(tuple(d["centre"]), float(d["upper"]), float(d["fore"]), tuple(d["pole"]), tuple(d["ref"]))

    def to_dict(self) -> dict:
        return {"centre": list(self.centre), "upper": self.upper, "fore": self.fore, "pole": list(self.pole),
                "ref": list(self.ref)}  # fmt: skip

    def _circle(self, px: float, py: float, pz: float) -> tuple[Vec, Vec, Vec, float]:
        """Circle of the wrist p: centre o, reference e1, e2 = u × e1 (units), radius r."""
        c = self.centre
        ax, ay, az = px - c[0], py - c[1], pz - c[2]
        d = math.sqrt(ax * ax + ay * ay + az * az)
        u = self.pole if d < 1e-9 else (ax / d, ay / d, az / d)
        x, r = elbow_circle(self.upper, self.fore, max(d, 1e-9))
        a0, r0 = self.pole, self.ref
        k = _dot(u, r0) / max(1.0 + _dot(u, a0), 1e-12)  # the seam (u = -a0) is out of the operators' range
        e1 = _unit((r0[0] - k * (a0[0] + u[0]), r0[1] - k * (a0[1] + u[1]), r0[2] - k * (a0[2] + u[2])))
        e2 = (u[1] * e1[2] - u[2] * e1[1], u[2] * e1[0] - u[0] * e1[2], u[0] * e1[1] - u[1] * e1[0])
        return (c[0] + x * u[0], c[1] + x * u[1], c[2] + x * u[2]), e1, e2, r

    def place_floats(self, cs: float, sn: float, px: float, py: float, pz: float) -> Vec:
        """:meth:`place` in floats: the elbow at angle atan2(sn, cs) on the circle of the wrist (px, py, pz).

        :meth:`_circle` written out (the solver calls this per arm every tick: half its cost).
        """
        cx, cy, cz = self.centre
        ax, ay, az = px - cx, py - cy, pz - cz
        d = math.sqrt(ax * ax + ay * ay + az * az)
        if d < 1e-9:
            return self._place_slow(cs, sn, px, py, pz)
        ux, uy, uz = ax / d, ay / d, az / d
        x, r = elbow_circle(self.upper, self.fore, d)
        (a0x, a0y, a0z), (r0x, r0y, r0z) = self.pole, self.ref
        k = (ux * r0x + uy * r0y + uz * r0z) / max(1.0 + ux * a0x + uy * a0y + uz * a0z, 1e-12)
        e1x, e1y, e1z = r0x - k * (a0x + ux), r0y - k * (a0y + uy), r0z - k * (a0z + uz)
        n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        n = math.sqrt(cs * cs + sn * sn)
        if not (n > 1e-12 and n1 > 1e-12):
            return self._place_slow(cs, sn, px, py, pz)
        a, b = r * cs / (n * n1), r * sn / (n * n1)  # e1 unnormalised: scaled by 1/n1 here, e2 = u x e1 too
        return (cx + x * ux + a * e1x + b * (uy * e1z - uz * e1y), cy + x * uy + a * e1y + b * (uz * e1x - ux * e1z),
                cz + x * uz + a * e1z + b * (ux * e1y - uy * e1x))  # fmt: skip

    def _place_slow(self, cs: float, sn: float, px: float, py: float, pz: float) -> Vec:
        """The placement through :meth:`_circle` (its guards for a wrist at the centre or a zero output)."""
        o, e1, e2, r = self._circle(px, py, pz)
        n = math.sqrt(cs * cs + sn * sn)
        if not n > 1e-12:
            cs, sn, n = 1.0, 0.0, 1.0
        a, b = r * cs / n, r * sn / n
        return o[0] + a * e1[0] + b * e2[0], o[1] + a * e1[1] + b * e2[1], o[2] + a * e1[2] + b * e2[2]

    def place(self, cs_sn: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """Elbow (3,) [m] at the angle (cos φ, sin φ) (2,) (any length: only its direction counts) on the
        circle of elbows that reach the wrist (3,) [m]."""
        return np.array(self.place_floats(float(cs_sn[0]), float(cs_sn[1]), *(float(x) for x in wrist)))

    def coords(self, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """(2,) [m]: the elbow (3,) [m] in the plane of the wrist's (3,) [m] circle, along (e1, e2) from the
        circle's centre; ``r (cos φ, sin φ)`` for an elbow on the circle."""
        o, e1, e2, _ = self._circle(*(float(x) for x in wrist))
        w = (float(elbow[0]) - o[0], float(elbow[1]) - o[1], float(elbow[2]) - o[2])
        return np.array([_dot(w, e1), _dot(w, e2)])

    def angle(self, elbow: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """(cos φ, sin φ) (2,) of an elbow (3,) [m] around the shoulder-wrist axis of the wrist (3,) [m]
        (only the elbow's direction from the axis counts)."""
        a, b = self.coords(elbow, wrist)
        n = math.hypot(a, b)
        return np.array([1.0, 0.0]) if n < 1e-12 else np.array([a / n, b / n])
