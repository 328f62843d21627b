"""Self-collision avoidance: velocity dampers on the signed distances of the profile's link pairs.

For every pair of links (a, b) of the profile's ``[collision]`` pairs closer than the influence
distance ``d_i``, with signed distance ``d`` and witness points ``p_a``, ``p_b``, the joint
velocities must satisfy the damper (Faverjon & Tournassoud; Kanoun et al.)

    d_dot = n^T (J_b(p_b) - J_a(p_a)) qd >= -xi (d - d_s) / (d_i - d_s)

with ``n`` the unit vector along which ``d`` grows, ``J(p)`` (3, n) the Jacobian of the witness
point on its link and ``d_s`` the safety distance: a pair may approach at ``xi`` [m/s] at ``d_i``
and not at all at ``d_s``; closer than ``d_s`` it must separate. The rows go to the solver as
``G qd <= h``, hard at every priority level (``inequalities.Inequalities``); rows that no velocity
of the step's box can break are dropped, so the QP keeps its box-only path on most ticks.

Geometry: proxies fitted once at start-up to each link's collision mesh (its convex hull, as
MuJoCo collides it), both containing the hull, so a proxy distance is never larger than the mesh
distance: a capsule along the hull's longest axis (tight on forearms and wrists) and a polytope of
66 face directions (tight on a boxy torso or head; :func:`link_proxy`). Each pair is the capsule of
one link against the polytope of the other, the polytope for the link whose capsule fits worse.
They are geoms of a MuJoCo model of the same URDF with the pairs as explicit contact pairs of
margin d_i, so one ``mj_collision`` call finds every pair within d_i with its distance, normal and
witness points (the meshes cost a GJK call of ~10-20 us per pair; the proxies about 1 us in C).
Measured against ``mj_geomDistance`` on the meshes (``tests/solver/test_collision.py``, random
poses): never more than the mesh distance, about 1 cm less on average within d_i.

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
from shared.robot.mujoco_model import _urdf_for_mujoco
from shared.robot.pinocchio_model import RobotModel
from shared.robot.profile import CollisionSpec

#: Distances below this [m] have no reliable witness direction.
DEGENERATE = 1e-9
#: Directions of a link's polytope proxy besides its 6 principal ones: its faces' normals in the
#: link frame (a Fibonacci lattice), about 25 degrees apart at 60.
POLYTOPE_DIRECTIONS = 60


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
    """A link's proxies in its frame, both containing its mesh's convex hull.

    Attributes:
        p0, p1: (3,) [m] the capsule's segment ends. r: its radius [m].
        normals: (F, 3) unit face normals of the polytope ``normals @ x <= offsets``; offsets (F,) [m].
        capsule_excess: the most [m] the capsule sticks out of the hull (over many directions).
    """

    p0: np.ndarray
    p1: np.ndarray
    r: float
    normals: np.ndarray
    offsets: np.ndarray
    capsule_excess: float

    def polytope_vertices(self) -> np.ndarray:
        """(k, 3) [m] the polytope's vertices (link frame)."""
        inside = 0.5 * (self.p0 + self.p1)  # the capsule's axis runs inside the hull
        hs = HalfspaceIntersection(np.hstack((self.normals, -self.offsets[:, None])), inside)
        return hs.intersections


