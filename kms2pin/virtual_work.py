"""The static update (thesis §2.3): virtual-work equilibrium on Pinocchio Jacobians.

After an M-step each body has a kinematically valid *primary* pose q_i (from the
joint configuration q) and an *intermediate* pose q'_i (the target).  Springs on
each of the 7 maximal coordinates pull with F_i[j] = k_ij (q'_i[j] - q_i[j])
(eq. 2.33); the update returns the valid configuration where B^T Q = 0 (eq. 2.28),
B = d q_max / d q being the map from joint velocities to maximal-coordinate rates
(the role of B_di, eq. 2.27/2.32, with Pinocchio's joint coordinates as the
independent coordinates).  B^T Q is minus the gradient of the spring energy
E = 1/2 sum k_ij (q'_i[j] - q_i[j])^2 over valid configurations, so the
equilibrium is found by a Levenberg-Marquardt descent of E.

Sign consistency.  Euler parameters are unique only up to sign (§2.2.1).  Each
target's Euler parameters are negated whenever their dot product with the
*current* primary body's is negative, at every evaluation; a target equal to the
primary pose therefore exerts no force whichever sign it was given with.
"""

from __future__ import annotations

import functools
import math
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol

import numpy as np
import pinocchio as pin

from .closures import column_order, least_norm, project
from .errors import RobotError, TargetError, did_you_mean
from .native import kernels
from .robot import Robot

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class StaticUpdateResult:
    """Outcome of :func:`static_update`.

    Attributes:
        q: equilibrium configuration (Pinocchio ``q``).
        converged: whether ||B^T Q|| fell below ``tol`` (with joint limits: its part
            along the joints that are free to move).
        iterations: Levenberg-Marquardt iterations taken.
        residual: ||B^T Q|| at ``q`` (eq. 2.28; generalized force, spring units), less
            the components held by active joint limits.
        energy: spring energy 1/2 sum k (q' - q)^2 at ``q``.
        forces: (n_bodies, 7) spring forces F_i (eq. 2.33) at ``q``, body order.
        message: why the iteration stopped.
    """

    q: np.ndarray
    converged: bool
    iterations: int
    residual: float
    energy: float
    message: str = ""
    _force_terms: tuple = field(default=(), repr=False, compare=False)  # (evaluator, X, diff): forces on demand

    @cached_property
    def forces(self) -> np.ndarray:
        """(n_bodies, 7) spring forces F_i (eq. 2.33) at ``q``, body order (computed when first asked)."""
        ev, X, diff = self._force_terms
        return ev.forces(X, diff)


