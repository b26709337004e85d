"""NumPy twins of the C kernels (``kms2pin/_kernels.c``): one function per C function,
with its signature and semantics (outputs filled in place, the same return values).

:mod:`kms2pin.native` chooses between the two.  The C file documents each kernel; in
brief, the static update's (thesis §2.3) are :func:`linearize`, :func:`frame_coordinates`,
:func:`pose_springs`, :func:`solve_shifted` and, for loop closures, :func:`closure_terms`
and :func:`nullspace_system`, and the tracker's (thesis §2.1.2, the
model in :mod:`kms2pin.ecm.mstep`'s docstring) are the closest approach of pixel rays
to an ellipsoid, the silhouette fit's sums, the E-step's union and the body boxes.
Unlike the C functions these do not check their arguments' types and shapes.

Layouts as in the C file: body coordinates and targets (n, 7) ``[px, py, pz, x, y, z, w]``
(Pinocchio's XYZQUAT), ``J`` Pinocchio's ``data.J`` (6, nv, world frame), pixel rays
``dirs`` (N, 3) world directions at unit camera depth, ``A = R diag(L⁻²) Rᵀ`` an
ellipsoid's metric and ``e`` the camera centre relative to the body centre (world).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

__all__ = [
    "all_unit",
    "body_boxes",
    "clip_limits",
    "closure_terms",
    "ellipsoid_a2",
    "estep_body",
    "estep_camera",
    "estep_view",
    "fit_bodies",
    "fit_body",
    "frame_coordinates",
    "hold_limits",
    "linearize",
    "nullspace_system",
    "outline_pixels",
    "pose_energy",
    "pose_springs",
    "scale_fit",
    "silhouette_add",
    "silhouette_counts",
    "silhouette_swap",
    "silhouette_fit",
    "silhouette_union",
    "solve_shifted",
    "spring_targets",
    "twist_prior",
]

#: ``|h|`` beyond which the logistic edge counts as saturated (σ(-7) < 1e-3); the C file's H_CUT.
H_CUT = 7.0

# ------------------------------------------------------------------ static update

_EPS = np.zeros((3, 9))  # v @ _EPS is [v]x flattened (eq. 2.3)
for _i, _j, _k, _sgn in ((0, 1, 2, -1), (0, 2, 1, 1), (1, 2, 0, -1), (1, 0, 2, 1), (2, 0, 1, -1), (2, 1, 0, 1)):
    _EPS[_k, 3 * _i + _j] = _sgn

# E(theta) = [-v^T; theta0 I - [v]x] (theta = (theta0, v)) is linear in theta: E = theta @ _EBASIS
# reshaped (4, 3); d theta/dt = 1/2 E(theta) omega for a world-frame omega
_EBASIS = np.zeros((4, 12))
for _row, _entries in enumerate(
    (((1, -1), (2, -1), (3, -1)), ((0, 1), (3, 1), (2, -1)), ((3, -1), (0, 1), (1, 1)), ((2, 1), (1, -1), (0, 1)))
):
    for _col, (_comp, _sgn) in enumerate(_entries):
        _EBASIS[_comp, 3 * _row + _col] = _sgn
# E for (x, y, z, w): the same rows and input components, reordered
_EBASIS_XYZW = _EBASIS.reshape(4, 4, 3)[[1, 2, 3, 0]][:, [1, 2, 3, 0]].reshape(4, 12)
_DIAG = np.arange(3)


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (n, 3, 3) of vectors (n, 3) (eq. 2.3)."""
    return (v @ _EPS).reshape(-1, 3, 3)


def linearize(J, X, T, K, S, same_joint, grad, H, diff, hessian) -> tuple[float, float, float]:
    """Spring energy, gradient ``grad = Bᵀ rho = -Bᵀ Q`` (eq. 2.28, rho = K diff = -F of
    eq. 2.33) and Newton matrix ``H = Bᵀ K B`` (+ the second-order term if ``hessian``)
    of the diagonal springs; ``diff = X - T`` with each target's Euler parameters on the
    primary's side (§2.2.1).  ``S`` (n, nv) is 1 where column a moves body i,
    ``same_joint`` (nv, nv) 1 where two columns belong to one joint.  Returns the energy,
    ``|grad|²`` and the largest diagonal entry of ``H``."""
    n, nv = len(X), J.shape[1]
    d = X - T
    flip = np.einsum("ij,ij->i", T[:, 3:], X[:, 3:]) < 0
    if flip.any():
        d[flip, 3:] = X[flip, 3:] + T[flip, 3:]
    diff[:] = d
    rho = K * d  # -F_i (eq. 2.33)
    energy = 0.5 * float(rho.ravel() @ d.ravel())
    p, theta = X[:, :3], X[:, 3:]
    S3 = S[:, None, :]
    Jang = J[3:][None] * S3  # (n, 3, nv)
    Jlin = (J[:3][None] - _skew(p) @ J[3:][None]) * S3  # v(p) = v0 + omega x p
    E = (theta @ _EBASIS_XYZW).reshape(n, 4, 3)
    B = np.concatenate([Jlin, 0.5 * (E @ Jang)], axis=1).reshape(7 * n, nv)  # d q_max / d q
    grad[:] = B.T @ rho.ravel()
    k0 = K.flat[0] if K.size else 0.0
    if k0 > 0 and (K == k0).all():  # the usual case: one stiffness for every coordinate
        Hm = k0 * (B.T @ B)
    else:
        Bk = B * np.sqrt(K).reshape(-1, 1)
        Hm = Bk.T @ Bk
    if hessian:
        Hm += _second_order(rho, theta, E, Jlin, Jang, same_joint)
    H[:] = Hm
    return energy, float(grad @ grad), float(H.diagonal().max())


