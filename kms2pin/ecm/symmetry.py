"""The model's left/right symmetry in joint space: twin joints, and a pose mirrored.

Reflecting a body through its own sagittal plane (``S``, a reflection in the root frame,
:func:`~kms2pin.ecm.limbs.sagittal_mirror`) puts its left limbs where the right ones
were.  In joint coordinates that is an exchange of twin joints (``left*`` / ``right*``):

- one-coordinate joints (revolute, prismatic) exchange their values, or their values
  negated where the twin's axis is mirrored the other way (:meth:`Symmetry.sign`: the
  mirror of a turn by θ about ``a`` is a turn by θ about ``-S a``, an axial vector, and of
  a slide along ``a`` one along ``S a``; the thesis's specs give left and right knees the
  same axis, a hand-written model may give them opposite ones); an unpaired one (a waist's
  twist) is mirrored in place the same way;
- a spherical joint's rotation ``R`` is in its parent body's axes (``A``, that frame's
  rest rotation relative to the root's).  Its rotation relative to rest, ``Δ = R R_restᵀ``,
  is mirrored by conjugation with ``T = A_twinᵀ S A`` (an improper matrix mapping the
  joint's parent axes onto its twin's mirror image): the twin's new rotation is
  ``T Δ Tᵀ R_twin,rest``.  An unpaired spherical joint (a waist, a neck) is its own twin.

The mirror is checked on the body centres at a random configuration (the swapped pose's
centres are the reflected centres of the twin bodies, within :data:`MIRROR_TOLERANCE` of the
height: a real subject's sides differ a little): a model whose twins do not mirror each
other has no :class:`Symmetry`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ..coordinates import JointCoordinates, quaternion_matrix
from ..robot import Robot
from .limbs import is_left, sagittal_mirror, twin_name

__all__ = ["MIRROR_TOLERANCE", "SAME_AXIS", "Symmetry", "spherical_angle"]

#: how far (a share of the model's height) the swapped pose's body centres may lie from
#: the reflected ones for the twins to count as mirror images: a real subject's two sides
#: differ (CMU subject 131's by 2.5-3.6 % of the height), and a swap is a candidate that
#: ECM refines, not a pose taken as it is.  A hinge whose axis points the other way from
#: its twin's mirror image is mirrored by negating its angle (:meth:`Symmetry.sign`); a
#: short segment still mirrored wrong some other way (3.4 % of the human's height for a
#: foot turned round) passes the check, and its swap is then a worse candidate, which the
#: fit turns down
MIRROR_TOLERANCE = 0.05
#: the cosine above which two joint axes count as the same (or, negated, opposite)
SAME_AXIS = np.cos(np.radians(10.0))


def _coeffs(R: np.ndarray) -> np.ndarray:
    return pin.Quaternion(R).coeffs()


def spherical_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (rad) between two spherical joints' quaternions (x, y, z, w)."""
    return float(np.linalg.norm(pin.log3(quaternion_matrix(a).T @ quaternion_matrix(b))))