def target_array(robot: Robot, targets: np.ndarray | Mapping[str, pin.SE3 | np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Targets as an (n, 7) array [mu, theta0..3] and an (n,) mask of bodies with springs.

    Accepts an (n, 7) array in ``robot.bodies`` order or a mapping body name ->
    ``pin.SE3`` (or a 7-vector); bodies left out of a mapping get no spring.
    Raises TargetError (a ValueError) naming the body for NaN or non-unit targets.
    """
    n = len(robot.bodies)
    if not isinstance(targets, np.ndarray) and isinstance(targets, Mapping):
        out = np.zeros((n, 7))
        out[:, 3] = 1.0
        mask = np.zeros(n, dtype=bool)
        for name, pose in targets.items():
            if name not in robot.bodies:
                raise TargetError(
                    f"target for unknown body '{name}'{did_you_mean(str(name), robot.bodies)}; "
                    f"'{robot.system.name}' has: {', '.join(robot.bodies)}"
                )
            i = robot.index(name)
            if isinstance(pose, pin.SE3):
                quat = pin.Quaternion(pose.rotation)
                out[i] = [*pose.translation, quat.w, quat.x, quat.y, quat.z]
            else:
                row = np.asarray(pose, dtype=float)
                if row.shape != (7,):
                    raise TargetError(f"target of body '{name}' must be a pin.SE3 or 7 numbers, not shape {row.shape}")
                out[i] = row
            mask[i] = True
    else:
        out = np.array(targets, dtype=float)
        if out.shape != (n, 7):
            raise TargetError(
                f"targets must be an ({n}, 7) array of [mu, theta0..theta3] per body of "
                f"'{robot.system.name}', not shape {out.shape}"
            )
        mask = np.ones(n, dtype=bool)
        if kernels.all_unit(out.ravel(), _euler_starts(n), _UNIT_LO, _UNIT_HI):
            return out, mask  # the usual case: every target finite and unit
    finite = np.isfinite(out).all(axis=1)
    norms = np.sqrt(np.einsum("ij,ij->i", out[:, 3:], out[:, 3:]))
    bad = mask & (~finite | (np.abs(norms - 1.0) > 1e-6))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        name = robot.bodies[i]
        if not finite[i]:
            raise TargetError(f"target of body '{name}' is not finite: {out[i]}")
        raise TargetError(
            f"target of body '{name}' has Euler parameters of norm {norms[i]:.6g}; they must be a unit "
            "quaternion (eq. 2.6)"
        )
    return out, mask


_UNIT_LO, _UNIT_HI = (1.0 - 1e-6) ** 2, (1.0 + 1e-6) ** 2  # squared norms within 1e-6 of unit


@functools.lru_cache(maxsize=16)
def _euler_starts(n: int) -> np.ndarray:
    """Where the Euler parameters of n targets start in their (n, 7) array, raveled (float
    indices, as the kernels take them)."""
    return np.arange(3, 7 * n, 7, dtype=float)


def stiffness_array(robot: Robot, stiffness: float | np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """k as an (n, 7) array from a scalar, a per-body (n,) vector or an (n, 7) array."""
    n = len(robot.bodies)
    if isinstance(stiffness, (int, float)) and math.isfinite(stiffness) and stiffness >= 0:
        k = np.full((n, 7), float(stiffness))  # the usual case: one scalar
        if mask is not None and not mask.all():
            k[~mask] = 0.0
        return k
    k = np.asarray(stiffness, dtype=float)
    if k.ndim == 0:
        k = np.full((n, 7), float(k))
    elif k.shape == (n,):
        k = np.repeat(k[:, None], 7, axis=1)
    elif k.shape != (n, 7):
        raise TargetError(f"stiffness must be a scalar, ({n},) or ({n}, 7), not shape {k.shape}")
    else:
        k = k.copy()
    if not np.all(np.isfinite(k)) or np.any(k < 0):
        raise TargetError("stiffness must be finite and >= 0")
    if mask is not None:
        k[~mask] = 0.0
    return k


class _Structure:
    """Per-robot constants: which velocity columns move each body, and joint blocks."""

    def __init__(self, robot: Robot):
        model = robot.model
        nv = model.nv
        self.support = np.zeros((len(robot.bodies), nv))
        for i, f in enumerate(robot.frame_ids):
            for jid in model.supports[model.frames[f].parentJoint]:
                if jid == 0:
                    continue
                jm = model.joints[jid]
                self.support[i, jm.idx_v : jm.idx_v + jm.nv] = 1.0
        col_joint = np.zeros(nv, dtype=int)
        for jid in range(1, model.njoints):
            jm = model.joints[jid]
            col_joint[jm.idx_v : jm.idx_v + jm.nv] = jid
        # Hessian entries (a <= b) pair an ancestor column a with a descendant b; the
        # columns of one multi-DoF joint (the free flyer) take the symmetric average.
        self.same_joint = (col_joint[:, None] == col_joint[None, :]).astype(float)
        # each body frame as (parent joint, fixed placement in it)
        self.frame_joint = np.array([float(model.frames[f].parentJoint) for f in robot.frame_ids])
        self.frame_offset = np.array([pin.SE3ToXYZQUAT(model.frames[f].placement) for f in robot.frame_ids])
        limited = [j for j in robot.joints if j.nq == 1 and np.isfinite(robot.lower_limits[j.idx_q])]
        # revolute angles without limits: reported modulo a full turn nearest the input
        self.unlimited_revolute_q = np.array(
            [j.idx_q for j in robot.joints if j.kind == "revolute" and not np.isfinite(robot.lower_limits[j.idx_q])],
            dtype=int,
        )
        # revolute and prismatic joints with limits from the spec: (q indices, v indices,
        # lower, upper), or None
        self.limits = None
        if limited:
            iq = np.array([j.idx_q for j in limited])
            iv = np.array([j.idx_v for j in limited])
            lo, hi = robot.lower_limits[iq], robot.upper_limits[iq]
            # (q indices, v indices, lower, upper, and the values at or below / above which a
            # coordinate counts as at its limit)
            self.limits = (iq, iv, lo, hi, lo + 1e-12 * (hi - lo), hi - 1e-12 * (hi - lo))
            # the same for the kernels clip_limits and hold_limits (float64 indices)
            self.kernel_limits = (iq.astype(float), iv.astype(float), lo, hi, *self.limits[4:])
        # loop closures: the column order of their curvature (kms2pin.closures.column_order)
        self.order = column_order(model) if robot.closures else None


_STRUCTURES: weakref.WeakKeyDictionary[Robot, _Structure] = weakref.WeakKeyDictionary()


def _structure(robot: Robot) -> _Structure:
    s = _STRUCTURES.get(robot)
    if s is None:
        s = _STRUCTURES[robot] = _Structure(robot)
    return s


def body_frames(data: pin.Data, s: _Structure) -> np.ndarray:
    """(n, 7) [mu, x, y, z, w] of the body frames after a forward pass into ``data``: the
    joint placements (one Pinocchio call for all) times each frame's fixed offset."""
    X = np.empty((len(s.frame_joint), 7))
    # tuples: Pinocchio's same numbers as SE3ToXYZQUAT's arrays, made faster
    kernels.frame_coordinates([pin.SE3ToXYZQUATtuple(M) for M in data.oMi.tolist()], s.frame_joint, s.frame_offset, X)
    return X


class _Evaluator:
    """Maximal coordinates, springs, B = d q_max / d q and the Newton Hessian at q.

    Internally the Euler parameters are kept in Pinocchio's (x, y, z, w) order, so the
    coordinates come straight from ``SE3ToXYZQUAT``; energy, gradient and Hessian do
    not depend on that order nor on the quaternions' signs.
    """

    def __init__(self, robot: Robot, targets: np.ndarray, k: np.ndarray):
        self.model, self.data = robot.model, robot.data
        self.n = len(robot.frame_ids)
        self.s = _structure(robot)
        self.targets = targets.take(_TO_XYZW, axis=1)
        self.k = k.take(_TO_XYZW, axis=1)

    def linearize(self, q: np.ndarray, hessian: bool = True):
        """Energy, gradient B^T K (q_max - q') = -B^T Q (nv,), Newton Hessian, internal coords."""
        return self.linearize_full(q, hessian)[:4]

    def linearize_full(self, q: np.ndarray, hessian: bool = True):
        """:meth:`linearize` plus the aligned residual q_max - q', ||grad||^2 and max diag H
        (the ``linearize`` kernel)."""
        pin.computeJointJacobians(self.model, self.data, q)
        X = body_frames(self.data, self.s)
        nv = self.model.nv
        grad, H, diff = np.empty(nv), np.empty((nv, nv)), np.empty((self.n, 7))
        energy, gsq, hmax = kernels.linearize(
            self.data.J, X, self.targets, self.k, self.s.support, self.s.same_joint, grad, H, diff, hessian
        )
        return energy, grad, H, X, diff, gsq, hmax

    def forces(self, X: np.ndarray, diff: np.ndarray) -> np.ndarray:
        """Spring forces k (q' - q) (eq. 2.33), (n, 7) in the [mu, theta0..3] layout,
        with the Euler parameters in the theta0 >= 0 convention of Robot.maximal_coordinates,
        from the body coordinates X and their aligned residual ``diff`` (:meth:`linearize_full`)."""
        F = (self.k * diff)[:, _TO_THESIS]
        F[:, :3] *= -1.0  # -k diff; the Euler parameters' sign flipped with theta0 < 0
        F[:, 3:] *= np.where(X[:, 6] >= 0, -1.0, 1.0)[:, None]
        return F


_TO_THESIS = [0, 1, 2, 6, 3, 4, 5]  # [mu, x, y, z, w] -> [mu, theta0..3]
_TO_XYZW = np.array([0, 1, 2, 4, 5, 6, 3])  # [mu, theta0..3] -> [mu, x, y, z, w]


def static_update(
    robot: Robot,
    q: np.ndarray,
    targets: np.ndarray | Mapping[str, pin.SE3 | np.ndarray],
    stiffness: float | np.ndarray = 1.0,
    *,
    max_iter: int = 100,
    tol: float = 1e-9,
) -> StaticUpdateResult:
    """Pull the primary configuration ``q`` into equilibrium with spring targets (§2.3.3).

    Args:
        robot: the loaded system (``root="spec"`` or ``"free"``).
        q: primary configuration (Pinocchio ``q``, radians).  With ``root="free"``
            ``q[3:7]`` is Pinocchio's quaternion (x, y, z, w), scalar LAST; a non-unit
            one is divided by its norm, a zero one is refused.
        targets: intermediate bodies, an (n_bodies, 7) array of [mu, theta0..3] (Euler
            parameters scalar FIRST, eq. 2.7, as :meth:`Robot.maximal_coordinates`) in
            ``robot.bodies`` order, or a mapping body name -> ``pin.SE3`` (bodies left
            out pull with no spring).
        stiffness: k, a scalar, a per-body (n,) vector or an (n, 7) array (eq. 2.33).
        max_iter: iteration limit; hitting it returns ``converged=False``.
        tol: convergence threshold on ||B^T Q|| (eq. 2.28).

    Returns:
        A :class:`StaticUpdateResult`; a non-converged update is returned, not raised.

    Raises:
        TargetError: malformed targets or stiffness, or a ``q`` that
            :class:`Robot`'s methods refuse (wrong shape, non-finite, zero root
            quaternion), with the same message.

    Spherical joints (and a free root) are integrated on their manifold
    (``pin.integrate``).  With loop closures (``robot.closures``) the start is projected
    onto them and the equilibrium is sought on the closed configurations (the thesis's
    coordinate partitioning, §2.3.2: :func:`_closed_static_update`); ``residual`` is then
    ||B^T Q|| along them.  Joint limits from the spec (``revolute(a, b, angle, lower,
    upper)`` and ``prismatic(a, b, offset, lower, upper)``, not in the thesis) are kept: the start is clipped into them, every step is projected onto
    them, and a joint held at a limit by a force pushing it outwards drops out of the
    Newton system (projected Levenberg-Marquardt); the equilibrium is then B^T Q = 0
    along the free joints only (a KKT point of the spring energy within the limits).
    """
    try:
        q_in = robot._check_q(q)
    except RobotError as err:
        raise TargetError(str(err)) from None
    q = q_in.copy()
    tgt, mask = target_array(robot, targets)
    k = stiffness_array(robot, stiffness, mask)
    ev = _Evaluator(robot, tgt, k)
    if robot.closures:
        return _closed_static_update(robot, q_in, ev, max_iter, tol)
    model = robot.model
    step = np.empty(model.nv)
    limited = ev.s.limits is not None
    if limited:
        iq, iv, lo, hi, lo_at, hi_at = ev.s.kernel_limits
        kernels.clip_limits(q, iq, lo, hi)

    energy, grad, H, X, diff, gsq, hmax = ev.linearize_full(q)
    if limited:
        gsq = kernels.hold_limits(q, iq, iv, lo_at, hi_at, grad, H)
    lam = 1e-8
    it = 0
    converged = False
    message = "iteration limit reached"
    tol2 = tol * tol
    while True:
        if gsq <= tol2:
            converged, message = True, "||B^T Q|| below tolerance"
            break
        if it >= max_iter:
            break
        it += 1
        # Levenberg-Marquardt on the Newton system: accept a step only if E decreases.
        def trial(step, q=q):
            q_new = pin.integrate(model, q, step)
            if limited:
                kernels.clip_limits(q_new, iq, lo, hi)
            return q_new

        lam, q_new, lin = _levenberg_marquardt(H, grad, lam, max(hmax, 1e-12), energy, step, trial, ev.linearize_full)
        if q_new is None:
            message = "no step decreases the energy further"
            break
        q = q_new
        energy, grad, H, X, diff, gsq, hmax = lin
        if limited:
            gsq = kernels.hold_limits(q, iq, iv, lo_at, hi_at, grad, H)
    # a revolute angle and itself plus a full turn are one pose: report the one nearest the
    # input (a joint with limits stays where they put it)
    rev = ev.s.unlimited_revolute_q
    q[rev] -= 2.0 * np.pi * np.round((q[rev] - q_in[rev]) / (2.0 * np.pi))
    return StaticUpdateResult(q, converged, it, math.sqrt(gsq), energy, message, (ev, X, diff))


def _closed_static_update(robot: Robot, q_in: np.ndarray, ev: _Evaluator, max_iter: int,
                          tol: float) -> StaticUpdateResult:
    """:func:`static_update` on the configurations that close every loop: Levenberg-Marquardt
    on the Newton system reduced to the closures' null space (B = N, :func:`_closed_system`;
    the Hessian with the constraints' curvature Σ λ ∇²c at the spring forces'
    multipliers), each step brought back onto the closures by Gauss-Newton.  Joints at a
    limit and pushed outwards are held (rows of A)."""
    held = np.zeros(robot.nv, dtype=bool)
    q = _closed_step(robot, q_in, np.zeros(robot.nv), held, ev.s.limits is not None)
    if q is None:
        raise TargetError(f"the loops of '{robot.system.name}' cannot be closed from the start configuration q")
    lin = ev.linearize_full(q)
    system = _closed_system(robot, ev.s, q, lin[1], lin[2])
    lam, it, converged, message = 1e-8, 0, False, "iteration limit reached"
    while True:
        H, g, N, held, gsq, second = system
        if gsq <= tol * tol:
            converged, message = True, "||B^T Q|| below tolerance"
            break
        if it >= max_iter:
            break
        it += 1
        def trial(z, q=q, N=N, held=held, second=second):
            return _closed_step(robot, q, second(N @ z), held, ev.s.limits is not None)

        scale = max(float(H.diagonal().max(initial=0.0)), 1e-12)
        lam, q_try, lin_try = _levenberg_marquardt(H, g, lam, scale, lin[0], np.empty(len(g)), trial,
                                                   ev.linearize_full)
        if q_try is None:
            message = "no step decreases the energy further"
            break
        q, lin = q_try, lin_try
        system = _closed_system(robot, ev.s, q, lin[1], lin[2])
    rev = ev.s.unlimited_revolute_q
    q[rev] -= 2.0 * np.pi * np.round((q[rev] - q_in[rev]) / (2.0 * np.pi))
    return StaticUpdateResult(q, converged, it, math.sqrt(system[4]), lin[0], message, (ev, lin[3], lin[4]))


def _closed_step(robot: Robot, q: np.ndarray, dq: np.ndarray, held: np.ndarray, limited: bool) -> np.ndarray | None:
    """``pin.integrate(q, dq)`` (clipped into the joint limits if ``limited``) brought back
    onto the closures by Gauss-Newton (:func:`kms2pin.closures.project`, to a tenth of their
    tolerance), or None if they cannot be closed there."""
    model, data = robot.model, robot.data
    q_new = pin.integrate(model, q, dq)
    if limited:
        q_new = robot.clamp(q_new)
    q_new, r = project(robot._closures, model, data, q_new, robot.lower_limits, robot.upper_limits, held,
                       0.1 * robot._closure_tol, what=2, order=_structure(robot).order)
    return q_new if np.abs(r).max(initial=0.0) <= 0.1 * robot._closure_tol else None


def _closed_system(robot: Robot, s: _Structure, q: np.ndarray, grad: np.ndarray, H: np.ndarray,
                   newton: bool = True) -> tuple:
    """The Newton system at a closed ``q`` reduced to the closures' null space (the thesis's
    coordinate partitioning, §2.3.2, with an orthonormal basis N for B_di): (Nᵀ (H + Σ λ
    ∇²c) N, Nᵀ g, N, the held columns, |Nᵀ g|², the second-order correction of a step) from
    the gradient ``grad`` and Newton matrix ``H`` at ``q`` (``robot.data`` after
    ``pin.computeJointJacobians`` there; ``kernels.nullspace_system``).  ``newton=False``:
    Gauss-Newton, Nᵀ H N without the curvature (positive semi-definite with H).  λ and the held
    limits come from the least-squares multipliers of g + Aᵀ μ = 0 over the closures' rows
    and the joints at a limit (held where μ pushes outwards)."""
    model, data, C = robot.model, robot.data, robot._closures
    _, Jc, curvature = C.system_at(model, data, q, 2, s.order)  # after project: no new evaluation
    nv = model.nv
    held = np.zeros(nv, dtype=bool)
    bounds = s.limits
    if bounds is not None:
        iq, iv, _, _, lo_at, hi_at = bounds
        low, high = q[iq] <= lo_at, q[iq] >= hi_at
        if (low | high).any():  # a limit holds where its multiplier pushes outwards
            at = iv[low | high]
            mu = _reduce(np.vstack([Jc, np.eye(nv)[at]]), grad, H, curvature)[4][len(Jc):]
            held[at[np.where(low[low | high], mu < 0, mu > 0)]] = True
    any_held = bool(held.any())
    k, N, Hr, gr, _ = _reduce(np.vstack([Jc, np.eye(nv)[held]]) if any_held else Jc, grad, H,
                              curvature if newton else curvature[:0])
    if any_held:
        Jc = Jc.copy()  # system_at's cache is not to be changed
        Jc[:, held] = 0.0

    def second(dq: np.ndarray) -> np.ndarray:
        """``dq`` (along the closures) plus its second-order correction: the least-norm δ with
        Jc δ = -½ dqᵀ ∇²c dq, so that the closures hold to third order at q ⊕ (dq + δ)."""
        v = 0.5 * ((curvature @ dq) @ dq)
        return dq + least_norm(Jc, v)

    return Hr[:k, :k], gr[:k], N[:, :k], held, float(gr @ gr), second


def _reduce(A: np.ndarray, grad: np.ndarray, H: np.ndarray, curvature: np.ndarray):
    """(k, N, Hr, gr, λ) of ``kernels.nullspace_system`` for the constraints A dq = 0."""
    nv = len(grad)
    N, Hr, gr, lam = np.empty((nv, nv)), np.empty((nv, nv)), np.empty(nv), np.empty(len(A))
    rank = kernels.nullspace_system(A, grad, H, curvature, N, Hr, gr, lam)
    return nv - rank, N, Hr, gr, lam


def _levenberg_marquardt(H: np.ndarray, grad: np.ndarray, lam: float, scale: float, energy: float,
                         step: np.ndarray, trial, evaluate):
    """One Levenberg-Marquardt search: the step of (H + lam scale I) step = -grad (in the
    buffer ``step``), lam raised tenfold while H + lam I is not positive definite, the step
    is no descent direction, ``trial(step)`` has no configuration (None) or ``evaluate``'s
    energy (its first value) there is above ``energy``; lam lowered tenfold once one is
    accepted.  Returns (lam, configuration, ``evaluate``'s result), or (lam, None, None)
    after 40 tries."""
    for _ in range(40):
        if kernels.solve_shifted(H, grad, lam * scale, step) and step @ grad < 0:
            q_new = trial(step)
            if q_new is not None:
                lin = evaluate(q_new)
                if lin[0] <= energy + 1e-15 * max(1.0, energy):
                    return max(lam * 0.1, 1e-12), q_new, lin
        lam = max(lam * 10.0, 1e-8)
    return lam, None, None


def perturbed_targets(
    robot: Robot,
    q: np.ndarray,
    rng: np.random.Generator,
    angle_deg: float = 30.0,
    fraction: float = 0.2,
) -> np.ndarray:
    """Synthetic intermediate bodies (thesis §4.1): every primary body of configuration
    ``q`` moved by up to ``fraction`` of its own length (twice its largest inner
    semi-axis; uniform in a ball) and turned by up to ``angle_deg`` about a uniformly
    random axis.  Returns (n, 7) targets [mu, theta0..3]."""
    t = robot.maximal_coordinates(q)
    n = len(t)
    length = np.array([2.0 * robot.inner(b).max() for b in robot.bodies])
    d = rng.normal(size=(n, 3))
    d *= (rng.uniform(0.0, 1.0, n) ** (1 / 3) / np.linalg.norm(d, axis=1))[:, None]
    t[:, :3] += d * (fraction * length)[:, None]
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    half = np.radians(rng.uniform(0.0, angle_deg, n)) / 2.0
    turn = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axes], axis=1)
    w1, v1 = turn[:, :1], turn[:, 1:]
    w2, v2 = t[:, 3:4].copy(), t[:, 4:].copy()
    t[:, 3:4] = w1 * w2 - np.sum(v1 * v2, axis=1, keepdims=True)
    t[:, 4:] = w1 * v2 + w2 * v1 + np.cross(v1, v2)
    return t


