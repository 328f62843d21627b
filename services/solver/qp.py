"""QP backends: one small interface over PIQP (dense) and DAQP.

Problem form (all dense, x (n,)):

    min 0.5 x^T H x + f^T x
    s.t. lb <= x <= ub            (optional box)
         gl <= G x <= gu          (optional general inequalities)
         E x = e                  (optional equalities)

PIQP keeps one ``DenseSolver`` per problem shape (``key`` plus dimensions):
it is set up the first time and only updated afterwards. DAQP is stateless
(its setup is part of each call). A solve is reported failed when the solver
says so or returns a non-finite x; the caller decides what to hold.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import daqp
import numpy as np
import piqp


@dataclass(slots=True)
class QpResult:
    """Outcome of one QP: x (n,), ok flag, iterations and the solver's status text."""

    x: np.ndarray
    ok: bool
    iters: int
    status: str


class QpBackend(ABC):
    """A dense QP solver.

    Attributes:
        name: registry name.
        regularization: Tikhonov term the callers add to H for this solver: PIQP copes with
            nearly singular H, DAQP (dual active set, factors H) needs a clearly definite one.
            Callers polish the QP solution on its active set, so the term does not bias the result.
    """

    name: str = ""
    regularization: float = 1e-9

    @abstractmethod
    def solve(
        self,
        H: np.ndarray,
        f: np.ndarray,
        lb: np.ndarray | None = None,
        ub: np.ndarray | None = None,
        G: np.ndarray | None = None,
        gl: np.ndarray | None = None,
        gu: np.ndarray | None = None,
        E: np.ndarray | None = None,
        e: np.ndarray | None = None,
        key: str = "",
    ) -> QpResult:
        """Solve the QP; H must be symmetric positive (semi)definite (PIQP) or definite (DAQP)."""


class PiqpBackend(QpBackend):
    """PIQP dense interior-point solver, set up once per problem shape and updated afterwards.

    Args:
        eps_abs, eps_rel: PIQP's absolute and relative tolerances.
        max_iter: iteration cap per solve.
    """

    name = "piqp"

    def __init__(self, eps_abs: float = 1e-7, eps_rel: float = 1e-8, max_iter: int = 100):
        self.eps_abs, self.eps_rel, self.max_iter = eps_abs, eps_rel, max_iter
        self._solvers: dict[tuple, piqp.DenseSolver] = {}

    def _new(self) -> piqp.DenseSolver:
        s = piqp.DenseSolver()
        s.settings.eps_abs = self.eps_abs
        s.settings.eps_rel = self.eps_rel
        s.settings.max_iter = self.max_iter
        s.settings.verbose = False
        return s

    def solve(self, H, f, lb=None, ub=None, G=None, gl=None, gu=None, E=None, e=None, key=""):
        n = f.shape[0]
        shape = (key, n, lb is not None, 0 if G is None else G.shape[0], 0 if E is None else E.shape[0])
        H = np.asfortranarray(H)
        G = None if G is None else np.asfortranarray(G)
        E = None if E is None else np.asfortranarray(E)
        solver = self._solvers.get(shape)
        try:
            if solver is None:
                solver = self._new()
                solver.setup(H, f, E, e, G, gl, gu, lb, ub)
                self._solvers[shape] = solver
            else:
                solver.update(H, f, E, e, G, gl, gu, lb, ub)
            status = solver.solve()
        except (ValueError, RuntimeError) as exc:
            self._solvers.pop(shape, None)
            return QpResult(np.zeros(n), False, 0, f"piqp error: {exc}")
        x = solver.result.x
        ok = status == piqp.PIQP_SOLVED and bool(np.all(np.isfinite(x)))
        return QpResult(np.array(x), ok, int(solver.result.info.iter), str(status).rsplit(".", 1)[-1])