class Symmetry:
    """Twin joints and the mirrored exchange of a configuration's coordinates (module
    docstring).  Build with :meth:`of`, which returns None for a model without a
    sagittal plane or whose twins do not mirror each other."""

    def __init__(self, robot: Robot, S: np.ndarray):
        self.robot, self.S = robot, S
        by_name = {j.name.lower(): j for j in robot.joints if j.kind in ("revolute", "prismatic", "spherical")}
        self.twin: dict[str, JointCoordinates] = {}
        for low, j in by_name.items():
            t = by_name.get(twin_name(low, by_name))
            if t is not None and t is not j and t.kind == j.kind:
                self.twin[j.name] = t
        self._sign = self._signs()
        self._frame = {j.name: self._parent_axes(j) for j in robot.joints if j.kind == "spherical"}
        self._rest = {j.name: quaternion_matrix(robot.q_rest[j.idx_q : j.idx_q + 4]) for j in robot.joints
                      if j.kind == "spherical"}

    @classmethod
    def of(cls, robot: Robot) -> Symmetry | None:
        """The model's symmetry, checked (module docstring), or None."""
        S = sagittal_mirror(robot) if robot.root == "free" else None
        if S is None:
            return None
        sym = cls(robot, S)
        return sym if sym._mirrors() else None

    def _signs(self) -> dict[str, float]:
        """Per one-coordinate joint, the sign its twin's (or, unpaired, its own) value takes
        in the mirror image: +1 where the twin's axis at rest, in the root's frame, is the
        joint's mirrored (``-S a`` for a revolute joint, ``S a`` for a prismatic one), -1
        where it is the opposite; joints with neither keep +1 (the check of :meth:`of`
        judges them)."""
        robot = self.robot
        pin.computeJointJacobians(robot.model, robot.data, robot.q_rest)
        root = pin.XYZQUATToSE3(robot.q_rest[:7]).rotation
        joints = {j.name: j for j in robot.joints if j.kind in ("revolute", "prismatic")}
        axes = {}
        for name, j in joints.items():
            col = pin.getJointJacobian(robot.model, robot.data, robot.model.getJointId(name), pin.WORLD)[:, j.idx_v]
            a = root.T @ (col[3:] if j.kind == "revolute" else col[:3])
            axes[name] = a / np.linalg.norm(a)
        sign = {}
        for name, a in axes.items():
            b = axes.get(self.twin[name].name if name in self.twin else name)
            if b is not None:
                image = (-1.0 if joints[name].kind == "revolute" else 1.0) * (self.S @ a)
                sign[name] = -1.0 if float(image @ b) < -SAME_AXIS else 1.0
        return sign

    def sign(self, j: JointCoordinates) -> float:
        """The factor joint ``j``'s twin's value takes when mirrored onto it (module docstring)."""
        return self._sign.get(j.name, 1.0)

    def _parent_axes(self, j: JointCoordinates) -> np.ndarray:
        """A spherical joint's parent body's axes at rest, in the root body's frame."""
        root = pin.XYZQUATToSE3(self.robot.q_rest[:7]).rotation
        parent = j.spec.parent
        return root.T @ self.robot.body_pose(self.robot.q_rest, parent).rotation

    def mirrored(self, q: np.ndarray, j: JointCoordinates, onto: JointCoordinates) -> np.ndarray:
        """Joint ``j``'s coordinates of ``q`` mirrored onto joint ``onto`` (its twin, or
        itself): the value for a one-coordinate joint (negated where :meth:`sign` says so),
        ``T Δ Tᵀ R_rest`` for a spherical one."""
        if j.kind != "spherical":
            return self.sign(onto) * q[j.idx_q : j.idx_q + 1]
        T = self._frame[onto.name].T @ self.S @ self._frame[j.name]
        delta = quaternion_matrix(q[j.idx_q : j.idx_q + 4]) @ self._rest[j.name].T
        return _coeffs(T @ delta @ T.T @ self._rest[onto.name])

    def exchange(self, q: np.ndarray, left: Sequence[JointCoordinates], right: Sequence[JointCoordinates]) -> np.ndarray:
        """``q`` with every joint of ``left`` and its twin in ``right`` exchanged, mirrored."""
        out = q.copy()
        for a, b in zip(left, right):
            out[b.idx_q : b.idx_q + b.nq] = self.mirrored(q, a, b)
            out[a.idx_q : a.idx_q + a.nq] = self.mirrored(q, b, a)
        return out

    def swap(self, q: np.ndarray) -> np.ndarray:
        """``q`` reflected through the body's own sagittal plane: every pair of twins
        exchanged (mirrored), every unpaired spherical joint mirrored in place."""
        left = [j for name, j in self._named()
                if name in self.twin and is_left(name.lower(), self.twin[name].name.lower())]
        out = self.exchange(q, left, [self.twin[j.name] for j in left])
        for j in self.robot.joints:
            if j.name not in self.twin and (j.kind == "spherical" or self.sign(j) < 0):
                out[j.idx_q : j.idx_q + j.nq] = self.mirrored(q, j, j)
        return out

    def _named(self) -> list[tuple[str, JointCoordinates]]:
        return [(j.name, j) for j in self.robot.joints]

    def swapped_joints(self) -> list[JointCoordinates]:
        """The joints :meth:`swap` changes."""
        return [j for j in self.robot.joints if j.name in self.twin or j.kind == "spherical" or self.sign(j) < 0]

    def difference(self, q: np.ndarray, left: Sequence[JointCoordinates], right: Sequence[JointCoordinates]) -> float:
        """The largest difference (rad, or length units) between each joint of ``left`` and
        its twin's coordinates mirrored onto it: 0 when exchanging them changes nothing."""
        worst = 0.0
        for a, b in zip(left, right):
            if a.kind == "spherical":
                worst = max(worst, spherical_angle(q[a.idx_q : a.idx_q + 4], self.mirrored(q, b, a)))
            else:
                worst = max(worst, float(abs(q[a.idx_q] - self.sign(a) * q[b.idx_q])))
        return worst

    def _mirrors(self) -> bool:
        """Whether :meth:`swap` reflects the body centres (within :data:`MIRROR_TOLERANCE`),
        at the rest pose with every joint it changes moved at random (up to 0.5 rad)."""
        robot = self.robot
        rng = np.random.default_rng(0)
        q = robot.q_rest.copy()
        for j in self.swapped_joints():
            if j.kind == "spherical":
                q[j.idx_q : j.idx_q + 4] = _coeffs(pin.exp3(rng.uniform(-0.5, 0.5, 3)) @ self._rest[j.name])
            else:
                q[j.idx_q] += rng.uniform(-0.5, 0.5)
        swapped = self.swap(q)
        root = pin.XYZQUATToSE3(q[:7])
        centres = [np.array([root.actInv(M).translation for M in robot.body_poses(x)]) for x in (q, swapped)]
        bodies = {n.lower(): i for i, n in enumerate(robot.bodies)}
        twin = [bodies.get(twin_name(n, bodies), -1) for n in bodies]
        if min(twin) < 0:
            return False
        return bool(np.abs(centres[1] - (centres[0] @ self.S.T)[twin]).max() <= MIRROR_TOLERANCE * robot.height)