def _second_order(rho, theta, E, Jlin, Jang, same_joint) -> np.ndarray:
    """sum_i rho_i . d^2 q_max,i / dq_a dq_b (the Newton term Gauss-Newton drops).

    For a <= b (column a an ancestor of b): positions rho . (omega_a x J_b);
    Euler parameters 1/4 [g . (omega_a x omega_b) - (rho_theta . theta)(omega_a . omega_b)]
    with g = E(theta)^T rho_theta; mirrored below the diagonal, the block of one joint
    symmetrized.  As bilinear forms of the angular columns:
    omega_a^T (-[rho_mu]x J_b + 1/4 (-[g]x - c I) omega_b).
    """
    n, nv = Jang.shape[0], Jang.shape[2]
    g = (rho[:, None, 3:] @ E)[:, 0]  # E^T rho_theta
    Z = _skew(-g)
    Z[:, _DIAG, _DIAG] -= np.einsum("ij,ij->i", rho[:, 3:], theta)[:, None]
    Y = _skew(-rho[:, :3]) @ Jlin + 0.25 * (Z @ Jang)
    A = Jang.reshape(3 * n, nv).T @ Y.reshape(3 * n, nv)
    A = np.where(same_joint != 0, 0.5 * (A + A.T), A)
    upper, strict_upper = _triangles(nv)
    return A * upper + (A * strict_upper).T


@functools.lru_cache(maxsize=32)
def _triangles(nv: int) -> tuple[np.ndarray, np.ndarray]:
    """The (nv, nv) masks of the upper triangle with and without the diagonal."""
    return np.triu(np.ones((nv, nv))), np.triu(np.ones((nv, nv)), 1)


def frame_coordinates(rows: Sequence[np.ndarray | tuple], joints, offsets, out) -> None:
    """Body frames from joint placements: ``out[i] = rows[joints[i]] * offsets[i]``, each
    an XYZQUAT 7-vector (``rows[j]`` joint j's world placement, an array or a tuple of 7
    floats; ``offsets[i]`` body i's fixed placement in its joint's frame)."""
    a = np.asarray(rows)[np.asarray(joints).astype(int)]
    av, aw, c = a[:, 3:6], a[:, 6:], offsets[:, :3]
    ov, ow = offsets[:, 3:6], offsets[:, 6:]
    V = _skew(av)  # v x (.)
    vxc = (V @ c[:, :, None])[:, :, 0]  # position: t_a + R(a) c = t_a + c + 2 w (v x c) + 2 v x (v x c)
    out[:, :3] = a[:, :3] + c + 2.0 * (aw * vxc + (V @ vxc[:, :, None])[:, :, 0])
    out[:, 3:6] = aw * ov + ow * av + (V @ ov[:, :, None])[:, :, 0]  # orientation: a (x) o
    out[:, 6] = aw[:, 0] * ow[:, 0] - np.einsum("ij,ij->i", av, ov)


def closure_terms(J, X, moving, kind, end, vec, row, coef, order, r, Jc, H, what) -> None:
    """Residual rows, Jacobian and curvature of loop closures written as sums of dot
    products (:mod:`kms2pin.closures`): term t adds ``coef[t] x_t . y_t`` to row ``row[t]``.
    Side s of a term (``kind[t, s]``): 0 a constant vector ``vec[t, 3s:3s+3]``, 1 that vector
    fixed in end ``end[t, s]``'s frame (R_e v), 2 that end's origin p_e.  ``X`` (E, 7) the
    ends' world placements (XYZQUAT), ``moving`` (E, nv) 1 where column a moves end e.
    Sets ``r`` (rows); with ``what >= 1`` also ``Jc`` (rows, nv), the residual's Jacobian in
    the tangent space; with ``what >= 2`` also each row's curvature ``H[r] = ∇²r_r`` (rows, nv,
    nv), with ∂²x/∂q_a∂q_b = ω_a x ∂x/∂q_b for ``order[a, b]`` (1: a's joint an ancestor of
    b's, ½ within one joint)."""
    kind, end, row = kind.astype(int), end.astype(int), row.astype(int)
    E = len(X)
    R = np.array([pin.Quaternion(x[6], x[3], x[4], x[5]).toRotationMatrix() for x in X]).reshape(E, 3, 3)
    W = J[3:][None] * moving[:, None, :]  # (E, 3, nv): each end's angular Jacobian
    P = (J[:3][None] + _cross_cols(W, X[:, :3])) * moving[:, None, :]  # its origin's velocity

    def side(s):
        k, e, v = kind[:, s], end[:, s], vec[:, 3 * s : 3 * s + 3]
        x = np.where((k == 0)[:, None], v, np.where((k == 1)[:, None], np.einsum("tij,tj->ti", R[e], v), X[e, :3]))
        We = W[e] * (k > 0)[:, None, None]
        Xj = np.where((k == 2)[:, None, None], P[e], _cross_cols(We, x))
        return x, Xj, We

    x, X0, W0 = side(0)
    y, Y1, W1 = side(1)
    r[:] = 0.0
    np.add.at(r, row, coef * np.einsum("ti,ti->t", x, y))
    if what < 1:
        return
    Jc[:] = 0.0
    np.add.at(Jc, row, coef[:, None] * (np.einsum("ti,tia->ta", y, X0) + np.einsum("ti,tia->ta", x, Y1)))
    if what < 2:
        return
    M = np.einsum("tia,tib->tab", W0, _cross_cols(X0, coef[:, None] * y))
    M += np.einsum("tia,tib->tab", W1, _cross_cols(Y1, coef[:, None] * x))
    M *= order
    M += np.einsum("t,tia,tib->tab", coef, X0, Y1)
    H[:] = 0.0
    np.add.at(H, row, M + M.transpose(0, 2, 1))


