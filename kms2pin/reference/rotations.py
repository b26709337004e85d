"""Rotation helpers of thesis §2.2.1 and §2.2.3, written from the equations.

Independent of :mod:`kms2pin.model` and of Pinocchio on purpose: the reference
re-derives the conventions so that it can check them.

* :func:`axis_angle_matrix` -- eq. 2.4 (right-handed rotation by ``angle`` about a unit axis).
* :func:`quat_to_matrix` -- eq. 2.7, Euler parameters scalar first.
* :func:`matrix_to_quat` -- the inverse of eq. 2.7 by Shepperd's method.  Eq. 2.9-2.10
  as printed in the thesis do not tie the sign of the axis to the direction of the
  rotation, so they return the inverse rotation for many matrices; they are not used.
* :func:`alignment_matrix` -- eq. 2.12, R_align with R_align o_child = o_parent.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Entries of a computed alignment matrix below this are set to exactly zero, so the
#: symbolic constraints have exact zeros where the geometry has them.
CLEAN_TOL = 1e-15


def skew(v: np.ndarray | Sequence[float]) -> np.ndarray:
    """The cross-product matrix ṽ of eq. 2.3 (ṽ x = v × x)."""
    v = np.asarray(v, dtype=float)
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def axis_angle_matrix(axis: np.ndarray | Sequence[float], angle: float) -> np.ndarray:
    """Eq. 2.4: rotation by ``angle`` (radians, right-handed) about unit ``axis``."""
    v1, v2, v3 = np.asarray(axis, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    C = 1.0 - c
    return np.array(
        [
            [v1 * v1 * C + c, v2 * v1 * C - v3 * s, v3 * v1 * C + v2 * s],
            [v1 * v2 * C + v3 * s, v2 * v2 * C + c, v3 * v2 * C - v1 * s],
            [v1 * v3 * C - v2 * s, v2 * v3 * C + v1 * s, v3 * v3 * C + c],
        ]
    )


def axis_angle_quat(axis: np.ndarray | Sequence[float], angle: float) -> np.ndarray:
    """Eq. 2.5: Euler parameters [cos(θ/2), v sin(θ/2)]."""
    v = np.asarray(axis, dtype=float)
    return np.concatenate([[np.cos(angle / 2.0)], v * np.sin(angle / 2.0)])


def quat_to_matrix(theta: np.ndarray | Sequence[float]) -> np.ndarray:
    """Eq. 2.7: the rotation matrix (body -> world) of Euler parameters θ0..θ3."""
    t0, t1, t2, t3 = np.asarray(theta, dtype=float)
    return np.array(
        [
            [1 - 2 * t2 * t2 - 2 * t3 * t3, 2 * (t1 * t2 - t0 * t3), 2 * (t1 * t3 + t0 * t2)],
            [2 * (t1 * t2 + t0 * t3), 1 - 2 * t1 * t1 - 2 * t3 * t3, 2 * (t2 * t3 - t0 * t1)],
            [2 * (t1 * t3 - t0 * t2), 2 * (t2 * t3 + t0 * t1), 1 - 2 * t1 * t1 - 2 * t2 * t2],
        ]
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit Euler parameters θ with ``quat_to_matrix(θ) == R`` (Shepperd's method).

    Picks the largest of 4θ0², 4θ1², 4θ2², 4θ3² (from the trace and the diagonal) to
    divide by, so it is accurate for every rotation including half turns.  Sign:
    θ0 >= 0 (for θ0 == 0 exactly, the first nonzero of θ1..θ3 is positive).
    """
    R = np.asarray(R, dtype=float)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        t0 = 0.5 * np.sqrt(max(1.0 + tr, 0.0))
        f = 0.25 / t0
        q = [t0, (R[2, 1] - R[1, 2]) * f, (R[0, 2] - R[2, 0]) * f, (R[1, 0] - R[0, 1]) * f]
    elif k == 1:
        t1 = 0.5 * np.sqrt(max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 0.0))
        f = 0.25 / t1
        q = [(R[2, 1] - R[1, 2]) * f, t1, (R[0, 1] + R[1, 0]) * f, (R[0, 2] + R[2, 0]) * f]
    elif k == 2:
        t2 = 0.5 * np.sqrt(max(1.0 - R[0, 0] + R[1, 1] - R[2, 2], 0.0))
        f = 0.25 / t2
        q = [(R[0, 2] - R[2, 0]) * f, (R[0, 1] + R[1, 0]) * f, t2, (R[1, 2] + R[2, 1]) * f]
    else:
        t3 = 0.5 * np.sqrt(max(1.0 - R[0, 0] - R[1, 1] + R[2, 2], 0.0))
        f = 0.25 / t3
        q = [(R[1, 0] - R[0, 1]) * f, (R[0, 2] + R[2, 0]) * f, (R[1, 2] + R[2, 1]) * f, t3]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    if q[0] < 0 or (q[0] == 0 and q[np.flatnonzero(q[1:])[0] + 1] < 0):
        q = -q
    return q


def perpendicular_axis(v: np.ndarray | Sequence[float]) -> np.ndarray:
    """v × e_k / |v × e_k| for the basis vector e_k least aligned with v (lowest k on ties)."""
    v = np.asarray(v, dtype=float)
    k = int(np.argmin(np.abs(v)))
    e = np.zeros(3)
    e[k] = 1.0
    w = np.cross(v, e)
    return w / np.linalg.norm(w)


def alignment_matrix(o_parent: np.ndarray | Sequence[float], o_child: np.ndarray | Sequence[float]) -> np.ndarray:
    """Eq. 2.12: R_align with ``R_align @ o_child == o_parent``.

    Axis (o_child × o_parent)/|·|, angle acos(o_parent · o_child) (computed as
    atan2(|×|, ·)).  Parallel axes give I; antiparallel axes give a half turn about
    :func:`perpendicular_axis` of ``o_child``.  Entries below :data:`CLEAN_TOL` are
    set to exactly 0.
    """
    p = np.asarray(o_parent, dtype=float)
    c = np.asarray(o_child, dtype=float)
    p = p / np.linalg.norm(p)
    c = c / np.linalg.norm(c)
    cross = np.cross(c, p)
    n = float(np.linalg.norm(cross))
    dot = float(np.dot(p, c))
    if n < 1e-12:
        R = np.eye(3) if dot > 0 else axis_angle_matrix(perpendicular_axis(c), np.pi)
    else:
        R = axis_angle_matrix(cross / n, np.arctan2(n, dot))
    R[np.abs(R) < CLEAN_TOL] = 0.0
    return R


def joint_rotation(
    kind: str, o_parent: np.ndarray | Sequence[float], o_child: np.ndarray | Sequence[float], angle=0.0
) -> np.ndarray:
    """R_ij: Rot(o_parent, angle) R_align for a revolute joint (eq. 2.16), Exp(r) R_align
    for a spherical joint (``angle`` the rotation vector r, radians, parent frame), R_align
    for fixed and prismatic joints (eq. 2.12)."""
    Ra = alignment_matrix(o_parent, o_child)
    if kind == "revolute":
        p = np.asarray(o_parent, dtype=float)
        return axis_angle_matrix(p / np.linalg.norm(p), angle) @ Ra
    if kind == "spherical":
        r = np.asarray(angle, dtype=float).reshape(3)
        n = float(np.linalg.norm(r))
        return (axis_angle_matrix(r / n, n) if n > 0 else np.eye(3)) @ Ra
    return Ra