class SpringTerm(Protocol):
    """An extra energy term of :func:`pose_spring_update` (a prior): its stiffness is set
    once per update from the springs' first Newton matrix, then it adds its term to the
    Newton system at every configuration tried."""

    def stiffness(self, A: np.ndarray) -> float:
        """The term's stiffness, from the springs' Newton matrix ``A`` (nv, nv) at the start."""

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        """Add the term (stiffness ``k``) to ``A`` and ``g`` at ``q`` (``data`` after a
        forward pass at ``q``); return its energy."""


#: halvings of a pose-spring step that raises the energy before the update gives up
BACKTRACK = 4


def pose_spring_update(
    robot: Robot,
    q: np.ndarray,
    targets: np.ndarray,
    K: np.ndarray,
    *,
    iterations: int = 3,
    terms: Sequence[SpringTerm] = (),
) -> np.ndarray:
    """Virtual-work equilibrium with a full 6x6 spring per body (§2.3.3, eq. 2.28).

    The springs act on each body's pose error ``e_i = (t_i - t'_i, log(R_i R'_iᵀ))``
    (world axes; translation in spec units, rotation in radians) with stiffness ``K_i``;
    the equilibrium ``Σ J_iᵀ K_i e_i = 0`` (Bᵀ Q = 0 with Q_i = -K_i e_i) is found by at
    most ``iterations`` Gauss-Newton steps in joint space, plus ``terms``' energies.
    This is the thesis's per-coordinate stiffness (eq. 2.33) one step further: the
    coordinates of a body are coupled in its own directions, not the world's.

    Each step must lower the energy: a step that raises it is halved up to
    :data:`BACKTRACK` times, and if none lowers it the update stops there.  Joints at
    a spec limit that the step pushes further are held there and the step is solved
    for the others (projected Gauss-Newton's active set); every step is clipped into
    the limits.  With loop closures the start is projected onto them and every step is
    taken along them (:func:`_closed_pose_spring_update`).

    Args:
        robot: the loaded system.
        q: start configuration (Pinocchio ``q``).
        targets: (n_bodies, 7) target poses, ``[t, x, y, z, w]`` (``pin.SE3ToXYZQUAT``).
        K: (n_bodies, 6, 6) stiffness in (world translation, world rotation vector).
        iterations: most Gauss-Newton steps.
        terms: extra energy terms (priors), added in order.

    Returns:
        The equilibrium configuration.
    """
    model, data = robot.model, robot.data
    n, nv = len(targets), model.nv
    st = _structure(robot)
    K36 = K.reshape(n, 36)
    limited = st.limits is not None
    if limited:
        qi, vi, lo, hi = st.limits[:4]
        lo, hi = lo + 1e-12, hi - 1e-12
    ks: list[float] = []  # the terms' stiffnesses, fixed at the first configuration's springs

    def springs(q, system=True):
        """Newton system A, g and energy of the springs (and terms) at q; without
        ``system`` the energy alone (A and g None; the terms add theirs to a scratch)."""
        pin.computeJointJacobians(model, data, q)
        X = body_frames(data, st)
        if system:
            A, g = np.empty((nv, nv)), np.empty(nv)
            energy = kernels.pose_springs(data.J, X, targets, K36, st.support, A, g)
            if not ks:
                ks.extend(t.stiffness(A) for t in terms)
        else:  # the first call has a system: ks are set
            energy = kernels.pose_energy(X, targets, K36)
            A, g = (np.zeros((nv, nv)), np.zeros(nv)) if terms else (None, None)
        for t, k in zip(terms, ks):
            energy += t.add(A, g, q, data, k)
        return (A, g, energy) if system else (None, None, energy)

    if robot.closures:
        return _closed_pose_spring_update(robot, q, springs, iterations)
    A, g, energy = springs(q)
    for it in range(iterations):
        dq = _newton_step(A, g)
        if limited:
            # a joint at a limit that the step pushes further is held there, and the
            # step is solved for the others: its clipped step need not lower the energy
            blocked = np.zeros(nv, dtype=bool)
            blocked[vi] = ((q[qi] <= lo) & (dq[vi] < 0)) | ((q[qi] >= hi) & (dq[vi] > 0))
            if blocked.any():
                free = ~blocked
                dq = np.zeros(nv)
                dq[free] = _newton_step(np.ascontiguousarray(A[np.ix_(free, free)]), g[free])
        def trial(dq, q=q):
            q_new = pin.integrate(model, q, dq)
            return robot.clamp(q_new) if limited else q_new  # projected Gauss-Newton: the spec's joint limits

        # the last step's trials need their energy alone (its A and g would go unused)
        last = it == iterations - 1
        found = _backtracked((lambda x: springs(x, False)) if last else springs, energy, dq, trial)
        if found is None:
            break  # no step lowers the energy: q is (close to) a minimum
        q, A, g, energy, dq = found
        if np.abs(dq).max() < 1e-7:
            break
    return q


