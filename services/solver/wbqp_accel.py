"""``wbqp-accel``: seed 002's whole-body acceleration QP for a wheeled-legged robot with an arm.

Decision variable: the generalised accelerations q̈ (7,) of ``q = [x_b, y_b, z_b, α, θ_a0,
θ_a1, θ_a2]`` (see :mod:`shared.kinematics.mobile_arm`). One QP per control tick Δt [s]:

* objective (eq. 6): ``(P̈ref - P̈)ᵀ Q (P̈ref - P̈) + (q - q_pre)ᵀ R (q - q_pre)`` with
  ``P̈ = J_a q̈ + J̇_a q̇`` and the discrete prediction (eq. 7) ``q = q_pre + (q̇_pre + q̈ Δt) Δt``;
  the reference is the PD law of eqs. 5/10, ``P̈ref = P̈d + Kp (Pd - P) + Kd (Ṗd - Ṗ)``;
* hard end-effector equality (eqs. 8-9): ``J_a q̈ = b``, ``b = P̈ref - J̇_a q̇`` (J̇_a q̇ analytic);
* position limits through the prediction (eq. 11): ``q_lo <= q_pre + (q̇_pre + q̈ Δt) Δt <= q_hi``;
* nonholonomic constraint (eq. 12), in its velocity form: the predicted torso velocity has no
  component across the predicted heading, ``-sin α' ẋ' + cos α' ẏ' = 0`` with
  ``ẋ' = ẋ + ẍ Δt`` (and ẏ'), ``α' = α + α̇ Δt``. Seed 002 prints ``x cos α - y sin α = 0`` on the
  predicted *positions*, which would pin the torso to a line through the world origin (at α = 0
  it reads x = 0: no forward motion at all); "the robot cannot move sideways" is a velocity
  constraint, so that is what is enforced;
* bound on the torso's acceleration change (eq. 13): ``|q̈_base - q̈_pre,base| <= ε`` (4 rows).

When the equality cannot hold with the other constraints (target out of reach, or faster than
eq. 13 lets the torso follow), the QP is infeasible; as section 4.1 argues, the end-effector
task then moves into the objective (Q term) and the status says ``infeasible`` with the
achieved acceleration residual. Eq. 6 weighs the hand term ~1e12 times the R term at Δt = 1 ms,
so that objective is solved as its limit (best hand acceleration, then R with it held).
The position limits always stay hard. Where eq. 11 and eq. 13
contradict (the torso must brake harder than ε allows to stay in its box) the limits win.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from services.solver.qp import QpBackend, QpResult, make_backend
from shared.kinematics.mobile_arm import ALPHA, NQ, MobileArmKinematics

#: Joint names of the 7 generalised coordinates, as they travel in a JointCommand.
Q_NAMES = ("base_x", "base_y", "base_z", "base_yaw", "arm_j1", "arm_j2", "arm_j3")
#: Stand-in for an unbounded coordinate [m or rad] (DAQP treats |b| >= 1e30 as infinite).
UNBOUNDED = 1e30


@dataclass
class WbqpConfig:
    """Settings of the planner.

    Attributes:
        dt: control period Δt [s].
        kp: eq. 5 position gain [1/s^2]; kd: velocity gain [1/s] (critically damped: kd = 2 sqrt(kp)).
        q_weight: (3,) diagonal of Q [s^4/m^2] (hand acceleration error, objective and fallback).
        r_weight: (7,) diagonal of R [1/m^2, 1/rad^2] on the position increment q - q_pre. With the
            equality active, only R shapes the solution: it is Δt^2 ||q̇'||_R^2, a weighted norm of
            the next velocity, so a heavy arm weight makes the torso carry the motion (the seed's
            "torso as an extension of the arm") and a heavy z/α weight keeps height and heading.
        eps: eq. 13 bound ε on the torso's acceleration change per tick [m/s^2, rad/s^2] (4,).
        limit_margin: position limits shrunk by this [m or rad] on each side.
        base_acc_max: bound on the torso's horizontal accelerations |ẍ|, |ÿ| [m/s^2] (not in seed 002,
            which assumes the TITA balances whatever it is asked): a wheeled pendulum accelerating at
            a leans by about a/g, and the balance loop (services/wbc/balance.py) fell on mocap-driven
            plans reaching 3 m/s^2. The seed's own experiment peaks at 0.5 m/s^2.
        brake: (7,) deceleration [m/s^2, rad/s^2] a bounded coordinate may need to stop at its limit
            (0 = none; not in seed 002). Eq. 11 alone lets a coordinate run at full speed into its
            limit and stop there in one tick (at Δt = 2 ms, 0.1 m/s becomes 50 m/s^2), which eq. 13
            forbids for the torso and the hand equality passes on to the arm: on mocap targets the
            torso height hit its limit and the arm whipped at 100 rad/s. So the velocity towards
            a limit is also bounded: ``q̇' <= sqrt(2 brake (q_hi - q))`` (and the mirror).
        qp: QP backend for the ticks where a bound is active (``daqp`` default: on this 7-variable QP
            it costs about 0.8x PIQP's CPU time; ``piqp``).
        eq_tol: relative residual of eq. 8 (times 1 + ||b||) above which the hard-equality solve counts as failed.
    """

    dt: float = 0.002
    kp: float = 25.0
    kd: float = 10.0
    q_weight: tuple[float, float, float] = (1.0, 1.0, 1.0)
    r_weight: tuple[float, ...] = (1.0, 1.0, 20.0, 5.0, 3.0, 3.0, 3.0)
    eps: tuple[float, float, float, float] = (0.02, 0.02, 0.02, 0.02)
    limit_margin: float = 0.02
    brake: tuple[float, ...] = (0.0, 0.0, 1.0, 0.0, 20.0, 20.0, 20.0)
    base_acc_max: float = 0.5
    qp: str = "daqp"
    eq_tol: float = 1e-5

    def __post_init__(self) -> None:
        if not 0.0 < self.dt <= 0.1:
            raise ValueError(f"dt must be in (0, 0.1] s, got {self.dt}")
        if len(self.r_weight) != NQ or min(self.r_weight) <= 0:
            raise ValueError(f"r_weight needs {NQ} values > 0, got {self.r_weight}")
        if len(self.q_weight) != 3 or min(self.q_weight) <= 0:
            raise ValueError(f"q_weight needs 3 values > 0, got {self.q_weight}")
        if not self.base_acc_max > 0:
            raise ValueError(f"base_acc_max must be > 0, got {self.base_acc_max}")
        if len(self.brake) != NQ or min(self.brake) < 0:
            raise ValueError(f"brake needs {NQ} values >= 0, got {self.brake}")
        if len(self.eps) != 4 or min(self.eps) <= 0:
            raise ValueError(f"eps needs 4 values > 0, got {self.eps}")


@dataclass
class WbqpResult:
    """One tick's outcome.

    Attributes:
        qdd: (7,) planned q̈. status: ``ok`` (hard equality held) or ``infeasible`` (section 4.1
            fallback) or ``failed`` (no QP solution: q̈ brakes within the limits). reason: why, when not ok.
        ee_residual: ||J_a q̈ - b|| [m/s^2]. iters: QP iterations (0: closed form, no bound active).
        solve_ms: wall time of the whole planner tick [ms]: hand kinematics (p, J_a, J̇_a q̇), the
            reference, objective and constraints, the QP solve(s) and the integration (eq. 7) into
            ``q_next``, ``qd_next``.
        pref_acc: (3,) P̈ref of eq. 10 [m/s^2]. cpu_ms: the same span in this thread's CPU time [ms]
            (what the tick costs, without the time the OS gave other processes).
        q_next, qd_next: (7,) the state after the tick, eq. 7 applied to qdd [m, rad; m/s, rad/s].
    """

    qdd: np.ndarray
    status: str
    reason: str
    ee_residual: float
    iters: int
    solve_ms: float
    pref_acc: np.ndarray
    cpu_ms: float
    q_next: np.ndarray
    qd_next: np.ndarray


class WbqpAccel:
    """Seed 002's planner: one QP in q̈ per tick (see the module docstring).

    The tick is built from plain floats (:meth:`MobileArmKinematics.evaluate_scalars`, the bounds and
    rows below) and handed to the QP solver as a few small arrays: at 7 variables, numpy's per-call
    overhead (~1 us per small-array operation), not arithmetic, was most of the tick.

    Args:
        kin: hand kinematics in the 7-D coordinates.
        lower, upper: (7,) position limits [m, rad] (±inf for unbounded x, y, α).
        config: settings.
        backend: QP backend instance (default: ``make_backend(config.qp)``).
    """

    name = "wbqp-accel"

    def __init__(
        self,
        kin: MobileArmKinematics,
        lower: np.ndarray,
        upper: np.ndarray,
        config: WbqpConfig | None = None,
        backend: QpBackend | None = None,
    ):
        self.kin = kin
        self.config = cfg = config or WbqpConfig()
        lo = np.asarray(lower, dtype=float) + cfg.limit_margin
        hi = np.asarray(upper, dtype=float) - cfg.limit_margin
        if lo.shape != (NQ,) or np.any(lo > hi):
            raise ValueError("limits: need (7,) lower <= upper (after the margin)")
        self.lower = np.where(np.isfinite(lo), lo, -UNBOUNDED)
        self.upper = np.where(np.isfinite(hi), hi, UNBOUNDED)
        self.backend = backend or make_backend(cfg.qp)
        self.Q = np.diag(cfg.q_weight)
        self._brake = np.asarray(cfg.brake, dtype=float) * (np.abs(self.upper - self.lower) < UNBOUNDED)
        self.R = np.diag(cfg.r_weight)
        self.eps = np.asarray(cfg.eps, dtype=float)
        self.qdd_prev = np.zeros(NQ)
        # Per coordinate, for box(): limits, damper deceleration, |ẍ|, |ÿ| bound (0: none), eq. 13's ε (0: none).
        amax = [cfg.base_acc_max] * 2 + [0.0] * (NQ - 2)
        eps = list(cfg.eps) + [0.0] * (NQ - 4)
        self._box_consts = list(zip(self.lower.tolist(), self.upper.tolist(), self._brake.tolist(), amax, eps))
        self._f_gain = [2.0 * r / cfg.dt for r in cfg.r_weight]  # f = 2 R q̇ / Δt (see solve)
        self._reg = self.backend.regularization * np.eye(NQ)
        self._H = 2.0 * self.R + self._reg  # the hard-equality QP's Hessian never changes (diagonal)
        self._h_inv = (1.0 / np.diag(self._H)).tolist()

    def reset(self, qdd: np.ndarray | None = None) -> None:
        """Forget the previous acceleration (eq. 13's q̈_pre), e.g. after a restart."""
        self.qdd_prev = np.zeros(NQ) if qdd is None else np.asarray(qdd, dtype=float).copy()

    # ------------------------------------------------------------------ pieces (tested one by one)

    def reference(self, q, qd, p_d, v_d, a_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(P̈ref (3,) of eq. 10, P (3,), Ṗ (3,)): PD on the hand from its desired p_d, v_d, a_d [m, m/s, m/s^2]."""
        p = self.kin.hand(q)
        J = self.kin.jacobian(q)
        v = J @ qd
        cfg = self.config
        return a_d + cfg.kp * (p_d - p) + cfg.kd * (v_d - v), p, v

    def box(self, q: list[float], qd: list[float], with_eq13: bool = True) -> tuple[list[float], list[float]]:
        """Bounds (lo, hi) [7] on q̈ from eq. 11 (prediction in the limits), eq. 13 (torso rows) and the
        two additions of :class:`WbqpConfig` (``brake``, ``base_acc_max``); q, qd: 7 floats each.

        The damper counts as part of the position limits: where it and eq. 13 disagree, it wins
        (eq. 13 would let the coordinate reach its limit too fast to stop there but in one tick).
        """
        dt = self.config.dt
        dt2 = dt * dt
        prev = self.qdd_prev.tolist()
        lo_out, hi_out = [], []
        for qk, vk, pk, (L, U, br, amax, eps) in zip(q, qd, prev, self._box_consts):
            lo = (L - qk - vk * dt) / dt2
            hi = (U - qk - vk * dt) / dt2
            if br > 0.0:
                # Velocity damper (WbqpConfig.brake): room to stop with the given deceleration.
                h = (math.sqrt(2.0 * br * (U - qk if qk < U else 0.0)) - vk) / dt
                g = (-math.sqrt(2.0 * br * (qk - L if qk > L else 0.0)) - vk) / dt
                hi = h if h < hi else hi
                lo = g if g > lo else lo
            if amax > 0.0:  # WbqpConfig.base_acc_max on ẍ, ÿ
                lo = -amax if lo < -amax else lo
                hi = amax if hi > amax else hi
            if lo > hi:
                # Already past a limit (measured state): the bounds cross; brake back towards the box.
                lo = hi = hi if qk > U else lo
            if with_eq13 and eps > 0.0:
                lo_b = pk - eps if pk - eps > lo else lo
                hi_b = pk + eps if pk + eps < hi else hi
                # Where eq. 13 and eq. 11 disagree, the position limit wins (a box must never be left).
                if lo_b <= hi_b:
                    lo, hi = lo_b, hi_b
            lo_out.append(lo)
            hi_out.append(hi)
        return lo_out, hi_out

    def nonholonomic_row(self, q: list[float], qd: list[float]) -> tuple[list[float], float]:
        """(row [7], rhs): ``row @ q̈ = rhs`` makes the predicted lateral velocity zero (eq. 12, velocity form).

        Lateral velocity after the tick: ``-sin(α') (ẋ + ẍ Δt) + cos(α') (ẏ + ÿ Δt)`` with
        ``α' = α + α̇ Δt + α̈ Δt^2``; linear in ẍ, ÿ and (to first order) α̈.
        """
        dt = self.config.dt
        a = q[ALPHA] + qd[ALPHA] * dt  # α' at α̈ = 0
        s, c = math.sin(a), math.cos(a)
        # The predicted heading also moves with α̈ (by α̈ Δt^2): linearised about α̈ = 0.
        row = [-s * dt, c * dt, 0.0, -(c * qd[0] + s * qd[1]) * dt * dt, 0.0, 0.0, 0.0]
        return row, s * qd[0] - c * qd[1]

    # ------------------------------------------------------------------ tick

    def solve(
        self,
        q: np.ndarray,
        qd: np.ndarray,
        p_d: np.ndarray,
        v_d: np.ndarray | None = None,
        a_d: np.ndarray | None = None,
    ) -> WbqpResult:
        """Plan q̈ (7,) for this tick from q_pre = q (7,), q̇_pre = qd (7,) and the hand's desired motion,
        and integrate it (eq. 7) into ``q_next``, ``qd_next``; ``solve_ms``/``cpu_ms`` time all of it.

        Args:
            q, qd: current generalised position [m, rad] and velocity [m/s, rad/s].
            p_d, v_d, a_d: desired hand position, velocity, acceleration in Σw (3,) [m, m/s, m/s^2].
        """
        c0 = time.thread_time()  # first: its own cost (~1 us) stays out of the wall figure
        t0 = time.perf_counter()
        cfg = self.config
        dt = cfg.dt
        ql, qdl = q.tolist(), qd.tolist()
        pd_l = p_d.tolist()
        vd_l = (0.0, 0.0, 0.0) if v_d is None else v_d.tolist()
        ad_l = (0.0, 0.0, 0.0) if a_d is None else a_d.tolist()
        p, J, jdqd = self.kin.evaluate_scalars(ql, qdl)
        kp, kd = cfg.kp, cfg.kd
        pref = []
        b = []
        for i in range(3):
            Ji = J[i]
            v = Ji[0] * qdl[0] + Ji[1] * qdl[1] + Ji[2] * qdl[2] + Ji[3] * qdl[3]
            v += Ji[4] * qdl[4] + Ji[5] * qdl[5] + Ji[6] * qdl[6]
            a = ad_l[i] + kp * (pd_l[i] - p[i]) + kd * (vd_l[i] - v)  # eq. 10
            pref.append(a)
            b.append(a - jdqd[i])  # eq. 9
        lo, hi = self.box(ql, qdl)
        nh_row, nh_rhs = self.nonholonomic_row(ql, qdl)
        # Objective eq. 6 with eq. 7 (Δq = Δt q̇ + Δt^2 q̈), as 0.5 q̈ᵀ H q̈ + fᵀ q̈:
        #   (b - J q̈)ᵀ Q (b - J q̈) + (Δt q̇ + Δt^2 q̈)ᵀ R (Δt q̇ + Δt^2 q̈).
        # On the feasible set of eq. 8 the first term is identically 0, so the hard-equality QP
        # keeps only the R term (divided by Δt^4: the same minimiser, a well-scaled H):
        #   H = 2 R, f = 2 R q̇ / Δt.
        f = [g * v for g, v in zip(self._f_gain, qdl)]
        nh_E = [x / dt for x in nh_row]
        nh_e = nh_rhs / dt
        res = self._solve_equality(f, lo, hi, [*J, nh_E], [*b, nh_e])
        status, reason = "ok", ""
        bnorm = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
        x = res.x.tolist()
        resid = _residual(J, x, b) if res.ok else math.inf
        if not res.ok or resid > cfg.eq_tol * (1.0 + bnorm):
            res, resid, lo, hi, reason = self._fallback(res, resid, f, lo, hi, J, b, nh_E, nh_e, bnorm, ql, qdl)
            status = "infeasible"
            x = res.x.tolist()
        if not res.ok:
            # No solution at all: brake every coordinate as hard as the box allows.
            x = [-v / dt for v in qdl]
            status, reason = "failed", f"QP failed ({res.status}): braking"
        x = [lk if xk < lk else (hk if xk > hk else xk) for xk, lk, hk in zip(x, lo, hi)]  # solver tolerance only
        if not res.ok:
            resid = _residual(J, x, b)
        qdd = np.array(x)
        self.qdd_prev = qdd
        q_next, qd_next = predict(q, qd, qdd, dt)
        ms = (time.perf_counter() - t0) * 1e3
        cpu = (time.thread_time() - c0) * 1e3
        return WbqpResult(qdd, status, reason, resid, res.iters, ms, np.array(pref), cpu, q_next, qd_next)

    def _solve_equality(
        self, f: list[float], lo: list[float], hi: list[float], E: list[list[float]], e: list[float]
    ) -> QpResult:
        """The hard-equality QP: min ½ q̈ᵀ H q̈ + fᵀ q̈ s.t. lo <= q̈ <= hi, E q̈ = e (E: 4 rows of 7).

        First its equality-only optimum in closed form (:func:`equality_qp`): when that lies in the
        box, no bound is active and it is the QP's solution (the KKT conditions hold with zero bound
        multipliers), ``iters = 0``. Otherwise the QP backend.
        """
        x = equality_qp(self._h_inv, f, E, e)
        if x is not None and all(lk <= xk <= hk for xk, lk, hk in zip(x, lo, hi)):
            return QpResult(np.array(x), True, 0, "closed form (no bound active)")
        return self.backend.solve(
            self._H, np.array(f), np.array(lo), np.array(hi), E=np.array(E), e=np.array(e), key="wbqp-eq"
        )

    def _fallback(
        self,
        res: QpResult,
        resid: float,
        f: list[float],
        lo: list[float],
        hi: list[float],
        J: list[list[float]],
        b: list[float],
        nh_E: list[float],
        nh_e: float,
        bnorm: float,
        q: list[float],
        qd: list[float],
    ) -> tuple[QpResult, float, list[float], list[float], str]:
        """Section 4.1: the end-effector task as objective, the other constraints kept.

        Eq. 6 weighs the two terms as (Q, Δt^4 R): the hand term dominates by ~1e12, which no QP
        solver resolves in one H (the R part drowns in its regularisation). Solved as its limit
        instead, in two well-scaled QPs: the best hand acceleration first, then the R term with
        that hand acceleration held. Returns (result, its residual ||J_a q̈ - b||, lo, hi as used, reason).
        """
        cfg = self.config
        eq_status = res.status if not res.ok else f"equality residual {resid:.3g}"
        Jn, bn = np.array(J), np.array(b)
        nh_En, nh_en = np.array([nh_E]), np.array([nh_e])
        JtQ = Jn.T @ self.Q
        H2 = 2.0 * (JtQ @ Jn) + self._reg
        f2 = -2.0 * (JtQ @ bn)
        relaxed = ""
        lo_a, hi_a = np.array(lo), np.array(hi)
        res = self.backend.solve(H2, f2, lo_a, hi_a, E=nh_En, e=nh_en, key="wbqp-obj")
        if not res.ok:
            # Eq. 13 against eq. 12 (e.g. a turn needs a centripetal acceleration the ε bound
            # does not allow from the previous tick's): the position limits stay, ε goes.
            lo, hi = self.box(q, qd, with_eq13=False)
            lo_a, hi_a = np.array(lo), np.array(hi)
            res = self.backend.solve(H2, f2, lo_a, hi_a, E=nh_En, e=nh_en, key="wbqp-obj")
            relaxed = "; eq. 13 relaxed this tick"
        if res.ok:
            held = self._solve_equality(f, lo, hi, [*J, nh_E], [*(Jn @ res.x).tolist(), nh_e])
            if held.ok and np.linalg.norm(Jn @ held.x - Jn @ res.x) <= cfg.eq_tol * (1.0 + bnorm):
                res = held
        resid = _residual(J, res.x.tolist(), b) if res.ok else math.inf
        reason = (
            f"J_a q̈ = b cannot hold within the limits and eq. 13 ({eq_status}): "
            f"hand task as objective, acceleration residual {resid:.3g} m/s^2{relaxed}"
        )
        return res, resid, lo, hi, reason


def equality_qp(h_inv: list[float], f: list[float], E: list[list[float]], e: list[float]) -> list[float] | None:
    """argmin ½ xᵀ H x + fᵀ x s.t. E x = e, for a diagonal H (h_inv [n]: its inverse) and 4 rows E [4][n], e [4].

    x = H⁻¹ (Eᵀ λ - f) with (E H⁻¹ Eᵀ) λ = e + E H⁻¹ f, the 4 x 4 system solved by Cholesky, all
    written out (the planner's 3 hand rows and eq. 12's row). Returns None when E H⁻¹ Eᵀ is not
    clearly positive definite (E loses rank, e.g. at an arm singularity): a QP solver decides then.
    """
    m00 = m10 = m11 = m20 = m21 = m22 = m30 = m31 = m32 = m33 = 0.0
    s0 = s1 = s2 = s3 = 0.0  # E H⁻¹ f
    for hk, fk, ak, bk, ck, dk in zip(h_inv, f, *E):
        ha, hb, hc, hd = hk * ak, hk * bk, hk * ck, hk * dk
        m00 += ha * ak
        m10 += hb * ak
        m11 += hb * bk
        m20 += hc * ak
        m21 += hc * bk
        m22 += hc * ck
        m30 += hd * ak
        m31 += hd * bk
        m32 += hd * ck
        m33 += hd * dk
        s0 += ha * fk
        s1 += hb * fk
        s2 += hc * fk
        s3 += hd * fk
    floor = 1e-12 * max(m00, m11, m22, m33)
    # Cholesky M = L Lᵀ (lower L), a relative floor on the pivots.
    if not m00 > floor:
        return None
    l00 = math.sqrt(m00)
    l10, l20, l30 = m10 / l00, m20 / l00, m30 / l00
    p = m11 - l10 * l10
    if not p > floor:
        return None
    l11 = math.sqrt(p)
    l21, l31 = (m21 - l20 * l10) / l11, (m31 - l30 * l10) / l11
    p = m22 - l20 * l20 - l21 * l21
    if not p > floor:
        return None
    l22 = math.sqrt(p)
    l32 = (m32 - l30 * l20 - l31 * l21) / l22
    p = m33 - l30 * l30 - l31 * l31 - l32 * l32
    if not p > floor:
        return None
    l33 = math.sqrt(p)
    e0, e1, e2, e3 = e
    y0 = (e0 + s0) / l00  # L y = e + E H⁻¹ f
    y1 = (e1 + s1 - l10 * y0) / l11
    y2 = (e2 + s2 - l20 * y0 - l21 * y1) / l22
    y3 = (e3 + s3 - l30 * y0 - l31 * y1 - l32 * y2) / l33
    k3 = y3 / l33  # Lᵀ λ = y
    k2 = (y2 - l32 * k3) / l22
    k1 = (y1 - l21 * k2 - l31 * k3) / l11
    k0 = (y0 - l10 * k1 - l20 * k2 - l30 * k3) / l00
    return [hk * (ak * k0 + bk * k1 + ck * k2 + dk * k3 - fk) for hk, fk, ak, bk, ck, dk in zip(h_inv, f, *E)]


def _residual(J: list[list[float]], x: list[float], b: list[float]) -> float:
    """||J x - b|| for J [3][7], x [7], b [3] (floats)."""
    s = 0.0
    for Ji, bi in zip(J, b):
        r = Ji[0] * x[0] + Ji[1] * x[1] + Ji[2] * x[2] + Ji[3] * x[3] + Ji[4] * x[4] + Ji[5] * x[5] + Ji[6] * x[6] - bi
        s += r * r
    return math.sqrt(s)


def predict(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 7: (q', q̇') = (q + (q̇ + q̈ Δt) Δt, q̇ + q̈ Δt)."""
    qd_next = qd + qdd * dt
    return q + qd_next * dt, qd_next