def _directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread over the sphere (Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    rxy = np.sqrt(1 - z * z)
    return np.stack((rxy * np.cos(phi), rxy * np.sin(phi), z), axis=1)


def capsule_around(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The capsule (p0 (3,), p1 (3,), r [m]) along the longest principal direction of points (k, 3) covering them all.

    Its axis passes through the middle of the points' cross-section box; its radius reaches the farthest
    point from the axis; its segment is as short as that radius allows (a capsule is convex, so covering
    a hull's vertices covers the hull).
    """
    centred = points - points.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2]
    ext = np.ptp(centred @ axes.T, axis=0)
    order = np.argsort(ext)[::-1]
    axis, e1, e2 = axes[order[0]], axes[order[1]], axes[order[2]]
    t, x, y = points @ axis, points @ e1, points @ e2
    c = 0.5 * (x.min() + x.max()) * e1 + 0.5 * (y.min() + y.max()) * e2
    rho = np.hypot(x - c @ e1, y - c @ e2)
    r = float(rho.max())
    # A point is within r of the segment [a, b] on the axis when a <= t + s and b >= t - s.
    s = np.sqrt(np.maximum(r * r - rho * rho, 0.0))
    a, b = float((t + s).min()), float((t - s).max())
    if a > b:  # shorter than its radius: a sphere anywhere in [b, a] covers the points
        a = b = 0.5 * (a + b)
    return c + a * axis, c + b * axis, r


def link_proxy(vertices: np.ndarray, directions: int = POLYTOPE_DIRECTIONS) -> LinkProxy:
    """Capsule and polytope proxies of the convex hull of vertices (m, 3) [m] (the link frame)."""
    hull = vertices[ConvexHull(vertices).vertices]
    p0, p1, r = capsule_around(hull)
    axes = np.linalg.svd(hull - hull.mean(axis=0), full_matrices=False)[2]
    normals = np.vstack((axes, -axes, _directions(directions)))
    offsets = (hull @ normals.T).max(axis=0)
    probe = _directions(400)
    excess = float(((np.maximum(probe @ p0, probe @ p1) + r) - (probe @ hull.T).max(axis=1)).max())
    return LinkProxy(p0, p1, r, normals, offsets, excess)


def add_proxy_geoms(mjspec: mujoco.MjSpec, body: str, proxy: LinkProxy) -> tuple[str, str]:
    """Add a link's proxies to its body as massless, non-colliding geoms (only explicit pairs use them).

    Returns the names of the capsule geom (a sphere when its segment is empty) and of the polytope geom.
    """
    b = mjspec.body(body)
    cap = b.add_geom()
    cap.name, cap.density, cap.contype, cap.conaffinity = f"capsule:{body}", 0.0, 0, 0
    if np.linalg.norm(proxy.p1 - proxy.p0) > 1e-6:
        cap.type = mujoco.mjtGeom.mjGEOM_CAPSULE
        cap.fromto = np.concatenate((proxy.p0, proxy.p1))
    else:
        cap.type, cap.pos = mujoco.mjtGeom.mjGEOM_SPHERE, proxy.p0
    cap.size = [proxy.r, 0.0, 0.0]
    mesh = mjspec.add_mesh()
    mesh.name = f"polytope:{body}"
    mesh.uservert = proxy.polytope_vertices().ravel()
    poly = b.add_geom()
    poly.name, poly.density, poly.contype, poly.conaffinity = f"polytope:{body}", 0.0, 0, 0
    poly.type, poly.meshname = mujoco.mjtGeom.mjGEOM_MESH, mesh.name
    return cap.name, poly.name


def proxy_contacts(
    model: mujoco.MjModel, data: mujoco.MjData
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[list[int]]]:
    """The explicit pairs within their margin at the current kinematics (``mj_collision``), closest first.

    Returns:
        (d (k,) [m], normal (k, 3) unit from the first geom to the second, witness points p1, p2 (k, 3) [m]
        on each, [[body 1, body 2]] * k); world frame.
    """
    mujoco.mj_collision(model, data)
    ncon = data.ncon
    con = data.contact
    dist = con.dist[:ncon]
    if ncon > 1:  # a capsule against a mesh may give two contacts: keep each pair's closest (few: plain Python)
        dl, best = dist.tolist(), {}
        for i, (g1, g2) in enumerate(con.geom[:ncon].tolist()):
            j = best.get((g1, g2))
            if j is None or dl[i] < dl[j]:
                best[g1, g2] = i
        sel = sorted(best.values(), key=dl.__getitem__)
    else:
        sel = list(range(ncon))
    dist = dist[sel]
    normal = con.frame[sel, :3]  # unit, from geom 1 to geom 2
    half = (0.5 * dist)[:, None] * normal
    pos = con.pos[sel]  # midway between the surfaces
    return dist, normal, pos - half, pos + half, model.geom_bodyid[con.geom[sel]].tolist()


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
        mjspec = mujoco.MjSpec.from_string(_urdf_for_mujoco(prof))
        for i, g in enumerate(mjspec.geoms):
            g.name = g.name or f"mesh{i}"
        m = self.model = mjspec.compile()
        self.data = mujoco.MjData(m)
        self.qpos_idx = np.array([m.jnt_qposadr[m.joint(n).id] for n in robot.joint_names])
        self.dof_idx = np.array([m.jnt_dofadr[m.joint(n).id] for n in robot.joint_names])
        for j in range(m.njnt):  # every joint at rest, as in the reduced Pinocchio model
            self.data.qpos[m.jnt_qposadr[j]] = prof.rest.get(m.joint(j).name, 0.0)
        mujoco.mj_kinematics(m, self.data)
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
        self.link_body = np.array([m.body(n).id for n in self.links])
        #: link -> the mesh geoms it stands for (the proxies' reference, ``mesh_distance``)
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
        # Each pair is the capsule of one link against the polytope of the other: the polytope for the
        # link its capsule fits worse (a boxy torso), the capsule for the elongated one (a forearm).
        excess = np.array([self.proxies[n].capsule_excess for n in self.links])
        a, b = self.link_pairs.T
        self._poly_is_a = excess[a] >= excess[b]
        self._build_proxy_model(mjspec, spec.influence_distance)
        self.d_s = spec.safety_distance
        self.d_i = spec.influence_distance
        self.xi = spec.damper_speed
        self._com_ready = False
        self._jac_a = np.zeros((3, m.nv))
        self._jac_b = np.zeros((3, m.nv))
        self._jacs = np.zeros((2, 8, 3, m.nv))  # witness Jacobians of up to 8 rows (grown on demand)
        self._fromto = np.zeros(6)
        #: pair distances behind the rows of the last ``rows`` call (row i <-> close[i]), closest first
        self.close: list[PairDistance] = []
        self.min_distance = np.inf

    def _fit(self, name: str) -> LinkProxy:
        """Proxies of a link's collision meshes (their vertices in the link frame, at the rest pose)."""
        m, d = self.model, self.data
        body = m.body(name).id
        Rb, ob = d.xmat[body].reshape(3, 3), d.xpos[body]
        verts = []
        for g in self.link_geoms[name]:
            if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
                raise ValueError(f"[collision] link {name}: geom {g} is not a mesh (only meshes are fitted)")
            mid = m.geom_dataid[g]
            v = m.mesh_vert[m.mesh_vertadr[mid] : m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
            world = d.geom_xpos[g] + v @ d.geom_xmat[g].reshape(3, 3).T
            verts.append((world - ob) @ Rb)  # into the link frame
        return link_proxy(np.vstack(verts))

    def _build_proxy_model(self, mjspec: mujoco.MjSpec, margin: float) -> None:
        """Recompile the model with the proxies as geoms and the link pairs as explicit contact pairs.

        MuJoCo's ``mj_collision`` then finds, in one C call, every pair closer than ``margin`` [m] (d_i)
        with its distance, normal and witness points; the meshes stop colliding (they stay as the
        reference, ``mesh_distance``). The proxies weigh nothing: the model is for kinematics only.
        """
        for g in mjspec.geoms:
            g.contype = g.conaffinity = 0
        names = {n: add_proxy_geoms(mjspec, n, self.proxies[n]) for n in self.links}
        for k, (a, b) in enumerate(self.link_pairs):
            la, lb = self.links[a], self.links[b]
            pair = mjspec.add_pair()
            (cap_a, poly_a), (cap_b, poly_b) = names[la], names[lb]
            pair.geomname1, pair.geomname2 = (poly_a, cap_b) if self._poly_is_a[k] else (cap_a, poly_b)
            pair.margin = margin
        qpos = self.data.qpos.copy()
        mesh_names = {n: [self.model.geom(g).name for g in ids] for n, ids in self.link_geoms.items()}
        self.model = mjspec.compile()
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        self.link_geoms = {n: [self.model.geom(g).id for g in names] for n, names in mesh_names.items()}

    def set_q(self, q: np.ndarray) -> None:
        """Kinematics of the MuJoCo model at the solver's q (n,) [rad]."""
        self.data.qpos[self.qpos_idx] = q
        mujoco.mj_kinematics(self.model, self.data)
        self._com_ready = False

    def distances(self, q: np.ndarray, dmax: float | None = None) -> list[PairDistance]:
        """Signed proxy distances of the link pairs within ``dmax`` [m] (default d_i) at q (n,) [rad], closest first."""
        self.set_q(q)
        if dmax is not None:
            self.model.pair_margin[:] = dmax
        try:
            dist, normal, p1, p2, bodies = proxy_contacts(self.model, self.data)
        finally:
            self.model.pair_margin[:] = self.d_i
        return [PairDistance(*bodies[i], float(dist[i]), p1[i], p2[i], normal[i]) for i in range(dist.shape[0])]

    def body_names(self, pd: PairDistance) -> tuple[str, str]:
        """The links (bodies) of a pair."""
        return self.model.body(pd.body_a).name, self.model.body(pd.body_b).name

    def rows(self, q: np.ndarray, lb: np.ndarray | None = None, ub: np.ndarray | None = None) -> Inequalities:
        """The damper rows ``G qd <= h`` (p, n) / (p,) at q (n,) [rad] for every link pair within d_i.

        With this step's velocity box ``[lb, ub]`` (n,) [rad/s]: each row raised to what the box can meet
        (``Inequalities.reachable_within``) and the rows every velocity of the box meets dropped (they
        constrain nothing: the QP keeps its box-only fast path); ``close`` keeps the pairs of the rows returned.
        """
        self.set_q(q)
        dist, normal, p1, p2, bodies = proxy_contacts(self.model, self.data)
        k = dist.shape[0]
        self.min_distance = float(dist[0]) if k else np.inf
        if not k:
            self.close = []
            return Inequalities(np.empty((0, self.dof_idx.shape[0])), np.empty(0))
        m, d = self.model, self.data
        if k > self._jacs.shape[1]:
            self._jacs = np.zeros((2, k, 3, m.nv))
        ja, jb = self._jacs[0, :k], self._jacs[1, :k]
        mujoco.mj_comPos(m, d)  # mj_jac reads cdof and subtree_com
        self._com_ready = True
        for r, (b1, b2) in enumerate(bodies):
            mujoco.mj_jac(m, d, ja[r], None, p1[r], b1)
            mujoco.mj_jac(m, d, jb[r], None, p2[r], b2)
        G = np.matmul(normal[:, None, :], ja - jb)[:, 0, self.dof_idx]  # -d_dot per qd
        h = (self.xi / (self.d_i - self.d_s)) * (dist - self.d_s)
        ineq = Inequalities(G, h)
        keep = range(k)
        if lb is not None and ub is not None:
            ineq.reachable_within(lb, ub)
            mask = ineq.binding(lb, ub)
            if not mask.all():
                ineq = Inequalities(G[mask], ineq.h[mask])
                keep = np.flatnonzero(mask).tolist()
        self.close = [PairDistance(*bodies[i], float(dist[i]), p1[i], p2[i], normal[i]) for i in keep]
        return ineq

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
        hulls) at the current kinematics, capped at dmax: the reference the capsules stand in for."""
        best = dmax
        for ga in self.link_geoms[link_a]:
            for gb in self.link_geoms[link_b]:
                best = min(best, mujoco.mj_geomDistance(self.model, self.data, ga, gb, dmax, self._fromto))
        return float(best)
