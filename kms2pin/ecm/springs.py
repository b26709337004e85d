"""The springs of the tracker's static update (thesis §2.3.3): M-step fits -> equilibrium.

After the M-step every body has an intermediate pose (its own fit) and a Gauss-Newton
matrix that says how firmly the images fix each of its coordinates.  The thesis lets
"k be different for every coordinate of every body ... to compensate for noise or
ambiguities": here the springs are that matrix, so a body seen edge-on, along the
viewing ray, or mostly hidden is soft in the directions the images do not fix and the
well-seen bodies carry it.  With the M-step's own curvature as the springs, M-step +
static update is close to one Gauss-Newton step on the whole-body silhouette fit in
joint space.

``"full"``: a 6x6 spring per body on its pose error (:func:`kms2pin.virtual_work.pose_spring_update`)
plus a floor; ``"diagonal"``: the thesis's diagonal spring per maximal coordinate
(eq. 2.33, :func:`kms2pin.virtual_work.static_update`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ..native import kernels
from ..robot import Robot
from ..virtual_work import SpringTerm, pose_spring_update, static_update
from .mstep import BodyFit, PackedFits

__all__ = ["diagonal_update", "full_update", "pose_springs"]


def pose_springs(fits: Sequence[BodyFit] | PackedFits, inner: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Targets (n, 7) ``[t, x, y, z, w]`` and stiffnesses (n, 6, 6) of the full springs:
    each body's M-step matrix plus ``floor`` times the stiffest body's diagonal entry
    (translations scaled by each body's mean semi-axis).  None if no body is seen.
    One ``spring_targets`` kernel call; its quaternions are ``pin.SE3ToXYZQUAT``'s."""
    n = len(fits)
    if isinstance(fits, PackedFits):
        R, t, H = fits.R.reshape(n, 9), fits.t, fits.hessian.reshape(n, 36)
    else:
        R = np.array([f.pose.rotation for f in fits]).reshape(n, 9)
        t = np.array([f.pose.translation for f in fits]).reshape(n, 3)
        H = np.array([f.hessian for f in fits]).reshape(n, 36)
    T, K = np.empty((n, 7)), np.empty((n, 36))
    hmax = kernels.spring_targets(np.ascontiguousarray(R), t, H, np.asarray(inner, dtype=float), float(floor), T, K)
    if hmax <= 0:
        return None
    return T, K.reshape(n, 6, 6)


def full_update(robot: Robot, q: np.ndarray, fits: Sequence[BodyFit] | PackedFits, inner: np.ndarray, floor: float,
                iterations: int, terms: Sequence[SpringTerm] = ()) -> np.ndarray:
    """The static update with the full springs (and ``terms``, the priors)."""
    springs = pose_springs(fits, inner, floor)
    if springs is None:
        return q
    return pose_spring_update(robot, q, *springs, iterations=iterations, terms=terms)


def _delta_to_stiffness(H: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Diagonal spring stiffness on [mu, theta0..3] (7,) from a 6x6 Gauss-Newton matrix
    in (world translation, world rotation vector): δθ = ½ E(θ) ω and ω = 2 E(θ)ᵀ δθ,
    so the rotational energy ½ ωᵀ H_ωω ω is ½ δθᵀ (4 E H_ωω Eᵀ) δθ."""
    w, x, y, z = theta
    E = np.array([[-x, -y, -z], [w, z, -y], [-z, w, x], [y, -x, w]])
    Kth = 4.0 * E @ H[3:, 3:] @ E.T
    return np.r_[np.diag(H[:3, :3]), np.diag(Kth)]


def diagonal_update(robot: Robot, q: np.ndarray, fits: Sequence[BodyFit] | PackedFits, floor: float) -> np.ndarray:
    """The static update with the thesis's diagonal springs (eq. 2.33), each the
    diagonal of its M-step matrix in maximal coordinates, relative to the stiffest,
    at least ``floor``."""
    n = len(fits)
    targets, k = np.empty((n, 7)), np.zeros((n, 7))
    for i, fit in enumerate(fits):
        quat = pin.Quaternion(fit.pose.rotation)
        theta = np.array([quat.w, quat.x, quat.y, quat.z])
        targets[i] = [*fit.pose.translation, *theta]
        k[i] = _delta_to_stiffness(fit.hessian, theta)
    kmax = float(k.max())
    if kmax <= 0:
        return q
    k = np.maximum(k / kmax, floor)
    return robot.clamp(static_update(robot, q, targets, k, max_iter=30, tol=1e-10).q)
