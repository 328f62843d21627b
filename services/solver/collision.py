"""Self-collision avoidance: velocity dampers on the signed distances of the profile's link pairs.

For every pair of links (a, b) of the profile's ``[collision]`` pairs closer than the influence
distance ``d_i``, with signed distance ``d`` and witness points ``p_a``, ``p_b``, the joint
velocities must satisfy the damper (Faverjon & Tournassoud; Kanoun et al.)

    d_dot = n^T (J_b(p_b) - J_a(p_a)) qd >= -xi (d - d_s) / (d_i - d_s)

with ``n`` the unit vector along which ``d`` grows, ``J(p)`` (3, n) the Jacobian of the witness
point on its link and ``d_s`` the safety distance: a pair may approach at ``xi`` [m/s] at ``d_i``
and not at all at ``d_s``; closer than ``d_s`` it must separate. Farther than the braking distance
``d_b`` the bound is the larger of that and ``sqrt(2 a (d - d_b))``, the speed the pair could still
brake from at deceleration ``a`` before ``d_b`` (``approach_bound``): a hand may come to the belly
at the operator's pace and brake late, where the linear damper alone slows it from ``d_i`` on
(off unless the profile sets ``braking_deceleration``: the G1's does not, see the solver README).
The rows go to the solver as ``G qd <= h``, hard at every priority level
(``inequalities.Inequalities``); rows that no velocity of the step's box can break are dropped, so
the QP keeps its box-only path on most ticks.

Geometry: a proxy fitted once at start-up to each link's collision mesh (its convex hull, as
MuJoCo collides it; a cylinder or box geom, such as the G1's shoulder pitch and roll links have, by
points whose hull holds it, :func:`primitive_points`): a polytope of 228 faces (the hull's 6
principal directions, 3 rings of 24 square to them, 150 spread over the sphere), each touching the
hull (:func:`link_proxy`). It holds
the hull, so a proxy distance is never larger than the mesh distance; with a few hundred vertices
instead of the meshes' 800-9500 it is cheap to collide. The proxies are geoms of a MuJoCo model of
the same URDF (legs and visual meshes removed) with the link pairs as explicit contact pairs of
margin d_i, so one ``mj_collision`` call a tick finds every pair within d_i with its distance,
normal and witness points. Measured against ``mj_geomDistance`` on the meshes
(``tests/solver/test_collision.py``, random poses): never more than the mesh distance, 0.2 cm less
on average within d_i. (Capsules were tried first: 1.0 cm less on average, 2 cm at a forearm's end.)

Kinematics and witness Jacobians (``mj_jac``) come from that model, kept for kinematics only: its
controlled joints are set from the solver's q, the rest stay at the profile's rest pose (as in the
reduced Pinocchio model). The base is welded in both models, so MuJoCo's world frame moves with the
pelvis and distances and their rates are the same in either frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial import ConvexHull, HalfspaceIntersection

from services.solver.inequalities import Inequalities
from shared.robot.mujoco_model import urdf_for_mujoco
from shared.robot.pinocchio_model import RobotModel
from shared.robot.profile import CollisionSpec

#: Distances below this [m] have no reliable witness direction.
DEGENERATE = 1e-9
#: Directions of a link's polytope proxy besides its 6 principal ones: its faces' normals in the
#: link frame (a Fibonacci lattice), about 16 degrees apart at 150.
POLYTOPE_DIRECTIONS = 150
#: Faces in each ring square to one of the hull's principal axes (15 degrees apart at 24).
RING_DIRECTIONS = 24
#: Sides of the polygon standing for a cylinder geom's circular ends (circumscribed: it holds the circle).
CYLINDER_SEGMENTS = 32
#: Extra margin [m] of the measured pairs beyond d_i: between two measurements the rows follow the joints to
#: first order (``SelfCollisionAvoidance.rows``), and a pair farther than d_i + this when measured cannot come
#: within d_i before the next one.
REFRESH_PAD = 0.03


@dataclass(slots=True)
class PairDistance:
    """One link pair: body ids, signed distance d [m], witness points (3,) [m] and the unit normal (3,)
    along which d grows, from a towards b (world frame)."""

    body_a: int
    body_b: int
    distance: float
    p_a: np.ndarray
    p_b: np.ndarray
    normal: np.ndarray


@dataclass(slots=True)
class LinkProxy:
    """A link's proxy in its frame: the polytope ``normals @ x <= offsets`` holding its mesh's convex hull.

    Attributes:
        normals: (F, 3) unit face normals. offsets: (F,) [m], each the hull's extent along its normal,
            so every face touches the hull. centre: (3,) [m] a point inside (the hull vertices' mean).
    """

    normals: np.ndarray
    offsets: np.ndarray
    centre: np.ndarray

    def vertices(self) -> np.ndarray:
        """(k, 3) [m] the polytope's vertices (link frame)."""
        hs = HalfspaceIntersection(np.hstack((self.normals, -self.offsets[:, None])), self.centre)
        return hs.intersections


def _directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread over the sphere (Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    rxy = np.sqrt(1 - z * z)
    return np.stack((rxy * np.cos(phi), rxy * np.sin(phi), z), axis=1)


def primitive_points(kind: int, size: np.ndarray) -> np.ndarray | None:
    """(k, 3) [m] points in a primitive geom's frame whose convex hull holds the geom: a MuJoCo cylinder (size:
    radius, half height along z) as two circumscribed ``CYLINDER_SEGMENTS``-gons, a box (size: half extents) as
    its 8 corners; None for any other kind."""
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        phi = np.linspace(0.0, 2 * np.pi, CYLINDER_SEGMENTS, endpoint=False)
        r = size[0] / np.cos(np.pi / CYLINDER_SEGMENTS)
        ring = np.stack((r * np.cos(phi), r * np.sin(phi)), axis=1)
        return np.vstack([np.hstack((ring, np.full((len(phi), 1), z))) for z in (-size[1], size[1])])
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * size[:3]
    return None


def link_proxy(vertices: np.ndarray, directions: int = POLYTOPE_DIRECTIONS) -> LinkProxy:
    """The polytope proxy of the convex hull of vertices (m, 3) [m] (the link frame): faces along the hull's
    6 principal directions (exact on a box), rings square to each of them and ``directions`` more spread
    over the sphere, each face touching the hull."""
    hull = vertices[ConvexHull(vertices).vertices]
    centre = hull.mean(axis=0)
    axes = np.linalg.svd(hull - centre, full_matrices=False)[2]
    # A face tilted from a long side reaches out by the length times the tilt: rings of faces square to
    # each principal axis keep the sides of elongated links tight.
    phi = np.linspace(0.0, 2 * np.pi, RING_DIRECTIONS, endpoint=False)[:, None]
    rings = [np.cos(phi) * axes[(k + 1) % 3] + np.sin(phi) * axes[(k + 2) % 3] for k in range(3)]
    normals = np.vstack((axes, -axes, *rings, _directions(directions)))
    return LinkProxy(normals, (hull @ normals.T).max(axis=0), centre)


def add_proxy_geom(mjspec: mujoco.MjSpec, body: str, proxy: LinkProxy) -> str:
    """Add a link's polytope to its body as a massless, non-colliding mesh geom (only explicit pairs use it);
    returns the geom's name."""
    mesh = mjspec.add_mesh()
    mesh.name = f"polytope:{body}"
    mesh.uservert = proxy.vertices().ravel()
    geom = mjspec.body(body).add_geom()
    geom.name, geom.density, geom.contype, geom.conaffinity = mesh.name, 0.0, 0, 0
    geom.type, geom.meshname = mujoco.mjtGeom.mjGEOM_MESH, mesh.name
    return geom.name


def witness_normal(dist: float, p1: np.ndarray, p2: np.ndarray, c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """(3,) unit direction along which the signed distance ``dist`` [m] of two geoms grows, from the first to the
    second, from ``mj_geomDistance``'s witness points p1, p2 (3,) [m]; touching exactly (no direction): along
    the line between the geoms' centres c1, c2 (3,) [m]."""
    v = p2 - p1
    nv = float(np.sqrt(v @ v))
    if nv > DEGENERATE and abs(dist) > DEGENERATE:
        return v * (np.sign(dist) / nv)  # p2 - p1 = d n: it points back when they overlap
    c = c2 - c1
    return c / max(float(np.sqrt(c @ c)), DEGENERATE)


def proxy_contacts(
    model: mujoco.MjModel, data: mujoco.MjData
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[list[int]]]:
    """The explicit pairs within their margin at the current kinematics, closest first.

    ``mj_collision`` finds the pairs (bounding spheres, then the narrow phase, in C); two polytopes
    face to face give several contacts spread over the overlap, each off the true distance by up to
    a millimetre, so each pair found is measured again with ``mj_geomDistance``: its distance and
    witness points (the nearest points, whose line is the distance's gradient direction).

    Returns:
        (d (k,) [m], normal (k, 3) unit along which d grows, from the first geom to the second, witness
        points p1, p2 (k, 3) [m] on each, [[body 1, body 2]] * k); world frame.
    """
    mujoco.mj_collision(model, data)
    ncon = data.ncon
    pairs = dict.fromkeys(map(tuple, data.contact.geom[:ncon].tolist()))  # unique, in order
    k = len(pairs)
    dist, p1, p2, normal = np.empty(k), np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3))
    ft = np.empty(6)
    margin = float(model.pair_margin[0]) if model.npair else 1.0
    for i, (g1, g2) in enumerate(pairs):
        dist[i] = mujoco.mj_geomDistance(model, data, g1, g2, margin + 0.01, ft)
        p1[i], p2[i] = ft[:3], ft[3:]
        normal[i] = witness_normal(dist[i], ft[:3], ft[3:], data.geom_xpos[g1], data.geom_xpos[g2])
    order = np.argsort(dist, kind="stable")
    order = order[dist[order] < margin] if k else order  # the narrow phase's margin is a little generous
    bodies = model.geom_bodyid[np.array(list(pairs), dtype=int).reshape(-1, 2)[order]].tolist()
    return dist[order], normal[order], p1[order], p2[order], bodies


class SelfCollisionAvoidance:
    """Damper rows ``G qd <= h`` for a robot's self-collision pairs at a configuration.

    Args:
        robot: the solver's reduced model (its joint order is the order of q and of G's columns).
        spec: the pairs and damper parameters (default: the profile's ``[collision]``).

    Raises:
        ValueError: no spec, or a link of the spec without collision geometry in the model.
    """

    def __init__(self, robot: RobotModel, spec: CollisionSpec | None = None):
        spec = spec or robot.profile.collision
        if spec is None:
            raise ValueError(f"robot profile {robot.profile.name} has no [collision] table")
        self.spec = spec
        prof = robot.profile
        mjspec = mujoco.MjSpec.from_string(urdf_for_mujoco(prof))
        for i, g in enumerate(mjspec.geoms):
            g.name = g.name or f"mesh{i}"
        self.joint_names = tuple(robot.joint_names)
        # every joint at rest, as in the reduced Pinocchio model
        m = self._install(mjspec.compile(), lambda name: prof.rest.get(name, 0.0))
        collides = (m.geom_contype != 0) | (m.geom_conaffinity != 0)
        links: dict[str, list[int]] = {}  # link name -> its collision geoms
        groups: dict[str, list[str]] = {}
        for group, names in spec.groups.items():
            kept = []
            for link in names:
                try:
                    body = m.body(link).id
                except KeyError:
                    raise ValueError(f"[collision] group {group}: link {link!r} is not in the model") from None
                ids = [g for g in range(m.ngeom) if m.geom_bodyid[g] == body and collides[g]]
                if ids:
                    links[link] = ids
                    kept.append(link)
            if not kept:
                raise ValueError(f"[collision] group {group}: none of {list(names)} has collision geometry")
            groups[group] = kept
        self.links = sorted(links)
        #: link -> the collision geoms it stands for (the proxies' reference, ``mesh_distance``)
        self.link_geoms = {n: links[n] for n in self.links}
        #: link -> its proxies (link frame)
        self.proxies = {n: self._fit(n) for n in self.links}
        li = {n: i for i, n in enumerate(self.links)}
        link_pairs = {
            (min(li[a], li[b]), max(li[a], li[b]))
            for ga, gb in spec.pairs
            for a in groups[ga]
            for b in groups[gb]
            if a != b
        }
        #: (P, 2) link index pairs, sorted
        self.link_pairs = np.array(sorted(link_pairs), dtype=int).reshape(-1, 2)
        self.d_s = spec.safety_distance
        self.d_i = spec.influence_distance
        self.xi = spec.damper_speed
        self.d_b = spec.braking_distance
        self.decel = spec.braking_deceleration
        self._build_proxy_model(mjspec, self.d_i + REFRESH_PAD)
        #: (L,) body ids of ``self.links`` in the proxy model
        self.link_body = np.array([self.model.body(n).id for n in self.links])
        #: (L,) [m] each link's farthest proxy vertex from its origin (``self.links`` order)
        self._radius = np.array([np.linalg.norm(self.proxies[n].vertices(), axis=1).max() for n in self.links])
        #: the last measurement (``_measure``): q (n,), its pairs' distances (k,), rows G (k, n) [m/s per rad/s],
        #: and what ``close`` reports of them
        self._q_ref: np.ndarray | None = None
        self._d_ref = np.empty(0)
        self._G_ref = np.empty((0, len(self.joint_names)))
        self._ref_pairs: tuple[list[list[int]], np.ndarray, np.ndarray, np.ndarray] = (
            [],
            np.empty((0, 3)),
            np.empty((0, 3)),
            np.empty((0, 3)),
        )
        #: the links' origins (L, 3) and orientations (L, 9) at the last measurement (world frame)
        self._x_ref = np.zeros((len(self.links), 3))
        self._R_ref = np.zeros((len(self.links), 9))
        #: measurements taken by ``rows`` (the others followed the last one)
        self.measurements = 0
        self._com_ready = False
        nv = self.model.nv  # the proxy model's (legs removed)
        self._jac_a = np.zeros((3, nv))
        self._jac_b = np.zeros((3, nv))
        self._jacs = np.zeros((2, 8, 3, nv))  # witness Jacobians of up to 8 rows (grown on demand)
        self._fromto = np.zeros(6)
        #: pair distances behind the rows of the last ``rows`` call (row i <-> close[i]), closest first
        self.close: list[PairDistance] = []
        self.min_distance = np.inf

    def _fit(self, name: str) -> LinkProxy:
        """Proxy of a link's collision geoms: meshes, cylinders and boxes (their vertices, or points holding them,
        :func:`primitive_points`, in the link frame at the rest pose)."""
        m, d = self.model, self.data
        body = m.body(name).id
        Rb, ob = d.xmat[body].reshape(3, 3), d.xpos[body]
        verts = []
        for g in self.link_geoms[name]:
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                mid = m.geom_dataid[g]
                v = m.mesh_vert[m.mesh_vertadr[mid] : m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
            elif (v := primitive_points(m.geom_type[g], m.geom_size[g])) is None:
                raise ValueError(
                    f"[collision] link {name}: geom {g} is a {mujoco.mjtGeom(m.geom_type[g]).name}; meshes, cylinders"
                    " and boxes are fitted"
                )
            world = d.geom_xpos[g] + v @ d.geom_xmat[g].reshape(3, 3).T
            verts.append((world - ob) @ Rb)  # into the link frame
        return link_proxy(np.vstack(verts))

    def _build_proxy_model(self, mjspec: mujoco.MjSpec, margin: float) -> None:
        """Recompile the model with the proxies as geoms and the link pairs as explicit contact pairs.

        MuJoCo's ``mj_collision`` then finds, in one C call, every pair closer than ``margin`` [m] (d_i)
        with its distance, normal and witness points; the meshes stop colliding (they stay as the
        reference, ``mesh_distance``). The proxies weigh nothing: the model is for kinematics only.
        """
        # Keep only what the proxies need: the pairs' links and their ancestors (not the legs), no other geoms.
        keep = set()
        for n in self.links:
            b = mjspec.body(n)
            while b is not None and b.name not in keep and b.name != "world":
                keep.add(b.name)
                b = b.parent
        for b in [b for b in mjspec.bodies if b.name not in keep and b.name != "world"]:
            if b.parent is not None and b.parent.name in keep | {"world"}:
                mjspec.delete(b)  # with its subtree
        for g in list(mjspec.geoms):
            if g.contype == 0 and g.conaffinity == 0:
                mjspec.delete(g)  # a visual mesh
            else:
                g.contype = g.conaffinity = 0
        names = {n: add_proxy_geom(mjspec, n, self.proxies[n]) for n in self.links}
        for a, b in self.link_pairs:
            pair = mjspec.add_pair()
            pair.geomname1, pair.geomname2 = names[self.links[a]], names[self.links[b]]
            pair.margin = margin
        rest = {self.model.joint(j).name: self.data.qpos[self.model.jnt_qposadr[j]] for j in range(self.model.njnt)}
        mesh_names = {n: [self.model.geom(g).name for g in ids] for n, ids in self.link_geoms.items()}
        self._install(mjspec.compile(), rest.__getitem__)
        self.link_geoms = {n: [self.model.geom(g).id for g in names] for n, names in mesh_names.items()}

    def _install(self, m: mujoco.MjModel, rest) -> mujoco.MjModel:
        """Use model ``m``: its data at the pose ``rest(joint name) -> q`` [rad], kinematics done, and the
        solver joints' qpos/dof addresses in it."""
        self.model, self.data = m, mujoco.MjData(m)
        for j in range(m.njnt):
            self.data.qpos[m.jnt_qposadr[j]] = rest(m.joint(j).name)
        self.qpos_idx = np.array([m.jnt_qposadr[m.joint(n).id] for n in self.joint_names])
        self.dof_idx = np.array([m.jnt_dofadr[m.joint(n).id] for n in self.joint_names])
        mujoco.mj_kinematics(m, self.data)
        return m

    def set_q(self, q: np.ndarray) -> None:
        """Kinematics of the MuJoCo model at the solver's q (n,) [rad]."""
        self.data.qpos[self.qpos_idx] = q
        mujoco.mj_kinematics(self.model, self.data)
        self._com_ready = False

    def distances(self, q: np.ndarray, dmax: float | None = None) -> list[PairDistance]:
        """Signed proxy distances of the link pairs within ``dmax`` [m] (default d_i) at q (n,) [rad], closest first."""
        self.set_q(q)
        self.model.pair_margin[:] = self.d_i if dmax is None else dmax
        try:
            dist, normal, p1, p2, bodies = proxy_contacts(self.model, self.data)
        finally:
            self.model.pair_margin[:] = self.d_i + REFRESH_PAD  # what ``_measure`` collides with
        return [PairDistance(*bodies[i], float(dist[i]), p1[i], p2[i], normal[i]) for i in range(dist.shape[0])]

    def body_names(self, pd: PairDistance) -> tuple[str, str]:
        """The links (bodies) of a pair."""
        return self.model.body(pd.body_a).name, self.model.body(pd.body_b).name

    def rows(self, q: np.ndarray, lb: np.ndarray | None = None, ub: np.ndarray | None = None) -> Inequalities:
        """The damper rows ``G qd <= h`` (p, n) / (p,) at q (n,) [rad] for every link pair within d_i.

        The pairs are measured (``_measure``: MuJoCo's narrow phase, witness points and their Jacobians, about
        0.25 ms) out to ``d_i + REFRESH_PAD``, and again only once the links have moved far enough that a pair
        could have closed that pad (``_travel``, from the links' poses: one forward-kinematics pass). In between,
        each measured pair's distance follows the joints to first order, ``d = d_ref - G_ref (q - q_ref)`` (its
        rows keep the measured Jacobians): a second-order error, under half a millimetre on the tested path
        (``test_rows_between_measurements_follow_the_joints``), where the safety distance is centimetres.
        Why: measured every tick, the rows took the solver's tick from 0.10 to 0.22-0.43 ms p50 and the stack
        fell behind real time on 2 cores (``SolverConfig``).

        With this step's velocity box ``[lb, ub]`` (n,) [rad/s]: each row raised to what the box can meet
        (``Inequalities.reachable_within``) and the rows every velocity of the box meets dropped (they
        constrain nothing: the QP keeps its box-only fast path); ``close`` keeps the pairs of the rows returned.
        """
        q = np.asarray(q, dtype=float)
        self.set_q(q)
        if self._q_ref is None or self._travel() > REFRESH_PAD:
            self._measure(q)
        d_ref, G_ref = self._d_ref, self._G_ref
        dist = d_ref - G_ref @ (q - self._q_ref) if d_ref.shape[0] else d_ref
        within = np.flatnonzero(dist < self.d_i)
        self.min_distance = float(dist[within].min()) if within.size else np.inf
        if not within.size:
            self.close = []
            return Inequalities(np.empty((0, self.dof_idx.shape[0])), np.empty(0))
        G = G_ref[within]
        ineq = Inequalities(G, self.approach_bound(dist[within]))
        keep = within
        if lb is not None and ub is not None:
            ineq.reachable_within(lb, ub)
            mask = ineq.binding(lb, ub)
            if not mask.all():
                ineq = Inequalities(G[mask], ineq.h[mask])
                keep = within[mask]
        bodies, normal, p1, p2 = self._ref_pairs
        self.close = [PairDistance(*bodies[i], float(dist[i]), p1[i], p2[i], normal[i]) for i in keep]
        return ineq

    def approach_bound(self, dist: np.ndarray) -> np.ndarray:
        """The dampers' bound h (k,) [m/s] on each pair's approach speed at its distance ``dist`` (k,) [m]: the
        linear damper ``xi (d - d_s) / (d_i - d_s)`` (negative closer than d_s: the pair must separate), or,
        farther than the braking distance d_b, the speed it could still brake from at deceleration a before d_b,
        ``sqrt(2 a (d - d_b))``, when that is more."""
        linear = (self.xi / (self.d_i - self.d_s)) * (dist - self.d_s)
        if self.decel <= 0.0:
            return linear
        braking = np.sqrt(2.0 * self.decel * np.maximum(dist - self.d_b, 0.0))
        # only beyond d_b: closer than d_s the linear bound is negative (the pair must separate) and stays so
        return np.where(dist > self.d_b, np.maximum(linear, braking), linear)

    def _travel(self) -> float:
        """[m] how far, at most, two links of a pair have moved towards each other since the last measurement (at
        the current kinematics): each link's points by at most its origin's displacement plus the chord its rotation
        sweeps at its radius (``|R - R_ref|_F / sqrt 2`` is that chord per metre), summed over the pair."""
        body = self.link_body
        moved = np.linalg.norm(self.data.xpos[body] - self._x_ref, axis=1)
        moved += np.linalg.norm(self.data.xmat[body] - self._R_ref, axis=1) * (self._radius / np.sqrt(2.0))
        return float((moved[self.link_pairs[:, 0]] + moved[self.link_pairs[:, 1]]).max())

    def _measure(self, q: np.ndarray) -> None:
        """Measure every pair within ``d_i + REFRESH_PAD`` at q (n,) [rad] (kinematics at q done): distances,
        witness points, rows."""
        self.measurements += 1
        self._x_ref[:] = self.data.xpos[self.link_body]
        self._R_ref[:] = self.data.xmat[self.link_body]
        dist, normal, p1, p2, bodies = proxy_contacts(self.model, self.data)
        k = dist.shape[0]
        self._q_ref = q.copy()
        self._d_ref = dist
        self._ref_pairs = (bodies, normal, p1, p2)
        if not k:
            self._G_ref = np.empty((0, self.dof_idx.shape[0]))
            return
        m, d = self.model, self.data
        if k > self._jacs.shape[1]:
            self._jacs = np.zeros((2, k, 3, m.nv))
        ja, jb = self._jacs[0, :k], self._jacs[1, :k]
        mujoco.mj_comPos(m, d)  # mj_jac reads cdof and subtree_com
        self._com_ready = True
        for r, (b1, b2) in enumerate(bodies):
            mujoco.mj_jac(m, d, ja[r], None, p1[r], b1)
            mujoco.mj_jac(m, d, jb[r], None, p2[r], b2)
        self._G_ref = np.matmul(normal[:, None, :], ja - jb)[:, 0, self.dof_idx]  # -d_dot per qd

    def distance_jacobian(self, pd: PairDistance) -> np.ndarray:
        """(n,) gradient of the pair's signed distance w.r.t. the solver's joints: d_dot = row @ qd.

        ``n^T (J_b(p_b) - J_a(p_a))`` with the witness points fixed on their links (kinematics at the
        last ``set_q``/``rows``); the closest points' sliding along the axes does not change d to first order.
        """
        if not self._com_ready:
            mujoco.mj_comPos(self.model, self.data)  # mj_jac reads cdof and subtree_com
            self._com_ready = True
        m, d = self.model, self.data
        mujoco.mj_jac(m, d, self._jac_a, None, pd.p_a, pd.body_a)
        mujoco.mj_jac(m, d, self._jac_b, None, pd.p_b, pd.body_b)
        return (pd.normal @ (self._jac_b - self._jac_a))[self.dof_idx]

    def mesh_distance(self, link_a: str, link_b: str, dmax: float = 1.0) -> float:
        """Signed distance [m] of two links' collision meshes (MuJoCo ``mj_geomDistance`` on their convex
        hulls) at the current kinematics, capped at dmax: the reference the proxies stand in for."""
        best = dmax
        for ga in self.link_geoms[link_a]:
            for gb in self.link_geoms[link_b]:
                best = min(best, mujoco.mj_geomDistance(self.model, self.data, ga, gb, dmax, self._fromto))
        return float(best)
