"""Numerical inverse kinematics on PoE chains (seed 003 section 1.2).

Newton-Raphson on the space form: the error twist ``V_s = Ad_{T_sb} log(T_sb^-1 T_sd)`` (6,)
[ω; v] is driven to zero with ``θ <- θ + step(J_s(θ), V_s)``. The variants differ only in the
step (seed 003's list):

* ``"newton"``: pseudo-inverse ``J^+ V`` (seed's ``IKinSpace``);
* ``"damped"``: ``λ J^+ V`` with 0 < λ <= 1 (a fixed step length: the simplest line search);
* ``"dls"``: damped least squares ``(J^T W J + λ I)^+ J^T W V`` (seed's
  ``IKinSpaceDampedLeastSquare``, W (6, 6) weights the twist rows).

Convergence: ``||ω|| <= eomg`` [rad] and ``||v|| <= ev`` [m], as in the seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.kinematics.poe import adjoint, fk_space, jacobian_space, log6, trans_inv

IK_METHODS = ("newton", "damped", "dls")


@dataclass
class IkResult:
    """theta (n,) [rad]; success: tolerances met; iterations used; err_w [rad], err_v [m] at the end."""

    theta: np.ndarray
    success: bool
    iterations: int
    err_w: float
    err_v: float


def space_error_twist(M: np.ndarray, S: np.ndarray, theta: np.ndarray, T_sd: np.ndarray) -> np.ndarray:
    """Error twist V_s (6,) = Ad_{T_sb} log6(T_sb^-1 T_sd) in the space frame, T_sb = fk_space(θ)."""
    T_sb = fk_space(M, S, theta)
    return adjoint(T_sb) @ log6(trans_inv(T_sb) @ T_sd)


def ik_space(
    S: np.ndarray,
    M: np.ndarray,
    T_sd: np.ndarray,
    theta0: np.ndarray,
    method: str = "newton",
    eomg: float = 1e-6,
    ev: float = 1e-6,
    max_iterations: int = 20,
    lamb: float = 1e-3,
    W: np.ndarray | None = None,
    step: float = 1.0,
) -> IkResult:
    """Joint angles θ (n,) with fk_space(M, S, θ) = T_sd (4, 4), from θ0 (n,).

    Args:
        S: (6, n) space screw axes; M: (4, 4) home pose.
        method: ``newton`` (pseudo-inverse), ``damped`` (``step`` * pseudo-inverse), ``dls``.
        eomg, ev: tolerances on the angular [rad] and linear [m] error.
        max_iterations: iteration cap (seed: 20).
        lamb: DLS damping λ (``dls`` only).
        W: (6, 6) twist-row weights (``dls`` only; identity by default).
        step: step length in (0, 1] (``damped`` only).
    """
    if method not in IK_METHODS:
        raise ValueError(f"unknown IK method {method!r}; choose one of {IK_METHODS}")
    if not 0.0 < step <= 1.0:
        raise ValueError(f"step must be in (0, 1], got {step}")
    theta = np.array(theta0, dtype=float)
    n = theta.shape[0]
    W = np.eye(6) if W is None else W
    i = 0
    Vs = space_error_twist(M, S, theta, T_sd)
    while True:
        ew, ev_ = float(np.linalg.norm(Vs[:3])), float(np.linalg.norm(Vs[3:]))
        done = ew <= eomg and ev_ <= ev
        if done or i >= max_iterations:
            return IkResult(theta, done, i, ew, ev_)
        J = jacobian_space(S, theta)
        if method == "newton":
            dtheta = np.linalg.pinv(J) @ Vs
        elif method == "damped":
            dtheta = step * (np.linalg.pinv(J) @ Vs)
        else:
            A = J.T @ W @ J + lamb * np.eye(n)
            dtheta = np.linalg.pinv(A) @ (J.T @ W @ Vs)
        theta = theta + dtheta
        i += 1
        Vs = space_error_twist(M, S, theta, T_sd)
