"""Reach-aware position mapping: the operator's reach onto the robot's reachable set ("reach" mode).

The box of eqs. (1)-(3) is not the set the robot reaches: its corners are out of reach, and a
target that leaves the arm's sphere of reach asks the solver for the impossible (on the vigorous
clips more than half the wrist targets of the box mapping were). The Monte Carlo samples of
:mod:`.workspace` are the reachable set. Seen from the shoulder centre ``c``, each direction ``u``
of the unit sphere has a radial interval ``[r_lo(u), r_hi(u)]`` of reachable wrist positions
(``r_lo``: the elbow cannot fold further, ``r_hi``: the arm at full stretch along ``u``; none at
all for directions into the body or behind the back beyond the shoulder's range).

:class:`ReachMap` estimates both radii on a grid of directions from the samples (kept a margin
inside, eroded so a direction never claims more than its neighbours reach) and interpolates them
with a smooth kernel over the sphere, so ``r_hi(u)`` is a continuous function of the direction.
The operator's wrist is mapped *per direction from the shoulder*:

    u = (w_H - s_H) / |w_H - s_H|,  rho = |w_H - s_H| / L_H   (L_H: operator arm length)
    U = c + u' * clip(rho * r_hi(u'), r_lo(u'), r_hi(u'))

so the operator at full stretch is the robot at full stretch in the same direction, a target
sliding along the edge of reach slides along the robot's edge (no jump), and the direction of
motion is kept. ``u' = u`` wherever the robot reaches in direction ``u``; in a direction it cannot
reach at all ``u'`` is the smooth nearest reachable direction (a kernel-weighted mean of the
reachable grid directions around ``u``, blended in by the reachable share of the neighbourhood),
so the mapping stays continuous there too.
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass, replace

import numpy as np

from services.retarget.workspace import Workspace, cache_dir
from shared.mirror import mirror_points
from shared.rotations import norm3

log = logging.getLogger(__name__)

#: Monte Carlo samples behind the reach map (each direction of the sphere needs its own samples).
REACH_SAMPLES = 60_000

#: Grid directions over the sphere (Fibonacci lattice, ~4.2 deg apart).
GRID_DIRECTIONS = 2400
#: Half-angle of the cone of samples that estimate each grid direction [deg].
CONE_DEG = 6.0
#: Fewest samples in a cone for its direction to count as reachable.
MIN_SAMPLES = 3
#: Radial margin kept inside the sampled reach, on both ends [m].
MARGIN = 0.01
#: Kernel concentration over the sphere: weight exp(KAPPA (u.d - 1)), ~5 deg wide.
KAPPA = 150.0


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) nearly uniform unit directions."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


@dataclass(frozen=True)
class ReachMap:
    """Reachable radii per direction from one shoulder centre, from Monte Carlo samples.

    Attributes:
        centre: (3,) shoulder centre [m], robot base frame.
        dirs: (D, 3) unit grid directions.
        r_lo, r_hi: (D,) reachable radial interval per grid direction [m] (margin applied).
        valid: (D,) bool, the robot reaches in that direction at all.
        kappa: kernel concentration of the interpolation.
    """

    centre: np.ndarray
    dirs: np.ndarray
    r_lo: np.ndarray
    r_hi: np.ndarray
    valid: np.ndarray
    kappa: float = KAPPA

    @classmethod
    def from_samples(
        cls,
        centre: np.ndarray,
        points: np.ndarray,
        n_dirs: int = GRID_DIRECTIONS,
        cone_deg: float = CONE_DEG,
        margin: float = MARGIN,
        min_samples: int = MIN_SAMPLES,
        kappa: float = KAPPA,
    ) -> ReachMap:
        """Estimate the radii from sampled wrist positions ``points`` (n, 3) [m] around ``centre`` (3,).

        Per grid direction the samples within ``cone_deg`` give ``r_hi`` (largest radius) and ``r_lo``
        (smallest); both are then eroded over the neighbouring grid directions within ``cone_deg``
        (``r_hi``: the smallest of the neighbours, ``r_lo``: the largest), so the interpolated
        interval stays inside what every nearby direction reaches, and ``margin`` is taken off.
        """
        c = np.asarray(centre, dtype=float)
        rel = np.asarray(points, dtype=float) - c
        rad = np.linalg.norm(rel, axis=1)
        keep = rad > 1e-6
        rel, rad = rel[keep], rad[keep]
        unit = rel / rad[:, None]
        dirs = fibonacci_sphere(n_dirs)
        cos_c = np.cos(np.radians(cone_deg))
        hi = np.zeros(n_dirs)
        lo = np.full(n_dirs, np.inf)
        count = np.zeros(n_dirs, dtype=int)
        for s in range(0, len(unit), 4096):  # (D, chunk) cosines in chunks keep memory small
            cos = dirs @ unit[s : s + 4096].T
            inside = cos >= cos_c
            r = rad[s : s + 4096][None, :]
            hi = np.maximum(hi, np.where(inside, r, 0.0).max(axis=1))
            lo = np.minimum(lo, np.where(inside, r, np.inf).min(axis=1))
            count += inside.sum(axis=1)
        valid = count >= min_samples
        near = (dirs @ dirs.T) >= cos_c  # (D, D) neighbourhoods
        hi_e = np.where(near & valid[None, :], hi[None, :], np.inf).min(axis=1)
        lo_e = np.where(near & valid[None, :], lo[None, :], -np.inf).max(axis=1)
        # a direction whose neighbourhood is partly unreachable is an edge: it counts, eroded
        r_hi = np.where(valid, hi_e - margin, 0.0)
        r_lo = np.where(valid, lo_e + margin, 0.0)
        valid &= r_hi > r_lo
        return cls(c, dirs, np.where(valid, r_lo, 0.0), np.where(valid, r_hi, 0.0), valid, kappa)

    @classmethod
    def cached(cls, cloud: Workspace, side: str, centre: np.ndarray) -> ReachMap:
        """The reach map of ``side``'s wrist samples in ``cloud`` around ``centre`` (3,) [m], cached next to
        the workspace cache (building it takes about a second)."""
        key = cloud.meta.get("cache_key")
        params = f"{key}|{side}|{np.round(centre, 9).tolist()}|{GRID_DIRECTIONS}|{CONE_DEG}|{MARGIN}|{MIN_SAMPLES}"
        path = cache_dir() / f"reach_{hashlib.sha256(params.encode()).hexdigest()[:16]}.npz"
        if key and path.exists():
            try:
                with np.load(path) as z:
                    return cls(z["centre"], z["dirs"], z["r_lo"], z["r_hi"], z["valid"])
            except (OSError, KeyError, ValueError) as exc:
                log.warning("reach cache %s unreadable (%s); recomputing", path, exc)
        rmap = cls.from_samples(centre, cloud.points[f"{side}_wrist"])
        if key:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
                np.savez_compressed(
                    tmp, centre=rmap.centre, dirs=rmap.dirs, r_lo=rmap.r_lo, r_hi=rmap.r_hi, valid=rmap.valid
                )
                os.replace(tmp, path)
            except OSError as exc:
                log.warning("could not cache reach map at %s: %s", path, exc)
        return rmap

    def mirrored(self) -> ReachMap:
        """The map of the mirror-image arm (reflected through the base frame's x-z plane): the other side of a
        robot whose arms are mirror images gets exactly this, where a map of its own would sit on a grid that is
        not mirror symmetric (:func:`fibonacci_sphere`) and differ by up to 0.3 mm."""
        return replace(self, centre=mirror_points(self.centre), dirs=mirror_points(self.dirs))

    def _weights(self, u: np.ndarray) -> np.ndarray:
        # exp(kappa (cos - 1)) peaks at 1 for the grid direction along u; only ~100 neighbours matter
        return np.exp(self.kappa * (self.dirs @ u - 1.0))

    def direction(self, u: np.ndarray) -> tuple[np.ndarray, float]:
        """Reachable direction (3,) for a unit direction u (3,), and the reachable share of u's neighbourhood.

        ``u`` itself where its whole neighbourhood is reachable; otherwise blended continuously towards
        the kernel-weighted mean of the reachable grid directions around it.
        """
        w = self._weights(u)
        tot = w.sum()
        wv = w[self.valid]
        share = float(wv.sum() / tot)
        if share >= 0.98:
            return u, share
        if wv.sum() < 1e-12 * tot or wv.sum() < 1e-300:
            # far from any reachable direction: the nearest one (log-domain to avoid underflow)
            logw = self.kappa * (self.dirs[self.valid] @ u - 1.0)
            wv = np.exp(logw - logw.max())
        mean = wv @ self.dirs[self.valid]
        m = mean / max(norm3(mean), 1e-12)
        # smoothstep on the share: u where (nearly) all neighbours reach, the mean where about none do
        s = np.clip((share - 0.5) / 0.48, 0.0, 1.0)
        s = s * s * (3.0 - 2.0 * s)
        v = s * u + (1.0 - s) * m
        return v / max(norm3(v), 1e-12), share

    def radii(self, u: np.ndarray) -> tuple[float, float]:
        """Interpolated reachable interval ``(r_lo, r_hi)`` [m] along unit direction u (3,).

        Reachable grid directions only, kernel-weighted (continuous in u).
        """
        w = self._weights(u)[self.valid]
        tot = w.sum()
        if tot < 1e-300:
            logw = self.kappa * (self.dirs[self.valid] @ u - 1.0)
            w, tot = np.exp(logw - logw.max()), None
            tot = w.sum()
        return float(w @ self.r_lo[self.valid] / tot), float(w @ self.r_hi[self.valid] / tot)

    def map(self, u: np.ndarray, rho: float) -> np.ndarray:
        """Robot target (3,) [m] for operator direction u (3,) and reach ratio rho (0: at the shoulder,
        1: stretched)."""
        u = np.asarray(u, dtype=float)
        u = u / max(norm3(u), 1e-12)
        v, _ = self.direction(u)
        lo, hi = self.radii(v)
        r = min(max(float(np.clip(rho, 0.0, 1.0)) * hi, lo), hi)
        return self.centre + r * v

    def project(self, p: np.ndarray) -> np.ndarray:
        """A robot point p (3,) [m] moved into the reachable set along its direction from the centre."""
        a = np.asarray(p, dtype=float) - self.centre
        d = norm3(a)
        if d < 1e-9:
            a, d = self.dirs[self.valid][0], 1e-9
        v, _ = self.direction(a / d)
        lo, hi = self.radii(v)
        return self.centre + min(max(d, lo), hi) * v


def operator_reach(shoulder: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> tuple[np.ndarray, float]:
    """Operator wrist direction (3,) from the shoulder and reach ratio ``|w - s| / (|e - s| + |w - e|)``."""
    s, e, w = (np.asarray(x, dtype=float) for x in (shoulder, elbow, wrist))
    a = w - s
    d = norm3(a)
    length = norm3(e - s) + norm3(w - e)
    if d < 1e-9 or length < 1e-9:
        return np.array([0.0, 0.0, -1.0]), 0.0
    return a / d, d / length
