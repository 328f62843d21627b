"""A robot described as data (``[[body]]`` tables of a profile TOML) and the MJCF made from it.

Used for robots that ship no URDF (the TITA-PiPER of seed 002): the profile lists every
body with its parent, placement, joint, mass and drawn shape. :func:`to_mjcf` writes one
MJCF file that MuJoCo compiles and Pinocchio loads (``pin.buildModelFromMJCF``), so both
libraries see the same description.

Conventions (the MJCF's): lengths [m], masses [kg], angles [rad], torques [N m] (forces [N]
for slide joints). ``pos`` is the body origin in its parent's frame (bodies are never
rotated: every body frame is parallel to its parent's at q = 0). ``com`` is the centre of
mass in the body frame. Inertias are those of uniform solids of the drawn shape, written
explicitly (``inertiafromgeom="false"``) so the two libraries cannot infer different ones.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

log = logging.getLogger("mimic.description")

JOINT_TYPES = ("free", "hinge", "slide")
SHAPE_TYPES = ("box", "cylinder")
AXES = {"x": 0, "y": 1, "z": 2}


class DescriptionError(ValueError):
    """A body table that cannot be built into a model; the message says which and why."""


@dataclass(frozen=True)
class Joint:
    """One joint: ``type`` free/hinge/slide, unit ``axis`` (3,) in the body frame, ``range`` [rad or m]
    (None = unlimited, e.g. a wheel), ``torque`` motor limit [N m or N] (None = unactuated),
    ``armature`` reflected rotor inertia [kg m^2] (MuJoCo only: Pinocchio's kinematics ignore it)."""

    name: str
    type: str
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    range: tuple[float, float] | None = None
    torque: float | None = None
    armature: float = 0.0


@dataclass(frozen=True)
class Shape:
    """Drawn solid: box ``size`` (3,) full lengths [m], or cylinder ``radius``/``length`` [m] along ``axis``."""

    type: str
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    length: float = 0.0
    axis: str = "z"
    contact: bool = False

    def inertia(self, mass: float) -> np.ndarray:
        """(3,) principal moments [kg m^2] of a uniform solid of this shape about its centre."""
        if self.type == "box":
            a, b, c = self.size
            return mass / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        r, h = self.radius, self.length
        axial = 0.5 * mass * r * r
        radial = mass * (3.0 * r * r + h * h) / 12.0
        out = np.full(3, radial)
        out[AXES[self.axis]] = axial
        return out


@dataclass(frozen=True)
class Site:
    """A named frame on a body: ``pos`` (3,) [m] in the body frame, rotated by ``euler_y`` [rad] about y."""

    name: str
    pos: tuple[float, float, float]
    euler_y: float = 0.0


@dataclass(frozen=True)
class Body:
    """One rigid body of the tree (see the module docstring for frames and units)."""

    name: str
    parent: str
    pos: tuple[float, float, float]
    mass: float
    shape: Shape
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    joint: Joint | None = None
    sites: tuple[Site, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class Description:
    """The body tree of a profile, parents before children."""

    name: str
    bodies: tuple[Body, ...]
    source: Path | None = None

    def body(self, name: str) -> Body:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(f"no body {name!r}; bodies: {[b.name for b in self.bodies]}")

    @property
    def joints(self) -> tuple[Joint, ...]:
        """Joints in tree order (the order MuJoCo and Pinocchio both use)."""
        return tuple(b.joint for b in self.bodies if b.joint is not None)

    @property
    def total_mass(self) -> float:
        return float(sum(b.mass for b in self.bodies))


def _vec3(x, where: str) -> tuple[float, float, float]:
    v = tuple(float(c) for c in x)
    if len(v) != 3 or not all(math.isfinite(c) for c in v):
        raise DescriptionError(f"{where}: expected 3 finite numbers, got {x!r}")
    return v  # type: ignore[return-value]


def _body(raw: dict, index: int) -> Body:
    name = raw.get("name")
    where = f"[[body]] #{index} ({name})"
    if not name or "parent" not in raw or "mass" not in raw or "shape" not in raw:
        raise DescriptionError(f"{where}: needs name, parent, mass and shape")
    mass = float(raw["mass"])
    if not mass > 0.0:
        raise DescriptionError(f"{where}: mass must be > 0 (MuJoCo rejects massless moving bodies), got {mass}")
    s = raw["shape"]
    if s.get("type") not in SHAPE_TYPES:
        raise DescriptionError(f"{where}: shape type must be one of {SHAPE_TYPES}, got {s.get('type')!r}")
    shape = Shape(
        type=s["type"],
        size=_vec3(s.get("size", (0, 0, 0)), where),
        radius=float(s.get("radius", 0.0)),
        length=float(s.get("length", 0.0)),
        axis=s.get("axis", "z"),
        contact=bool(s.get("contact", False)),
    )
    if shape.axis not in AXES:
        raise DescriptionError(f"{where}: shape axis must be x, y or z, got {shape.axis!r}")
    joint = None
    if "joint" in raw:
        j = raw["joint"]
        if j.get("type") not in JOINT_TYPES:
            raise DescriptionError(f"{where}: joint type must be one of {JOINT_TYPES}, got {j.get('type')!r}")
        axis = np.array(_vec3(j.get("axis", (0, 0, 1)), where))
        rng = j.get("range")
        if rng is not None and (len(rng) != 2 or not float(rng[0]) < float(rng[1])):
            raise DescriptionError(f"{where}: joint range must be [lower, upper] with lower < upper, got {rng}")
        joint = Joint(
            name=j.get("name", name),
            type=j["type"],
            axis=tuple(axis / np.linalg.norm(axis)),
            range=None if rng is None else (float(rng[0]), float(rng[1])),
            torque=None if "torque" not in j else float(j["torque"]),
            armature=float(j.get("armature", 0.0)),
        )
    sites = tuple(
        Site(s["name"], _vec3(s.get("pos", (0, 0, 0)), where), float(s.get("euler_y", 0.0)))
        for s in raw.get("sites", ())
    )
    return Body(
        name=name,
        parent=raw["parent"],
        pos=_vec3(raw.get("pos", (0, 0, 0)), where),
        mass=mass,
        shape=shape,
        com=_vec3(raw.get("com", (0, 0, 0)), where),
        joint=joint,
        sites=sites,
    )


def load_description(path: str | Path) -> Description:
    """Read the ``[[body]]`` tables of a profile TOML.

    Raises:
        DescriptionError: missing fields, unknown parents, bodies listed before their parent.
    """
    path = Path(path)
    with path.open("rb") as fh:
        raw = tomllib.load(fh)
    if "body" not in raw:
        raise DescriptionError(f"{path}: no [[body]] tables")
    bodies = tuple(_body(b, i) for i, b in enumerate(raw["body"]))
    seen = {"world"}
    for b in bodies:
        if b.parent not in seen:
            raise DescriptionError(f"{path}: body {b.name!r} has parent {b.parent!r} not listed before it")
        if b.name in seen:
            raise DescriptionError(f"{path}: body {b.name!r} listed twice")
        seen.add(b.name)
    return Description(raw.get("name", path.stem), bodies, path)


def _f(x) -> str:
    return " ".join(repr(float(c)) for c in np.atleast_1d(x))


def _geom(b: Body) -> str:
    s = b.shape
    # Only the wheels touch the floor: the legs cannot reach it and self-contacts are not modelled.
    # A wheel touches through a sphere of its radius: one contact point, where MuJoCo's
    # cylinder-plane contact chatters between 0 and 4 points as the wheel rolls.
    nocontact = 'contype="0" conaffinity="0"'
    extra = ""
    if s.contact:
        extra = (
            f'<geom name="{b.name}_contact" type="sphere" size="{s.radius!r}" pos="{_f(b.com)}" '
            'contype="1" conaffinity="1" condim="3" friction="1.0 0.01 0.001" rgba="0 0 0 0"/>'
        )
    contact = nocontact
    if s.type == "box":
        size = _f(np.array(s.size) / 2)
        return f'<geom name="{b.name}_geom" type="box" size="{size}" pos="{_f(b.com)}" {contact}/>{extra}'
    half = s.length / 2
    axis = np.zeros(3)
    axis[AXES[s.axis]] = half
    com = np.array(b.com)
    # The drawn cylinder is centred on the centre of mass (uniform solid).
    return (
        f'<geom name="{b.name}_geom" type="cylinder" size="{s.radius!r}" fromto="{_f(com - axis)} {_f(com + axis)}" '
        f"{contact}/>{extra}"
    )


def to_mjcf(desc: Description) -> str:
    """MJCF text of the description: bodies, explicit inertials, joints, sites, one motor per joint, a floor."""
    children: dict[str, list[Body]] = {}
    for b in desc.bodies:
        children.setdefault(b.parent, []).append(b)
    lines: list[str] = []

    def emit(b: Body, depth: int) -> None:
        ind = "  " * depth
        lines.append(f'{ind}<body name="{b.name}" pos="{_f(b.pos)}">')
        I = b.shape.inertia(b.mass)
        lines.append(f'{ind}  <inertial pos="{_f(b.com)}" mass="{b.mass!r}" diaginertia="{_f(I)}"/>')
        j = b.joint
        if j is not None:
            if j.type == "free":
                lines.append(f'{ind}  <freejoint name="{j.name}"/>')
            else:
                rng = "" if j.range is None else f' limited="true" range="{_f(j.range)}"'
                arm = f' armature="{j.armature!r}"' if j.armature else ""
                lines.append(f'{ind}  <joint name="{j.name}" type="{j.type}" axis="{_f(j.axis)}"{rng}{arm}/>')
        lines.append(f"{ind}  {_geom(b)}")
        for s in b.sites:
            c, sn = math.cos(s.euler_y / 2), math.sin(s.euler_y / 2)
            lines.append(f'{ind}  <site name="{s.name}" pos="{_f(s.pos)}" quat="{_f((c, 0.0, sn, 0.0))}" size="0.01"/>')
        for c in children.get(b.name, []):
            emit(c, depth + 1)
        lines.append(f"{ind}</body>")

    for b in children.get("world", []):
        emit(b, 2)
    motors = []
    for jt in desc.joints:
        if jt.type != "free" and jt.torque is not None:
            rng = _f((-jt.torque, jt.torque))
            motors.append(f'    <motor name="{jt.name}" joint="{jt.name}" ctrllimited="true" ctrlrange="{rng}"/>')
    src = desc.source.name if desc.source else desc.name
    return "\n".join(
        [
            f"<!-- GENERATED from {src} by shared/robot/description.py: edit the TOML, not this file. -->",
            f'<mujoco model="{desc.name}">',
            '  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>',
            '  <option timestep="0.001" integrator="implicitfast"/>',
            "  <worldbody>",
            '    <light pos="0 0 3" dir="0 0 -1"/>',
            '    <geom name="floor" type="plane" size="20 20 0.1" contype="1" conaffinity="1" '
            'friction="1.0 0.01 0.001"/>',
            *lines,
            "  </worldbody>",
            "  <actuator>",
            *motors,
            "  </actuator>",
            "</mujoco>",
            "",
        ]
    )


def mjcf_path(profile_path: str | Path) -> Path:
    """Where the generated MJCF of a profile lives (its ``mjcf`` key, beside the TOML)."""
    profile_path = Path(profile_path)
    with profile_path.open("rb") as fh:
        raw = tomllib.load(fh)
    return profile_path.parent / raw.get("mjcf", f"{profile_path.stem}.xml")


def main(argv: list[str] | None = None) -> int:
    """Regenerate the MJCF of a profile: ``python -m shared.robot.description models/tita_piper.toml``."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("profile", help="profile TOML with [[body]] tables")
    parser.add_argument("--check", action="store_true", help="exit 1 if the file on disk differs")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    text = to_mjcf(load_description(args.profile))
    out = mjcf_path(args.profile)
    if args.check:
        same = out.exists() and out.read_text() == text
        log.info("%s is %s", out, "up to date" if same else "STALE: regenerate it")
        return 0 if same else 1
    out.write_text(text)
    log.info("wrote %s", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
