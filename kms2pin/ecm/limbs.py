"""The left/right structure of a model, from its names, and its limbs: what the
one-camera tracker's alternative hypotheses (the mirror image, the left/right swap;
:mod:`kms2pin.ecm.symmetry`) and its limb search work on.

Twins are named ``left*`` / ``right*`` (compared in lower case): bodies such as
``leftThigh`` / ``rightThigh``, joints such as ``leftThigh_hip`` / ``rightThigh_hip``; or, where
both names exist, with a side word (``thigh_l`` / ``thigh_r``, and the joint ``thigh_l_joint`` /
``thigh_r_joint`` an import makes of them), a word's ``left`` / ``right`` start after a prefix
(Mixamo's ``mixamorig:LeftArm``) or ``l*`` / ``r*`` (CMU's ``lhand`` / ``rhand``,
``LHipJoint`` / ``RHipJoint``; :func:`twin_name`).
"""

from __future__ import annotations

import re
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..robot import Robot

#: the side words that name a twin where the other side's name exists, as a separate word
#: (``thigh_l_joint`` / ``thigh_r_joint``, ``hand.l`` / ``hand.r``, ``arm_left`` / ``arm_right``)
_SIDES = {"l": "r", "r": "l", "left": "right", "right": "left"}


def _others(name: str) -> list[str]:
    """The names that would be ``name``'s twin, in this order: each side word turned to
    the other side (words split at ``_``, ``.``, ``:``, ``-`` and spaces: ``thigh_l``), a
    word's ``left`` / ``right`` start turned (Mixamo's ``mixamorig:LeftArm``, imported as
    ``mixamorig_leftarm``), then a word's first letter ``l`` <-> ``r`` (CMU's ``lhand``)."""
    words = re.split(r"([_.:\- ])", name)

    def turned(k: int, word: str) -> str:
        return "".join([*words[:k], word, *words[k + 1 :]])

    out = [turned(k, _SIDES[w]) for k, w in enumerate(words) if w in _SIDES]
    out += [turned(k, _SIDES[side] + w[len(side) :]) for k, w in enumerate(words) for side in ("left", "right")
            if w.startswith(side) and len(w) > len(side)]
    out += [turned(k, _SIDES[w[0]] + w[1:]) for k, w in enumerate(words) if w[:1] in ("l", "r") and len(w) > 1]
    return out


def _first(name: str, names: Collection[str]) -> str | None:
    return next((o for o in _others(name) if o in names), None)


def twin_name(name: str, names: Collection[str] = ()) -> str:
    """The left/right twin of a lower-case name: ``left*`` <-> ``right*`` always
    (``leftthigh`` <-> ``rightthigh``); among ``names`` (lower case too: the model's names
    of the same kind) also a side word turned (``hip_l_joint`` <-> ``hip_r_joint``,
    ``arm_left`` <-> ``arm_right``), a word's side start (``mixamorig_leftarm`` <->
    ``mixamorig_rightarm``) or a word's first letter ``l`` <-> ``r`` (``lhand`` <-> ``rhand``),
    where the two names are each other's first such twin.  Itself if it has none."""
    if name.startswith("left"):
        return "right" + name[4:]
    if name.startswith("right"):
        return "left" + name[5:]
    other = _first(name, names) if names else None
    return other if other is not None and _first(other, names) == name else name


def left_right_pairs(names: Sequence[str]) -> list[tuple[int, int]]:
    """Index pairs (left, right) of the names that are left/right twins
    (:func:`twin_name`), compared in lower case."""
    index = {n.lower(): i for i, n in enumerate(names)}
    pairs = []
    for n, i in index.items():
        t = twin_name(n, index)
        if t != n and t in index and is_left(n, t):
            pairs.append((i, index[t]))
    return pairs


def is_left(name: str, twin: str) -> bool:
    """Whether ``name`` is the left one of the twins ``name`` / ``twin`` (lower case): where
    they first differ, it has the ``l``."""
    return next((a == "l" for a, b in zip(name, twin) if a != b), False)