def _cross_cols(V: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(T, 3, nv): V[t, :, b] x p[t] for every t and column b."""
    x, y, z = V[:, 0], V[:, 1], V[:, 2]
    px, py, pz = (p[:, k, None] for k in range(3))
    return np.stack([y * pz - z * py, z * px - x * pz, x * py - y * px], axis=1)


def nullspace_system(A, g, H, C, N, Hr, gr, lam) -> int:
    """The Newton system reduced to the null space of the constraints ``A dq = 0`` (A (m,
    nv)): a QR factorisation of Aᵀ with column pivoting (LAPACK's dgeqp3), rank where
    |R_kk| drops below 1e-10 |R_00|.  Sets the first k = nv - rank columns of ``N`` to an
    orthonormal basis of the null space, ``lam`` (m) to the basic least-squares solution of
    Aᵀ lam = -g, the top-left k x k block of ``Hr`` to Nᵀ (H + Σ_r lam_r C[r]) N (``C``
    (mc, nv, nv): the first mc rows' curvature) and the first k entries of ``gr`` to Nᵀ g
    (the rest of each zero).  Returns the rank."""
    m, nv = A.shape
    qr, perm, tau, _, _ = lapack.dgeqp3(A.T.copy(order="F"))
    diag = np.abs(qr.diagonal())
    rank = int((diag > 1e-10 * diag[0]).sum()) if diag.size and diag[0] > 0 else 0
    full = np.zeros((nv, nv), order="F")
    full[:, : min(m, nv)] = qr[:, :nv]
    taus = np.zeros(nv)
    taus[:rank] = tau[:rank]  # Q of the reflectors up to the rank (the rest only turns the null space)
    Q = lapack.dorgqr(full, taus, overwrite_a=1)[0] if nv else full
    lam[:] = 0.0
    if rank:
        lam[perm[:rank] - 1] = lapack.dtrtrs(qr[:rank, :rank], -(Q[:, :rank].T @ g))[0]
    k = nv - rank
    Nk = Q[:, rank:]
    Hf = H + (lam[: len(C)] @ C.reshape(len(C), -1)).reshape(nv, nv) if len(C) else H
    R = Nk.T @ Hf @ Nk
    N[:] = 0.0
    Hr[:] = 0.0
    gr[:] = 0.0
    N[:, :k] = Nk
    Hr[:k, :k] = 0.5 * (R + R.T)
    gr[:k] = Nk.T @ g
    return rank


def _pose_errors(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(n, 6) each body's pose error: translation, then the rotation vector of X's rotation
    relative to T's (world axes)."""
    e = np.empty((len(X), 6))
    e[:, :3] = X[:, :3] - T[:, :3]
    e[:, 3:] = _log_quat(_quat_mul_conj(X[:, 3:], T[:, 3:]))
    return e


def pose_energy(X, T, K) -> float:
    """:func:`pose_springs`' energy alone: ``Σ ½ e_iᵀ K_i e_i``."""
    e = _pose_errors(X, T)
    return 0.5 * float(np.einsum("ni,nij,nj->", e, K.reshape(len(X), 6, 6), e))


def pose_springs(J, X, T, K, S, A, g) -> float:
    """The static update with a full 6x6 spring per body (:func:`kms2pin.virtual_work.pose_spring_update`):
    body i's pose error ``e_i = (t_i - t'_i, log(R_i R'_iᵀ))`` (world axes) and its
    LOCAL_WORLD_ALIGNED Jacobian ``J_i`` at the body centre; ``K`` (n, 36) row-major
    6x6 stiffness.  Sets ``A = Σ J_iᵀ K_i J_i`` and ``g = Σ J_iᵀ K_i e_i``; returns the
    energy ``Σ ½ e_iᵀ K_i e_i``."""
    n, nv = len(X), J.shape[1]
    K = K.reshape(n, 6, 6)
    e = _pose_errors(X, T)
    Ji = np.empty((n, 6, nv))
    Ji[:, 3:] = J[3:][None] * S[:, None, :]
    Ji[:, :3] = (J[:3][None] + np.cross(J[3:].T[None], X[:, None, :3]).transpose(0, 2, 1)) * S[:, None, :]
    KJ = (K @ Ji).reshape(6 * n, nv)
    A[:] = Ji.reshape(6 * n, nv).T @ KJ
    g[:] = KJ.T @ e.ravel()
    return 0.5 * float(np.einsum("ni,nij,nj->", e, K, e))


def _eigen_quaternions(R: np.ndarray) -> np.ndarray:
    """(n, 4) ``[x, y, z, w]`` of rotations ``R`` (n, 3, 3) by Eigen's formula term for
    term (Pinocchio's ``SE3ToXYZQUAT``: the same numbers to the last bit)."""
    q = np.empty((len(R), 4))
    m = R
    tr = m[:, 0, 0] + (m[:, 1, 1] + m[:, 2, 2])  # Eigen's trace: the unrolled halves
    pos = tr > 0.0
    u = np.sqrt(tr[pos] + 1.0)
    q[pos, 3] = 0.5 * u
    u = 0.5 / u
    mp = m[pos]
    q[pos, 0] = (mp[:, 2, 1] - mp[:, 1, 2]) * u
    q[pos, 1] = (mp[:, 0, 2] - mp[:, 2, 0]) * u
    q[pos, 2] = (mp[:, 1, 0] - mp[:, 0, 1]) * u
    for r in np.flatnonzero(~pos):
        M = m[r]
        a = 0
        if M[1, 1] > M[0, 0]:
            a = 1
        if M[2, 2] > M[a, a]:
            a = 2
        j, k = (a + 1) % 3, (a + 2) % 3
        v = np.sqrt(M[a, a] - M[j, j] - M[k, k] + 1.0)
        q[r, a] = 0.5 * v
        v = 0.5 / v
        q[r, 3] = (M[k, j] - M[j, k]) * v
        q[r, j] = (M[j, a] + M[a, j]) * v
        q[r, k] = (M[k, a] + M[a, k]) * v
    return q


def spring_targets(R, t, H, inner, floor, T, K) -> float:
    """The full springs (:func:`kms2pin.ecm.springs.pose_springs`) from the M-step fits:
    ``T`` (n, 7) ``[t, x, y, z, w]`` of the fits' rotations ``R`` (n, 9) and centres ``t``
    (Pinocchio's ``SE3ToXYZQUAT`` numbers); ``K`` (n, 36) = ``H`` plus ``floor * hmax /
    S_d²`` on each diagonal entry, S_d the body's mean semi-axis (translations) or 1
    (rotations), ``hmax = max H_dd S_d²`` (returned; -inf for no body).  ``K`` is ``H``
    where ``hmax <= 0``."""
    n = len(R)
    S = np.ones((n, 6))
    S[:, :3] = inner.mean(axis=1)[:, None]
    hmax = float((H[:, ::7] * S**2).max()) if n else -np.inf  # ::7: the 6x6 diagonals
    K[:] = H
    if not hmax <= 0:
        K[:, ::7] += floor * hmax / S**2
    T[:, :3] = t
    T[:, 3:] = _eigen_quaternions(R.reshape(n, 3, 3))
    return hmax


def outline_pixels(R, t, inner, Rwc, centre, K, out) -> None:
    """Ellipsoids' outline points (each centre, then its axes' ends +, then -; rotations
    ``R`` (n, 9), centres ``t`` (n, 3), semi-axes ``inner`` (n, 3), world) projected into
    an undistorted pinhole camera (``Rwc`` world_R_camera, ``centre``, ``K``): ``out``
    (7n, 2) pixels, NaN at or behind the camera plane."""
    n = len(R)
    ends = R.reshape(n, 3, 3) * inner[:, None, :]  # column k: axis k's half length
    axes = ends.transpose(0, 2, 1)
    pts = np.concatenate([t[:, None], t[:, None] + axes, t[:, None] - axes], 1).reshape(-1, 3)
    pc = (pts - centre) @ Rwc
    z = pc[:, 2]
    front = z > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = pc[:, 0] / z, pc[:, 1] / z
    out[:, 0] = np.where(front, x * K[0, 0] + y * K[0, 1] + K[0, 2], np.nan)
    out[:, 1] = np.where(front, x * K[1, 0] + y * K[1, 1] + K[1, 2], np.nan)


def twist_prior(q, iq, iv, axes, rest, free, k, A, g) -> float:
    """The twist prior (:class:`kms2pin.ecm.priors.TwistPrior`) added to the Newton system
    in place: for each spherical joint (``iq``, ``iv`` its first q and v indices, float),
    ``Δ = conj(rest) ⊗ x = (v, w)`` (x the joint's quaternion, (x, y, z, w)), the twist
    ``θ = 2 atan2(v·a, w)`` about unit ``axes`` a (past ``free`` rad when ``free`` > 0),
    ``A += k J Jᵀ`` and ``g += k J θ`` with ``J = dθ/dω``.  Returns ``½ k Σ θ²``."""
    iq, iv = iq.astype(int), iv.astype(int)
    a = axes
    x = q[iq[:, None] + np.arange(4)]  # (n, 4) x y z w
    rv, rw, xv, xw = rest[:, :3], rest[:, 3], x[:, :3], x[:, 3]
    w = rw * xw + np.einsum("ij,ij->i", rv, xv)  # conj(rest) * x
    v = rw[:, None] * xv - xw[:, None] * rv - np.cross(rv, xv)
    flip = w < 0.0  # the same rotation: the twist in (-pi, pi]
    w, v = np.where(flip, -w, w), np.where(flip[:, None], -v, v)
    norm = np.sqrt(w * w + np.einsum("ij,ij->i", v, v))  # q need not be exactly unit
    w, v = w / norm, v / norm[:, None]
    t = np.einsum("ij,ij->i", v, a)
    theta = 2.0 * np.arctan2(t, w)
    den = np.maximum(w * w + t * t, 1e-300)
    J = ((w * w)[:, None] * a + w[:, None] * np.cross(a, v) + t[:, None] * v) / den[:, None]
    if free > 0.0:  # the joints past the free range only
        theta = np.sign(theta) * np.maximum(np.abs(theta) - free, 0.0)
        keep = np.flatnonzero(theta)
        iv, J, theta = iv[keep], J[keep], theta[keep]
    cols = iv[:, None] + np.arange(3)  # each joint's three velocity indices, distinct
    A[cols[:, :, None], cols[:, None, :]] += k * (J[:, :, None] * J[:, None, :])
    g[cols] += k * J * theta[:, None]
    return 0.5 * k * float(theta @ theta)


def _quat_mul_conj(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊗ conj(b) for (n, 4) quaternions in (x, y, z, w) order."""
    av, aw, bv, bw = a[:, :3], a[:, 3:], b[:, :3], b[:, 3:]
    out = np.empty_like(a)
    out[:, 3:] = aw * bw + np.sum(av * bv, axis=1, keepdims=True)
    out[:, :3] = bw * av - aw * bv - np.cross(av, bv)
    return out


def _log_quat(qr: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) of unit quaternions (n, 4), (x, y, z, w): angle in [0, pi]."""
    v, w = qr[:, :3], qr[:, 3]
    sign = np.where(w < 0, -1.0, 1.0)
    v, w = v * sign[:, None], w * sign
    nv = np.linalg.norm(v, axis=1)
    small = nv < 1e-12
    scale = np.where(small, 2.0 / np.maximum(w, 1e-300), 2.0 * np.arctan2(nv, w) / np.where(small, 1.0, nv))
    return v * scale[:, None]


def solve_shifted(H, grad, shift, step) -> bool:
    """Solve ``(H + shift I) step = -grad`` by Cholesky (H's lower triangle); False,
    ``step`` untouched, if the matrix is not positive definite."""
    n = len(grad)
    if n == 0:
        return True
    M = np.array(H, dtype=float)
    M[np.diag_indices(n)] += shift
    L, info = lapack.dpotrf(M, lower=1)
    if info != 0 or not np.isfinite(L).all():
        return False
    step[:] = lapack.dpotrs(L, -np.asarray(grad, dtype=float), lower=1)[0]
    return True


def all_unit(v, starts, lo2, hi2) -> bool:
    """Whether every entry of ``v`` is finite and each 4-block ``v[starts[k]:starts[k]+4]`` (a
    quaternion; float indices) has a squared norm in ``[lo2, hi2]``."""
    if not np.isfinite(v).all():
        return False
    b = v[starts.astype(int)[:, None] + np.arange(4)]
    n2 = np.einsum("ij,ij->i", b, b)
    return bool(((n2 >= lo2) & (n2 <= hi2)).all())


def clip_limits(q, iq, lo, hi) -> None:
    """``q[iq]`` clipped into ``[lo, hi]`` in place (the spec's joint limits; ``iq`` float
    indices, as every index array of the kernels)."""
    i = iq.astype(int)
    q[i] = np.clip(q[i], lo, hi)


def hold_limits(q, iq, iv, lo_at, hi_at, grad, H) -> float:
    """The joints at a limit (``q[iq] <= lo_at`` or ``>= hi_at``) that descent ``-grad``
    pushes outwards taken out of the Newton system in place: zero gradient, zero row and
    column of ``H`` with H's largest diagonal entry (at least 1e-12) on the diagonal
    (projected Levenberg-Marquardt).  Returns ``|grad|²``."""
    x, v = q[iq.astype(int)], iv.astype(int)
    g = grad[v]
    active = ((x <= lo_at) & (g > 0)) | ((x >= hi_at) & (g < 0))
    if active.any():
        a = v[active]
        d = max(float(H.diagonal().max()), 1e-12)
        grad[a] = 0.0
        H[a, :] = 0.0
        H[:, a] = 0.0
        H[a, a] = d
    return float(grad @ grad)


# ------------------------------------------------------------------ ECM


def sigmoid(h: np.ndarray) -> np.ndarray:
    """The logistic function σ(h)."""
    return 0.5 * (1.0 + np.tanh(0.5 * h))


def closest(d: np.ndarray, A: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest approach ``q* = e + s* d`` of each ray ``d`` (N, 3) to an ellipsoid of
    metric ``A`` seen from ``e`` (camera centre relative to the body centre), and ``A q*``."""
    Ae, Ad = A @ e, d @ A
    nn = np.einsum("ij,ij->i", Ad, d)
    s = np.maximum(-(d @ Ae) / np.where(nn > 0, nn, np.inf), 0.0)
    return e + s[:, None] * d, Ae + s[:, None] * Ad


def ellipsoid_a2(dirs, A, e, out) -> None:
    """``out`` (N,): ``a² = q*ᵀ A q*`` of every ray, its closest approach to the ellipsoid
    in the ellipsoid metric."""
    qs, g = closest(dirs, A, e)
    out[:] = np.einsum("ij,ij->i", qs, g)


def _paint(rays, A, e, box, img, v0: int, u0: int) -> None:
    """Bodies ``A``, ``e``, ``box`` ORed into ``img``, whose pixel (0, 0) is (v0, u0)."""
    for Ai, ei, (bu0, bv0, bu1, bv1) in zip(A, e, box.astype(int).tolist()):
        if bu1 <= bu0 or bv1 <= bv0:
            continue
        dirs = rays[bv0:bv1, bu0:bu1].reshape(-1, 3)
        a2 = np.empty(len(dirs))
        ellipsoid_a2(dirs, Ai.reshape(3, 3), ei, a2)
        img[bv0 - v0 : bv1 - v0, bu0 - u0 : bu1 - u0] |= (a2 <= 1.0).reshape(bv1 - bv0, bu1 - bu0)


def silhouette_union(rays, A, e, box, out) -> None:
    """Sets ``out`` (H, W) where the pixel's ray meets body i's ellipsoid (``a² <= 1``,
    :func:`ellipsoid_a2`) within its box ``box[i]`` (u0, v0, u1, v1)."""
    _paint(rays, A, e, box, out, 0, 0)


def _bounding_box(box) -> tuple[int, int, int, int] | None:
    """(u0, v0, u1, v1) holding every non-empty box of ``box`` (n, 4), None if none is."""
    b = np.reshape(box, (-1, 4))
    b = b[(b[:, 2] > b[:, 0]) & (b[:, 3] > b[:, 1])].astype(int)
    return (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()) if len(b) else None


def silhouette_counts(rays, A, e, box, offset, on, off, counts) -> None:
    """``counts[k]``: how many pixels of the union of bodies ``offset[k]:offset[k+1]``
    (as :func:`silhouette_union`'s) the images ``on`` and ``off`` hold."""
    for k in range(len(offset) - 1):
        i0, i1 = int(offset[k]), int(offset[k + 1])
        bb = _bounding_box(box[i0:i1])
        if bb is None:
            counts[k] = 0.0
            continue
        u0, v0, u1, v1 = bb
        img = np.zeros((v1 - v0, u1 - u0), dtype=bool)
        _paint(rays, A[i0:i1], e[i0:i1], box[i0:i1], img, v0, u0)
        counts[k] = np.count_nonzero(img & on[v0:v1, u0:u1]), np.count_nonzero(img & off[v0:v1, u0:u1])


def _count(rays, A, e, box, img, v0: int, u0: int, full: str) -> None:
    """Bodies ``A``, ``e``, ``box`` counted into ``img`` (uint8, each pixel + 1 per body), as
    :func:`_paint` paints them; ValueError ``full`` if a count would pass 255."""
    for Ai, ei, bi in zip(A, e, box):
        one = np.zeros(img.shape, dtype=bool)
        _paint(rays, Ai[None], ei[None], bi[None], one, v0, u0)
        if (img[one] == 255).any():
            raise ValueError(full)
        img += one


def _counts_arg(counts) -> None:
    if np.asarray(counts).dtype != np.uint8 or np.ndim(counts) != 2:
        raise TypeError("counts must be a 2-D uint8 image")


def silhouette_add(rays, A, e, box, counts) -> None:
    """``counts`` (H, W) uint8 + 1 on each pixel of each body's silhouette (as
    :func:`silhouette_union` paints it); ValueError if a count would pass 255."""
    _counts_arg(counts)
    _count(rays, A, e, box, counts, 0, 0, "silhouette_add: more than 255 bodies on a pixel")


def silhouette_swap(rays, A_old, e_old, box_old, A_new, e_new, box_new, counts, mask) -> tuple[int, int]:
    """With ``counts`` (H, W) how many bodies cover each pixel (:func:`silhouette_add`), the
    old bodies among them: the change (intersection, union) of the union's counts against
    ``mask`` when the old bodies are taken out and the new ones painted in."""
    _counts_arg(counts)
    bb = _bounding_box(np.vstack([np.reshape(box_old, (-1, 4)), np.reshape(box_new, (-1, 4))]))
    if bb is None:
        return 0, 0
    u0, v0, u1, v1 = bb
    old = np.zeros((v1 - v0, u1 - u0), dtype=np.uint8)
    _count(rays, A_old, e_old, box_old, old, v0, u0, "silhouette_swap: the old bodies are not all in counts")
    new = np.zeros(old.shape, dtype=bool)
    _paint(rays, A_new, e_new, box_new, new, v0, u0)
    c, m = counts[v0:v1, u0:u1], mask[v0:v1, u0:u1] != 0
    if (old > c).any():
        raise ValueError("silhouette_swap: the old bodies are not all in counts")
    base, trial = c > 0, (c > old) | new
    return (int(np.count_nonzero(trial & m)) - int(np.count_nonzero(base & m)),
            int(np.count_nonzero(trial | m)) - int(np.count_nonzero(base | m)))


def _edge_sums(a2, D, inv, y, o, weight, H, grad) -> tuple[float, float]:
    """One view's cost ``Σ wt r²`` with ``r = y - o - (1 - o) s``, ``s = σ((1 - a²) inv)``,
    and, with ``D = d(a²)/dp`` (N, k), its evidence ``Σ wt (1 - o) s y``; then it also
    adds ``Jᵀ wt J`` to ``H`` and ``Jᵀ wt r`` to ``grad`` over the pixels on the edge
    (``|h| < H_CUT``), ``J = dr/dp``.  Without ``D`` the evidence is 0."""
    h = (1.0 - a2) * inv
    s = sigmoid(h)
    free = 1.0 - o
    r = y - o - free * s
    wt = 1.0 if weight is None else weight  # inlier responsibility
    cost = float((wt * r) @ r)
    if D is None:
        return cost, 0.0
    evidence = float((wt * free) @ (s * y))
    # dr = -free * s(1-s) * dh,  dh = -d(a²) * inv
    w = free * s * (1.0 - s) * inv
    act = (np.abs(h) < H_CUT) & (w > 0)  # off the saturated edge: no gradient
    Jr = D[act] * w[act, None]  # = d r / d p
    Jw = Jr if weight is None else Jr * weight[act, None]
    H += Jw.T @ Jr
    grad += Jw.T @ r[act]
    return cost, evidence


def silhouette_fit(dirs, A, e, inv, y, o, weight, jac, H, grad) -> tuple[float, float]:
    """One body in one view (:mod:`kms2pin.ecm.mstep`): cost and evidence of
    :func:`_edge_sums`; with ``jac`` its Gauss-Newton sums in ``p = (δt, ω)``, a world
    translation and rotation vector of the body, are added to ``H`` (6x6) and ``grad`` (6)."""
    qs, g = closest(dirs, A, e)
    a2 = np.einsum("ij,ij->i", qs, g)
    D = None
    if jac:  # d(a²) = -2 (gᵀ δt + ωᵀ (q* × g)) (envelope theorem)
        D = np.empty((len(qs), 6))
        D[:, :3] = g
        D[:, 3:] = np.cross(qs, g)
        D *= -2.0
    return _edge_sums(a2, D, inv, y, o, weight, H, grad)


def scale_fit(dirs, A, e, R, inner, inv, y, o, weight, H, grad) -> float:
    """:func:`silhouette_fit`'s cost in the log semi-axes of the body's inner ellipsoid,
    its pose (rotation ``R``) held; adds the sums to ``H`` (3x3) and ``grad`` (3)."""
    qs, _ = closest(dirs, A, e)
    xb = (qs @ R) / inner  # closest points in the body frame, in semi-axes
    # a² = Σ_k (r_k·q*)² / L_k², so d(a²)/d log L_k = -2 x_k² (envelope theorem in s*)
    return _edge_sums(np.einsum("ij,ij->i", xb, xb), -2.0 * xb**2, inv, y, o, weight, H, grad)[0]


def estep_body(dirs, A, e, inv, log_free, v0, u0, rows, cols, sp, log_free_o, widen) -> None:
    """One body's share of the union on its box (rows, cols at v0, u0): ``h = (1 - a²) inv``,
    ``sp = softplus(h) = -log(1 - s)``, ``log_free[box] -= sp``; with ``log_free_o`` also
    ``log_free_o[box] -= softplus(widen h)``."""
    a2 = np.empty(len(dirs))
    ellipsoid_a2(dirs, A, e, a2)
    h = (1.0 - a2) * inv
    sp[:] = np.logaddexp(0.0, h)
    box = slice(v0, v0 + rows), slice(u0, u0 + cols)
    log_free[box] -= sp.reshape(rows, cols)
    if log_free_o is not None:
        log_free_o[box] -= np.logaddexp(0.0, widen * h).reshape(rows, cols)


def estep_view(log_free, mask, v0, u0, rows, cols, sp, o, y) -> None:
    """A body's view of the union on its box: ``o = 1 - exp(min(log_free + sp, 0))``, what
    the other bodies explain, and ``y`` the mask there (bool/uint8: 0/1; float64: the value)."""
    box = slice(v0, v0 + rows), slice(u0, u0 + cols)
    o[:] = -np.expm1(np.minimum(log_free[box].ravel() + sp, 0.0))
    m = mask[box]
    y[:] = (m if m.dtype == np.float64 else m != 0).ravel()


def estep_camera(rays, A, e, inv, box, offset, mask, log_free, dirs, sp, o, y) -> None:
    """One camera's E-step: body i (metric ``A[i]`` (9,), ``e[i]``, ``inv[i]``) on its box
    ``(u0, v0, u1, v1)`` (empty: out of view) fills rows ``offset[i]..offset[i+1]`` of the
    outputs, its box row by row: its rays copied out of the ray grid ``rays`` (H, W, 3),
    then :func:`estep_body` per body, then :func:`estep_view` per body; ``log_free``,
    zero on entry, is zeroed again over the boxes."""
    boxes = [(int(u0), int(v0), int(u1 - u0), int(v1 - v0)) for u0, v0, u1, v1 in box.tolist()]
    spans = [(int(a), int(b)) for a, b in zip(offset[:-1].tolist(), offset[1:].tolist())]
    seen = [i for i, (_, _, cols, rows) in enumerate(boxes) if rows > 0 and cols > 0]
    for i in seen:
        (u0, v0, cols, rows), (a, b) = boxes[i], spans[i]
        dirs[a:b] = rays[v0 : v0 + rows, u0 : u0 + cols].reshape(-1, 3)
        estep_body(dirs[a:b], A[i].reshape(3, 3), e[i], inv[i], log_free, v0, u0, rows, cols, sp[a:b], None, 1.0)
    for i in seen:
        (u0, v0, cols, rows), (a, b) = boxes[i], spans[i]
        estep_view(log_free, mask, v0, u0, rows, cols, sp[a:b], o[a:b], y[a:b])
    for i in seen:
        u0, v0, cols, rows = boxes[i]
        log_free[v0 : v0 + rows, u0 : u0 + cols] = 0.0


def _views_eval(views, R: np.ndarray, t: np.ndarray, inner: np.ndarray):
    """Cost, evidence, gradient (6) and Gauss-Newton matrix (6x6) of one body at (R, t)
    over ``views`` (:func:`fit_body`)."""
    A = (R / inner**2) @ R.T
    cost = evidence = 0.0
    grad, H = np.zeros(6), np.zeros((6, 6))
    for dirs, centre, inv, y, o, weight in views:
        c, ev = silhouette_fit(dirs, A, centre - t, inv, y, o, weight, True, H, grad)
        cost += c
        evidence += ev
    return cost, evidence, grad, H


def fit_body(views, R, t, inner, iterations, damping, max_step, R_out, t_out, H_out) -> tuple[float, float]:
    """One body's M-step (:func:`kms2pin.ecm.mstep.fit_body`): damped Gauss-Newton on its
    world pose from ``(R, t)`` over ``views``, each ``(dirs, camera centre, inv = 1/(2δ),
    y, o, weight or None)``; ``max_step <= 0``: no cap.  Sets the pose and the
    Gauss-Newton matrix at it; returns (evidence, cost)."""
    R, t, inner = np.array(R, dtype=float), np.array(t, dtype=float), np.asarray(inner, dtype=float)
    cost, evidence, grad, H = _views_eval(views, R, t, inner)
    if np.any(H):
        size = float(np.mean(inner))
        S = np.r_[np.full(3, size), np.ones(3)]
        offset = np.zeros(6)  # accumulated move from the start (first order in rotation)
        prior = damping * max(float(np.max(np.diag(S[:, None] * H * S[None, :]))), 1e-12)
        lam = 1e-3
        stepn = np.empty(6)
        for _ in range(iterations):
            Hn = S[:, None] * H * S[None, :]
            gn = S * grad + prior * offset / S
            improved = False
            for _ in range(6):
                if not solve_shifted(Hn, gn, prior + lam * float(np.max(np.diag(Hn))), stepn):
                    break
                if max_step > 0:
                    big = max(np.linalg.norm(stepn[:3]), np.linalg.norm(stepn[3:]))
                    stepn *= min(1.0, max_step / max(big, 1e-300))
                step = stepn * S
                R2, t2 = pin.exp3(step[3:]) @ R, t + step[:3]
                c2, e2, g2, H2 = _views_eval(views, R2, t2, inner)
                new_off = offset + step
                p_old = 0.5 * prior * float(np.sum((offset / S) ** 2))
                p_new = 0.5 * prior * float(np.sum((new_off / S) ** 2))
                if 0.5 * c2 + p_new <= 0.5 * cost + p_old:
                    R, t, offset, cost, grad, H, evidence = R2, t2, new_off, c2, g2, H2, e2
                    lam = max(lam * 0.3, 1e-6)
                    improved = True
                    break
                lam *= 10.0
            if not improved:
                break
    R_out[:], t_out[:], H_out[:] = R, t, H
    return evidence, cost


def fit_bodies(cams, inv, seen, R, t, inner, iterations, damping, max_step, R_out, t_out, H_out, out) -> None:
    """:func:`fit_body` of every body of one E-step, its views packed per camera as
    ``(dirs, y, o, offset, centre)`` (body i's pixels ``offset[i]:offset[i + 1]``), with
    ``inv[c, i] = 1/(2δ)`` and ``seen[c, i]`` nonzero where camera c sees body i; start
    poses ``R`` (n, 9), ``t`` (n, 3); sets ``R_out`` (n, 9), ``t_out``, ``H_out`` (n, 36)
    and ``out`` (n, 2) = (evidence, cost)."""
    for i in range(len(R)):
        views = []
        for c, (dirs, y, o, offset, centre) in enumerate(cams):
            if seen[c, i]:
                a, b = int(offset[i]), int(offset[i + 1])
                views.append((dirs[a:b], centre, float(inv[c, i]), y[a:b], o[a:b], None))
        Ri, ti, Hi = np.empty((3, 3)), np.empty(3), np.empty((6, 6))
        out[i] = fit_body(views, R[i].reshape(3, 3), t[i], inner[i], iterations, damping, max_step, Ri, ti, Hi)
        R_out[i], t_out[i], H_out[i] = Ri.ravel(), ti, Hi.ravel()


def body_boxes(R, t, inner, Rwc, centre, K, delta_px, slack_px, width, height, box, delta, status) -> None:
    """Per body (rotation ``R[i]`` (9,), centre ``t[i]``, inner semi-axes ``inner[i]``, world)
    in an undistorted camera (``Rwc`` its world rotation, ``centre``, intrinsics ``K``):
    its edge width ``delta`` (``delta_px`` over a rough outline radius, in 1e-6..0.08) and
    ``status`` 2 with ``box[i] = (u0, v0, u1, v1)``, the pixel box of its inner ellipsoid
    grown to ``h = -H_CUT`` plus ``slack_px`` (the image of the grown quadric,
    ``C* = P Q* Pᵀ``); 0: not in view (behind the camera: ``delta`` 0); 1: straddling
    the camera plane, containing the camera or degenerate.  ``box`` is written for
    status 2 only."""
    n = len(R)
    Rs = R.reshape(n, 3, 3)
    mu = (t - centre) @ Rwc  # camera-frame centres
    depth = mu[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        Ls = np.sort(inner, axis=1)
        radius_px = np.sqrt(K[0, 0] * K[1, 1]) * np.sqrt(Ls[:, 0] * Ls[:, 1]) / depth
        r = np.maximum(radius_px, 1e-6)
        dl = np.minimum(np.maximum(delta_px / r, 1e-6), 0.08)
        L = inner * (np.sqrt(1.0 + 2.0 * H_CUT * dl) + slack_px / r)[:, None]
        R_cb = Rwc.T @ Rs
        sigma = (R_cb * L[:, None, :] ** 2) @ R_cb.transpose(0, 2, 1)
        c_body = -np.einsum("ni,nij->nj", mu, R_cb)  # camera centre in the body frames
        inside = ((c_body / L) ** 2).sum(axis=1) <= 1.0
        front = ~inside & (mu[:, 2] - np.sqrt(sigma[:, 2, 2]) > 0)
        D = K @ (sigma - mu[:, :, None] * mu[:, None, :]) @ K.T  # dual conics P Q* P^T
        a = D[:, 2, 2]
        lo, hi = [], []
        for i in (0, 1):
            b, c = D[:, i, 2], D[:, i, i]
            rt = np.sqrt(np.maximum(b * b - a * c, 0.0))
            k1, k2 = (b - rt) / a, (b + rt) / a
            lo.append(np.minimum(k1, k2))
            hi.append(np.maximum(k1, k2))
    finite = np.isfinite(lo[0]) & np.isfinite(lo[1]) & np.isfinite(hi[0]) & np.isfinite(hi[1])
    visible = depth > 1e-9 * inner.max(axis=1)
    st = np.where(front & finite, 2.0, 1.0)
    st[~visible] = 0.0
    ok = st == 2
    b = np.empty((int(ok.sum()), 4))
    b[:, 0] = np.maximum(np.ceil(lo[0][ok]) - 1, 0)
    b[:, 1] = np.maximum(np.ceil(lo[1][ok]) - 1, 0)
    b[:, 2] = np.minimum(np.floor(hi[0][ok]) + 2, width)
    b[:, 3] = np.minimum(np.floor(hi[1][ok]) + 2, height)
    empty = (b[:, 2] <= b[:, 0]) | (b[:, 3] <= b[:, 1])  # out of the image
    st[np.flatnonzero(ok)[empty]] = 0.0
    box[np.flatnonzero(ok)[~empty]] = b[~empty]
    delta[:] = np.where(visible, dl, 0.0)
    status[:] = st
