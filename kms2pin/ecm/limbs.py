"""The left/right structure of a model, from its names, and its limbs: what the
one-camera tracker's alternative hypotheses (the mirror image, the left/right swap)
and its limb search work on.

Twins are named ``left*`` / ``right*`` (compared in lower case): bodies such as
``leftThigh`` / ``rightThigh``, joints such as ``leftThigh_hip`` / ``rightThigh_hip``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ..robot import Robot


def twin_name(name: str) -> str:
    """The left/right twin of a lower-case name (``leftthigh`` <-> ``rightthigh``); itself if
    it is neither."""
    if name.startswith("left"):
        return "right" + name[4:]
    if name.startswith("right"):
        return "left" + name[5:]
    return name


def left_right_pairs(names: Sequence[str]) -> list[tuple[int, int]]:
    """Index pairs (left, right) of the names that are ``left*`` / ``right*`` twins,
    compared in lower case."""
    index = {n.lower(): i for i, n in enumerate(names)}
    return [(i, index[twin_name(n)]) for n, i in index.items() if n.startswith("left") and twin_name(n) in index]


def sagittal_mirror(robot: Robot) -> np.ndarray | None:
    """Reflection (3x3, root frame) through the model's left/right plane: its normal is
    the mean offset of the ``left*`` bodies' centres from their ``right*`` twins at rest.
    None if the model has no such pairs."""
    pairs = left_right_pairs(robot.bodies)
    if not pairs:
        return None
    poses = robot.body_poses(robot.q_rest)
    root = pin.XYZQUATToSE3(robot.q_rest[:7]) if robot.root == "free" else pin.SE3.Identity()
    lateral = root.rotation.T @ np.mean([poses[i].translation - poses[j].translation for i, j in pairs], axis=0)
    norm = float(np.linalg.norm(lateral))
    if norm < 1e-9:
        return None
    lateral /= norm
    return np.eye(3) - 2.0 * np.outer(lateral, lateral)


def left_right_joints(robot: Robot, sagittal: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(q indices of the ``left*`` joints, of their ``right*`` twins; names compared in lower
    case), if exchanging their angles reflects the body through its own left/right plane
    (``sagittal``, root frame): checked on the body centres at a random configuration.
    None otherwise."""
    if sagittal is None:
        return None
    m = robot.model
    revolute = [j for j in range(1, m.njoints) if m.joints[j].nq == 1]
    pairs = left_right_pairs([m.names[j] for j in revolute])
    if not pairs:
        return None
    a = np.array([m.joints[revolute[i]].idx_q for i, _ in pairs])
    b = np.array([m.joints[revolute[j]].idx_q for _, j in pairs])
    q = robot.q_rest.copy()
    q[np.concatenate([a, b])] += np.random.default_rng(0).uniform(-0.5, 0.5, 2 * len(a))
    swapped = q.copy()
    swapped[a], swapped[b] = q[b], q[a]
    root = pin.XYZQUATToSE3(q[:7]) if robot.root == "free" else pin.SE3.Identity()
    centres = [np.array([root.actInv(M).translation for M in robot.body_poses(x)]) for x in (q, swapped)]
    bodies = {n.lower(): i for i, n in enumerate(robot.bodies)}
    twin = [bodies.get(twin_name(n), -1) for n in bodies]
    if min(twin) < 0:
        return None
    reflected = centres[0] @ sagittal.T
    if np.abs(centres[1] - reflected[twin]).max() > 1e-6 * robot.height:
        return None
    return a, b


def twin_limbs(robot: Robot, limbs: Sequence[str]) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """The pairs of limbs that are left/right twins (``leftUpperArm_shoulder`` and
    ``rightUpperArm_shoulder``), each as (left joint, right joint, q indices of the left
    limb's revolute joints, of their right twins in the same order).  A pair whose joints
    do not all have twins is left out."""
    m = robot.model
    q_index = {m.names[j].lower(): m.joints[j].idx_q for j in range(1, m.njoints) if m.joints[j].nq == 1}
    pairs = []
    for i, t in left_right_pairs(limbs):
        name, twin = limbs[i], limbs[t]
        j = m.getJointId(name)
        chain = [m.names[k].lower() for k in m.subtrees[j] if m.joints[k].nq == 1]
        if not all(twin_name(n) in q_index for n in chain):
            continue
        a = np.array([q_index[n] for n in chain], dtype=int)
        b = np.array([q_index[twin_name(n)] for n in chain], dtype=int)
        pairs.append((name, twin, a, b))
    return pairs


def limb_joints(robot: Robot) -> list[str]:
    """The revolute joints that start a limb: the first joint of every chain hanging off
    a free root's body or off a body that branches (two or more joints below it), e.g.
    the hips, the waist and the shoulders of ``specs/fullbody.kms``.  Joints on the
    world (``root="spec"``) are not limbs: the root is not swung."""
    m = robot.model
    return [
        m.names[j]
        for j in range(1, m.njoints)
        if m.joints[j].nq == 1
        and (p := m.parents[j]) != 0
        and (m.joints[p].nq == 7 or len(m.children[p]) >= 2)
    ]