class DaqpBackend(QpBackend):
    """DAQP dual active-set solver (needs a positive definite H).

    Args:
        primal_tol, dual_tol: DAQP feasibility tolerances.
        iter_limit: iteration cap per solve.
        eq_band: half-width of the band that stands in for equality rows.
    """

    name = "daqp"
    regularization = 1e-6

    def __init__(
        self, primal_tol: float = 1e-9, dual_tol: float = 1e-12, iter_limit: int = 1000, eq_band: float = 1e-9
    ):
        # eps_prox = 0: the callers regularise H themselves; DAQP's automatic proximal term would blur the optimum.
        self.settings = {"primal_tol": primal_tol, "dual_tol": dual_tol, "iter_limit": iter_limit, "eps_prox": 0.0}
        self.eq_band = eq_band
        #: solver asked when DAQP fails (None: report the failure); solves it rescued
        self.fallback: QpBackend | None = PiqpBackend()
        self.fallbacks = 0
        self._empty: dict[int, np.ndarray] = {}
        self._sense: dict[int, np.ndarray] = {}

    def solve(self, H, f, lb=None, ub=None, G=None, gl=None, gu=None, E=None, e=None, key=""):
        n = f.shape[0]
        rows = []
        upper = []
        lower = []
        sense = []
        if lb is not None:
            upper.append(ub)
            lower.append(lb)
            sense.append(self._zeros(n))
        if G is not None:
            rows.append(G)
            upper.append(gu)
            lower.append(gl)
            sense.append(self._zeros(G.shape[0]))
        if E is not None:
            # DAQP declares degenerate equality sets (equalities plus bounds active on the same
            # directions, the normal case in the stacked HQP) infeasible; a band of width
            # 2 * eq_band keeps it an inequality pair and the caller's polish restores equality.
            rows.append(E)
            upper.append(e + self.eq_band)
            lower.append(e - self.eq_band)
            sense.append(self._zeros(E.shape[0]))
        if rows:
            A = rows[0] if len(rows) == 1 else np.vstack(rows)
        else:
            A = self._empty.get(n)
            if A is None:
                A = self._empty[n] = np.zeros((0, n))
        if not upper:
            x = np.linalg.solve(H, -f)
            return QpResult(x, bool(np.all(np.isfinite(x))), 0, "unconstrained")
        bu = upper[0] if len(upper) == 1 else np.concatenate(upper)
        bl = lower[0] if len(lower) == 1 else np.concatenate(lower)
        sn = sense[0] if len(sense) == 1 else np.concatenate(sense)
        x, _fval, flag, info = daqp.solve(
            np.ascontiguousarray(H), f, np.ascontiguousarray(A), bu, bl, sn, **self.settings
        )
        ok = flag in (1, 2) and bool(np.isfinite(x).all())
        if not ok and self.fallback is not None:
            # DAQP can call a feasible problem infeasible (cycling on the degenerate active sets
            # of a stacked HQP level; seen on a real clip: inputs perturbed by 1e-8 solve). An
            # interior-point solve decides before the caller drops the level.
            again = self.fallback.solve(H, f, lb, ub, G, gl, gu, E, e, key=f"daqp-fallback/{key}")
            if again.ok:
                self.fallbacks += 1
                return QpResult(again.x, True, again.iters, f"exitflag {flag}, solved by {self.fallback.name}")
        return QpResult(np.asarray(x, dtype=float), ok, int(info.get("iterations", 0)), f"exitflag {flag}")

    def _zeros(self, m: int) -> np.ndarray:
        z = self._sense.get(m)
        if z is None:
            z = self._sense[m] = np.zeros(m, dtype=np.int32)
        return z


QP_BACKENDS: dict[str, type[QpBackend]] = {"piqp": PiqpBackend, "daqp": DaqpBackend}


def make_backend(name: str) -> QpBackend:
    """Backend by name; the error lists the valid names."""
    try:
        return QP_BACKENDS[name]()
    except KeyError:
        raise ValueError(f"unknown QP backend {name!r}; choose one of {sorted(QP_BACKENDS)}") from None
