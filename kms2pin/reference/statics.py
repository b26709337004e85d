"""The static update of thesis §2.3.3 in maximal coordinates: springs (eq. 2.33) pull the
primary bodies toward the intermediate bodies (targets) until B_diᵀ Q = 0 (eq. 2.28).

Sign alignment: Euler parameters are unique only up to sign, so every target's Euler
parameters are negated whenever their dot product with the *current* primary body's
Euler parameters is negative; this is re-checked at every evaluation, and the energy,
the forces and the equilibrium all use the aligned targets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import TargetError
from ..model import System
from ._blas import single_threaded_blas
from .symbolic import SymbolicModel, svd_pinv, symbolic_model

UNIT_TOL = 1e-6  # |‖θ'‖ - 1| allowed for a target's Euler parameters


@dataclass(frozen=True)
class ReferenceResult:
    """Outcome of :func:`solve_equilibrium`.

    q: (n, 7) equilibrium configuration (quaternion signs continue those of q0).
    energy: ½ Σ k (q' - q)² at q with aligned targets.
    residual: ‖B_diᵀ Q‖ at q (B_di of the numerical partition at q).
    iterations: Newton iterations taken.
    converged: residual <= tol * max(1, ‖Q‖).
    constraint_error: max |C(q)|.
    """

    q: np.ndarray
    energy: float
    residual: float
    iterations: int
    converged: bool
    constraint_error: float


# ---------------------------------------------------------------------- springs
def _as_targets(targets, n: int | None = None) -> np.ndarray:
    t = np.asarray(targets, dtype=float)
    if t.ndim != 2 or t.shape[1] != 7 or (n is not None and t.shape[0] != n):
        want = f"({n}, 7)" if n is not None else "(n, 7)"
        raise TargetError(f"targets must have shape {want}, not {t.shape}")
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(t), axis=1))[0])
        raise TargetError(f"target of body {bad} is not finite: {t[bad]}")
    norms = np.linalg.norm(t[:, 3:], axis=1)
    if np.any(np.abs(norms - 1.0) > UNIT_TOL):
        bad = int(np.flatnonzero(np.abs(norms - 1.0) > UNIT_TOL)[0])
        raise TargetError(f"target Euler parameters of body {bad} are not unit (norm {norms[bad]:.9g})")
    return t


def stiffness_matrix(stiffness: float | np.ndarray, n: int) -> np.ndarray:
    """Broadcast a scalar, (n,) or (n, 7) stiffness to (n, 7); k >= 0, finite."""
    k = np.asarray(stiffness, dtype=float)
    if k.ndim == 0:
        k = np.full((n, 7), float(k))
    elif k.shape == (n,):
        k = np.repeat(k[:, None], 7, axis=1)
    elif k.shape != (n, 7):
        raise TargetError(f"stiffness must be a scalar, shape ({n},) or ({n}, 7), not {k.shape}")
    if not np.all(np.isfinite(k)) or np.any(k < 0):
        raise TargetError("stiffness must be finite and >= 0")
    return k


def aligned_targets(q: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """``targets`` with each body's Euler parameters negated where θ'·θ < 0 (θ from ``q``)."""
    q = np.asarray(q, dtype=float).reshape(-1, 7)
    t = np.array(targets, dtype=float).reshape(-1, 7)
    flip = np.einsum("ij,ij->i", q[:, 3:], t[:, 3:]) < 0
    t[flip, 3:] *= -1.0
    return t


def spring_forces(q: np.ndarray, targets: np.ndarray, stiffness: float | np.ndarray) -> np.ndarray:
    """F_i[j] = k_ij (q'_i[j] - q_i[j]) (eq. 2.33) with aligned targets, shape (n, 7)."""
    q = np.asarray(q, dtype=float).reshape(-1, 7)
    t = _as_targets(targets, q.shape[0])
    k = stiffness_matrix(stiffness, q.shape[0])
    return k * (aligned_targets(q, t) - q)


def energy(q: np.ndarray, targets: np.ndarray, stiffness: float | np.ndarray) -> float:
    """E(q) = ½ Σ k_ij (q'_ij - q_ij)² with aligned targets."""
    q = np.asarray(q, dtype=float).reshape(-1, 7)
    t = _as_targets(targets, q.shape[0])
    k = stiffness_matrix(stiffness, q.shape[0])
    return 0.5 * float(np.sum(k * (aligned_targets(q, t) - q) ** 2))


def _energy_fast(q: np.ndarray, t: np.ndarray, k: np.ndarray) -> float:
    return 0.5 * float(np.sum(k * (aligned_targets(q, t) - q.reshape(-1, 7)) ** 2))


def equilibrium_residual(
    system: System, q: np.ndarray, targets: np.ndarray, stiffness: float | np.ndarray, root: str = "spec"
) -> float:
    """‖B_diᵀ Q‖ at ``q`` (eq. 2.28), B_di from the numerical partition at ``q``."""
    model = symbolic_model(system, root)
    Q = spring_forces(np.asarray(q, dtype=float).reshape(-1, 7), targets, stiffness).reshape(-1)
    return float(np.linalg.norm(model.B_di(q).T @ Q))


# ---------------------------------------------------------------------- the solver
def _restore(
    model: SymbolicModel,
    q: np.ndarray,
    dep: np.ndarray,
    pinv: np.ndarray | None = None,
    tol: float = 1e-15,
    max_iter: int = 40,
):
    """Restore C(q) = 0 by moving the dependent coordinates only, q_I held (eq. 2.26 with
    the SVD pseudo-inverse C_qd⁺ of eq. 2.31): q_D <- q_D - C_qd⁺ C(q).

    ``pinv`` (C_qd⁺ at the start of the step) is reused while it contracts fast (a chord
    iteration, cheap); otherwise C_qd⁺ is recomputed at every iterate (Newton).
    Returns (q, max |C|), or (None, max |C|) if it fails to converge.
    """
    q = q.copy()
    err = np.inf
    for _ in range(max_iter):
        c = model.C(q)
        new_err = float(np.max(np.abs(c)))
        if new_err <= tol or (new_err < 1e-13 and new_err >= 0.5 * err):  # done, or at rounding level
            return q, new_err
        if not np.isfinite(new_err) or new_err > 10 * err:
            return None, new_err
        if pinv is not None and new_err > 0.25 * err:  # chord too slow: switch to Newton
            pinv = None
        err = new_err
        P = pinv if pinv is not None else svd_pinv(model.C_q(q)[:, dep])
        q[dep] -= P @ c
    c_err = float(np.max(np.abs(model.C(q))))
    return (q, c_err) if c_err < 1e-12 else (None, c_err)


def project(model: SymbolicModel, q: np.ndarray, max_iter: int = 50) -> np.ndarray:
    """Nearest-ish valid configuration: Gauss-Newton q <- q - C_q⁺ C(q) on all coordinates."""
    q = np.asarray(q, dtype=float).reshape(-1).copy()
    for _ in range(max_iter):
        c = model.C(q)
        if np.max(np.abs(c)) <= 1e-15:
            break
        q -= svd_pinv(model.C_q(q)) @ c
    return q


def solve_equilibrium(
    system: System,
    q0: np.ndarray,
    targets: np.ndarray,
    stiffness: float | np.ndarray,
    root: str = "spec",
    tol: float = 1e-12,
    max_iter: int = 200,
    model: SymbolicModel | None = None,
) -> ReferenceResult:
    """Static update of §2.3.3: the valid q nearest (a stationary point of E) to the targets.

    Newton's method on the independent coordinates q_I, entirely in maximal coordinates:

    1. at the current valid q, partition the coordinates numerically
       (:meth:`SymbolicModel.partition`) and form B_di and C_qd⁺ (eq. 2.30-2.32);
    2. gradient of E(q(q_I)) is -B_diᵀ Q; Hessian B_diᵀ K B_di + B_diᵀ (Σ_r λ_r ∂²C_r) B_di
       with λ = C_qd⁺ᵀ Q_D (the second-order change of q_D; exact Newton).  Where that
       Hessian is not positive definite, Gauss-Newton B_diᵀ K B_di (+ a small damping);
    3. step q_I by α δ (α from a backtracking Armijo line search on E; in the final
       Newton steps, whose decrease of E is below its rounding error, whole steps are
       taken), predict q_D to first order (q + α B_di δ), then restore C(q) = 0 by
       Newton on q_D alone with q_I held (eq. 2.26 with the SVD pseudo-inverse of
       eq. 2.31).

    The quaternion signs of the result continue those of ``q0``.  OpenBLAS runs with one
    thread during the solve (see :mod:`kms2pin.reference._blas`).

    Stops when ‖B_diᵀ Q‖ <= tol · max(1, ‖Q‖) (converged) or after ``max_iter`` iterations
    or when no step decreases E any more.

    Args:
        q0: (n, 7) valid primary configuration (a drift up to 1e-6 in C is projected away).
        targets: (n, 7) intermediate bodies q' (unit Euler parameters).
        stiffness: scalar, (n,) per body or (n, 7) per coordinate; 0 = no spring.
    """
    model = model or symbolic_model(system, root)
    n = model.n_bodies
    q = np.asarray(q0, dtype=float)
    if q.shape != (n, 7):
        raise TargetError(f"q0 must have shape ({n}, 7), not {q.shape}")
    t = _as_targets(targets, n)
    k = stiffness_matrix(stiffness, n)
    q = q.reshape(-1).copy()
    c = model.C(q)
    worst = int(np.argmax(np.abs(c)))
    if abs(c[worst]) > 1e-6 or not np.all(np.isfinite(q)):
        raise TargetError(f"q0 is not a valid configuration: |C| = {abs(c[worst]):.3g} in row '{model.labels[worst]}'")
    with single_threaded_blas():
        if abs(c[worst]) > 1e-14:
            q = project(model, q)
        return _newton(model, q, t, k, tol, max_iter)


def _newton(model: SymbolicModel, q: np.ndarray, t: np.ndarray, k: np.ndarray, tol: float, max_iter: int):
    n = model.n_bodies
    kf = k.reshape(-1)
    it = 0
    E = _energy_fast(q, t, k)
    while True:
        Cq = model.C_q(q)
        B, pinv, part = model.B_di_and_pinv(q, Cq=Cq)
        Q = kf * (aligned_targets(q, t).reshape(-1) - q)
        grad = -B.T @ Q
        res = float(np.linalg.norm(grad))
        if res <= tol * max(1.0, float(np.linalg.norm(Q))) or it >= max_iter:
            break
        it += 1
        lam = pinv.T @ Q[part.dependent]
        H_gn = B.T @ (kf[:, None] * B)
        H = H_gn + B.T @ model.constraint_hessian(q, lam) @ B
        H = 0.5 * (H + H.T)
        try:
            L = np.linalg.cholesky(H)
            delta = -np.linalg.solve(L.T, np.linalg.solve(L, grad))
            kind = "newton"
        except np.linalg.LinAlgError:
            mu = 1e-10 * max(1.0, float(np.trace(H_gn)))
            delta = -np.linalg.solve(H_gn + mu * np.eye(len(grad)), grad)
            kind = "gn"
        slope = float(grad @ delta)
        step = B @ delta
        # In the final Newton steps the decrease of E is below its rounding error, so a
        # line search on E would reject good steps: take them whole.
        final = kind == "newton" and -slope < 1e-10 * max(1.0, E)
        alpha, accepted = 1.0, False
        while alpha > 1e-12:
            trial, _ = _restore(model, q + alpha * step, part.dependent, pinv)
            if trial is not None:
                E_trial = _energy_fast(trial, t, k)
                if (final and E_trial <= E + 1e-12 * max(1.0, E)) or E_trial <= E + 1e-4 * alpha * slope + 1e-15 * max(
                    1.0, E
                ):
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            break
        q, E = trial, E_trial

    q_out = q.reshape(n, 7)
    return ReferenceResult(
        q=q_out,
        energy=_energy_fast(q, t, k),
        residual=res,
        iterations=it,
        converged=res <= tol * max(1.0, float(np.linalg.norm(Q))),
        constraint_error=float(np.max(np.abs(model.C(q)))),
    )