def _backtracked(springs, energy: float, step: np.ndarray, trial):
    """The first of ``step``, ``step / 2``, ... (:data:`BACKTRACK` halvings) whose ``trial``
    configuration (None: none there) has a spring energy no higher than ``energy``:
    (configuration, its A, g and energy, the step), or None."""
    for _ in range(BACKTRACK + 1):
        q_new = trial(step)
        if q_new is not None:
            A_new, g_new, e_new = springs(q_new)
            if e_new <= energy * (1.0 + 1e-12):
                return q_new, A_new, g_new, e_new, step
        step = 0.5 * step
    return None


def _closed_pose_spring_update(robot: Robot, q: np.ndarray, springs, iterations: int) -> np.ndarray:
    """:func:`pose_spring_update` along the loop closures: the start projected onto them,
    then Gauss-Newton steps on the system reduced to their null space (:func:`_closed_system`;
    joints at a limit and pushed outwards held), each corrected to second order, brought
    back onto them and halved while it raises the energy.  A start that
    cannot be closed is returned as it is."""
    s = _structure(robot)
    limited = s.limits is not None
    q_start = _closed_step(robot, q, np.zeros(robot.nv), np.zeros(robot.nv, dtype=bool), limited)
    if q_start is None:
        return q
    q = q_start
    A, g, energy = springs(q)
    for _ in range(iterations):
        H, gr, N, held, _, second = _closed_system(robot, s, q, g, A, newton=False)
        def trial(z, q=q, N=N, held=held, second=second):
            return _closed_step(robot, q, second(N @ z), held, limited)

        found = _backtracked(springs, energy, _newton_step(H, gr), trial)
        if found is None:
            break  # no step lowers the energy: q is (close to) a minimum
        q, A, g, energy, z = found
        if np.abs(N @ z).max() < 1e-7:
            break
    return q


def _newton_step(A: np.ndarray, g: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step -A⁻¹ g, with A shifted by 1e-9 of its largest diagonal entry
    (Cholesky, else LU if A is not positive definite; ``A`` may be changed)."""
    n = len(g)
    shift = 1e-9 * max(float(A.diagonal().max()), 1e-300) if n else 0.0
    dq = np.empty(n)
    if not kernels.solve_shifted(A, g, shift, dq):
        A[np.diag_indices(n)] += shift
        dq = -np.linalg.solve(A, g)
    return dq