def sagittal_mirror(robot: Robot) -> np.ndarray | None:
    """Reflection (3x3, root frame) through the model's left/right plane: its normal is
    the mean offset of the left bodies' centres from their right twins at rest.
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


@dataclass(frozen=True)
class Sides:
    """Which side of the body's midline each body with a left/right twin lies on
    (:func:`sides`): ``body`` (indices), the nearest ancestor without a twin that each
    hangs from (``anchor``: the chest for an arm's bodies, the pelvis for a leg's), the
    sagittal plane's normal in that ancestor's axes (``normal``, (n, 3)) and the side of
    it the body's centre lies on at rest (``sign``, ±1)."""

    body: np.ndarray
    anchor: np.ndarray
    normal: np.ndarray
    sign: np.ndarray

    def crossed(self, Rs: np.ndarray, ts: np.ndarray) -> np.ndarray:
        """Per configuration (bodies' rotations ``Rs`` (k, n_bodies, 3, 3) and centres
        ``ts`` (k, n_bodies, 3), world; only this object's bodies and anchors are read),
        whether some body's centre lies across its anchor's sagittal plane from its side
        at rest."""
        n = np.einsum("kaij,aj->kai", Rs[:, self.anchor], self.normal)
        side = np.einsum("kai,kai->ka", n, ts[:, self.body] - ts[:, self.anchor])
        return (side * self.sign < 0).any(axis=1)


def sides(robot: Robot, hinged: Collection[int] = ()) -> Sides | None:
    """The :class:`Sides` of the roots of ``robot``'s twin limbs (:func:`left_right_pairs`):
    the bodies from the one hanging from a body without a twin down to the first of
    ``hinged`` (bodies on a spherical joint with a hinge below: a collar and an upper arm, a
    hip and a thigh), or that first body alone; those off the midline at rest.  None
    without a sagittal plane."""
    S = sagittal_mirror(robot)
    if S is None:
        return None
    w, v = np.linalg.eigh(S)
    poses = robot.body_poses(robot.q_rest)
    root = pin.XYZQUATToSE3(robot.q_rest[:7]).rotation if robot.root == "free" else np.eye(3)
    normal = root @ v[:, int(np.argmin(w))]  # world, at rest
    twins = {k for pair in left_right_pairs(robot.bodies) for k in pair}
    parent = {j.child: j.parent for j in robot.system.joints if j.child is not None}
    hinged = {robot.bodies[i] for i in hinged}
    rows = []
    for i in sorted(twins):
        path = [robot.bodies[i]]  # from body i up to the first body without a twin
        while robot.index(path[-1]) in twins and parent.get(path[-1]) in robot.bodies:
            path.append(parent[path[-1]])
        k = robot.index(path[-1])
        chain = path[-2::-1]  # from the anchor's child down to body i
        # the limb's root: down to its first spherical joint with a hinge below (a collar and
        # an upper arm; a thigh), or the anchor's child alone; the bodies below may cross
        top = next((n + 1 for n, b in enumerate(chain) if b in hinged), 1)
        if k in twins or len(chain) > top:
            continue
        offset = float(normal @ (poses[i].translation - poses[k].translation))
        if abs(offset) > 1e-3 * robot.height:
            rows.append((i, k, poses[k].rotation.T @ normal, np.sign(offset)))
    if not rows:
        return None
    body, anchor, n, sign = zip(*rows)
    return Sides(np.array(body), np.array(anchor), np.array(n), np.array(sign))


def hinged_bodies(robot: Robot) -> list[int]:
    """The bodies on a spherical joint whose one movable joint below is a hinge (an upper
    arm above its elbow, a thigh above its knee): the roots of twin limbs :func:`sides` takes."""
    kinds = {j.name: j.kind for j in robot.joints}
    out = []
    for spec in robot.system.joints:
        if kinds.get(spec.name) != "spherical" or spec.child is None:
            continue
        below = [kinds[c.name] for c in robot.system.joints
                 if c.parent == spec.child and kinds.get(c.name) in ("spherical", "revolute")]
        if below == ["revolute"]:
            out.append(robot.index(spec.child))
    return out


def movable(robot: Robot, jid: int) -> bool:
    """Whether Pinocchio joint ``jid`` is one a limb moves: one coordinate (revolute,
    prismatic) or a spherical joint (a quaternion), not the free root."""
    j = robot.model.joints[jid]
    return j.nq == 1 or (j.nq == 4 and j.nv == 3)


def limb_joints(robot: Robot) -> list[str]:
    """The joints that start a limb: the first joint of every chain hanging off a free
    root's body or off a body that branches (two or more joints below it), e.g. the
    hips, the waist and the shoulders of ``specs/fullbody.kms`` (revolute) and of
    ``specs/human.kms`` (spherical).  Joints on the world (``root="spec"``) are not
    limbs: the root is not swung."""
    m = robot.model
    return [
        m.names[j]
        for j in range(1, m.njoints)
        if movable(robot, j)
        and (p := m.parents[j]) != 0
        and (m.joints[p].nq == 7 or len(m.children[p]) >= 2)
    ]
