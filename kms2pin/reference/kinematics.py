"""Forward kinematics in maximal coordinates (thesis §2.2.2-2.2.4, eq. 2.12-2.16)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..errors import RobotError, did_you_mean
from ..model import System
from .rotations import joint_rotation, matrix_to_quat, quat_to_matrix

ROOTS = ("spec", "free")


def check_root(root: str) -> str:
    if root not in ROOTS:
        raise RobotError(f"root must be one of {ROOTS}, not {root!r}")
    return root


MOVING = ("revolute", "spherical", "prismatic")


def joint_angles(system: System, angles: Mapping[str, object] | None) -> dict[str, object]:
    """Every moving joint's value: ``angles`` over the spec's defaults.

    Revolute: the angle in radians; spherical: a rotation vector (3,) in radians in the
    parent body's frame (R_ij = Exp(r) R_align); prismatic: the offset (spec length units).
    """
    out: dict[str, object] = {}
    for j in system.joints:
        if j.kind == "revolute":
            out[j.name] = np.radians(j.default_angle)
        elif j.kind == "spherical":
            out[j.name] = np.radians(np.asarray(j.default_rotation, dtype=float))
        elif j.kind == "prismatic":
            out[j.name] = float(j.default_offset)
    kinds = {j.name: j.kind for j in system.joints}
    for name, value in (angles or {}).items():
        if name not in out:
            fixed = [j.name for j in system.joints if j.kind not in MOVING]
            why = " (it is a fixed joint)" if name in fixed else did_you_mean(name, out)
            raise RobotError(f"'{system.name}' has no moving joint '{name}'{why}")
        if kinds[name] == "spherical":
            out[name] = np.asarray(value, dtype=float).reshape(3)
        else:
            out[name] = float(value)
    return out


def forward_kinematics(
    system: System,
    angles: Mapping[str, float] | None = None,
    root_pose: tuple | None = None,
    root: str = "spec",
) -> np.ndarray:
    """Maximal coordinates q (n, 7) = [mu, θ0..θ3] per body, bodies in ``system.bodies`` order.

    Walks the bodies in preorder (§2.2.2): for body j with lower body i (or the
    inertial frame: mu = 0, R = I) and joint bound vectors (a_ij, o_ij), (a_ji, o_ji),
    R_ij = Rot(o_ij, angle) R_align (revolute, eq. 2.16), Exp(r) R_align (spherical)
    or R_align (fixed and prismatic, eq. 2.12), R_0j = R_0i R_ij and
    mu_j = mu_i + R_0i (a_ij + d o_ij) - R_0j a_ji (eq. 2.14; d is a prismatic joint's
    offset, else 0).

    Args:
        angles: joint name -> value (:func:`joint_angles`: radians, a rotation vector
            in radians, or an offset); missing joints take the spec's default.  Angle 0
            means the joint axes are aligned.
        root_pose: ``(mu, theta)`` of the root body (centre in the world and unit Euler
            parameters).  Only with ``root="free"``; None puts the root where the
            spec's joint to the inertial frame puts it (at that joint's angle).
        root: ``"spec"`` keeps the root body's joint to the inertial frame, ``"free"``
            lets ``root_pose`` place the root body.

    Euler parameters are normalised with θ0 >= 0 (except a given root pose, which is
    only normalised).
    """
    check_root(root)
    if root_pose is not None and root != "free":
        raise RobotError("root_pose needs root='free' (with root='spec' the root joint places the root body)")
    theta = joint_angles(system, angles)
    n = len(system.bodies)
    index = {b.name: i for i, b in enumerate(system.bodies)}
    q = np.empty((n, 7))
    rot = [np.empty((3, 3))] * n
    for i, (body, joint) in enumerate(zip(system.bodies, system.joints)):
        if joint.child != body.name:
            raise RobotError(f"joint '{joint.name}' does not connect body '{body.name}' (system not in preorder)")
        if i == 0 and root == "free" and root_pose is not None:
            mu, th = root_pose
            mu = np.asarray(mu, dtype=float).reshape(3)
            th = np.asarray(th, dtype=float).reshape(4)
            th = th / np.linalg.norm(th)
            R = quat_to_matrix(th)
            q[i, :3], q[i, 3:] = mu, th
            rot[i] = R
            continue
        if joint.parent is None:
            mu_p, R_p = np.zeros(3), np.eye(3)
        else:
            p = index[joint.parent]
            if p >= i:
                raise RobotError(f"body '{joint.parent}' comes after its child '{body.name}' (not preorder)")
            mu_p, R_p = q[p, :3], rot[p]
        value = theta.get(joint.name, 0.0)
        R_ij = joint_rotation(joint.kind, joint.parent_bvec.orient, joint.child_bvec.orient, value)
        R = R_p @ R_ij
        a_ij = np.asarray(joint.parent_bvec.pos, dtype=float)
        if joint.kind == "prismatic":
            o_ij = np.asarray(joint.parent_bvec.orient, dtype=float)
            a_ij = a_ij + value * o_ij / np.linalg.norm(o_ij)
        mu = mu_p + R_p @ a_ij - R @ np.asarray(joint.child_bvec.pos, dtype=float)
        rot[i] = R
        q[i, :3] = mu
        q[i, 3:] = matrix_to_quat(R)
    return q
