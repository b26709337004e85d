"""The syntax-free kinematic model a spec compiles to (thesis §2.1.1, §2.2).

Frames and units: every body frame is its ellipsoid centre with the ellipsoid's
axes (thesis mu_0,i and R_0,i, eq. 2.1); bound-vector positions are in the frame
of the body that owns them (or in the inertial frame for inertial bvecs); lengths
are in the spec's units (metres in the thesis models); angles in degrees.

A :class:`System` is a spanning tree rooted at the inertial frame: each body has
exactly one joint to its parent (``Joint.parent is None`` means the inertial frame) and
``System.bodies`` lists the bodies in preorder traversal (thesis §3.2.1).  The joints
that close kinematic loops (thesis §4.2) are ``System.closures``: each joins the body of
its first argument (``parent``) to the body of its second (``child``; None for the
inertial frame) and closes the loop :meth:`System.loop` through the tree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .errors import Diagnostic

WORLD = "world"


@dataclass(frozen=True)
class Loc:
    """Where something was written: 1-based line and column."""

    line: int = 0
    column: int = 0


@dataclass(frozen=True)
class BoundVector:
    """A unit vector bound to a point (thesis §3.1.4).

    ``pos`` is the joint position a and ``orient`` the unit joint axis o, both in
    the owner's frame (a body frame, or the inertial frame when ``body`` is None).
    """

    name: str
    pos: tuple[float, float, float]
    orient: tuple[float, float, float]
    body: str | None = None
    loc: Loc = Loc()

    @property
    def qualified_name(self) -> str:
        return f"{self.body}.{self.name}" if self.body else self.name


@dataclass(frozen=True)
class Body:
    """A rigid body shaped as concentric inner/outer ellipsoids (thesis §2.1.1).

    ``inner`` and ``outer`` are the semi-axes along the body's x, y, z.
    """

    name: str
    inner: tuple[float, float, float]
    outer: tuple[float, float, float]
    bvecs: dict[str, BoundVector] = field(default_factory=dict, compare=False)
    system: str = ""
    loc: Loc = Loc()


#: Degrees of freedom of each joint type of the language.
JOINT_DOF = {"fixed": 0, "revolute": 1, "spherical": 3, "prismatic": 1}


@dataclass(frozen=True)
class Joint:
    """A fixed, revolute, spherical or prismatic joint, oriented parent (lower) -> child (upper).

    ``parent`` is None for a joint to the inertial frame; then ``parent_bvec`` is
    an inertial bvec.  The rest pose (kms2pin's extensions for the last two types):

    * revolute: ``default_angle`` (degrees), a right-handed rotation of the child
      about the parent end's axis (eq. 2.16);
    * spherical: ``default_rotation`` (degrees), a rotation vector r in the parent
      body's frame, R_ij = Exp(r) R_align;
    * prismatic: ``default_offset`` (spec length units), the signed distance of the
      child end's point from the parent end's along the parent end's axis.

    ``limits`` bound a revolute joint's angle (degrees) or a prismatic joint's offset
    (length units) when the spec gives them; None: no limits.

    A loop closure (:attr:`System.closures`) has no rest value nor limits, and its
    ``child`` is None when its second argument is an inertial bvec.
    """

    name: str
    kind: str  # "fixed" | "revolute" | "spherical" | "prismatic"
    parent: str | None
    child: str | None
    parent_bvec: BoundVector
    child_bvec: BoundVector
    default_angle: float = 0.0
    loc: Loc = Loc()
    limits: tuple[float, float] | None = None
    default_rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    default_offset: float = 0.0

    @property
    def parent_link(self) -> str:
        return self.parent if self.parent is not None else WORLD

    @property
    def child_link(self) -> str:
        return self.child if self.child is not None else WORLD

    @property
    def dof(self) -> int:
        """Degrees of freedom: 0 fixed, 1 revolute or prismatic, 3 spherical."""
        return JOINT_DOF[self.kind]


@dataclass(frozen=True)
class System:
    """One ``rigidBodySystem``: bodies in preorder, one tree joint per body, and the
    joints that close loops (``closures``, in spec order)."""

    name: str
    bodies: tuple[Body, ...]
    joints: tuple[Joint, ...]  # joints[i] connects bodies[i] to its parent
    loc: Loc = Loc()
    closures: tuple[Joint, ...] = ()

    @property
    def root(self) -> Body:
        return self.bodies[0]

    @cached_property
    def _by_name(self) -> dict[str, tuple[Body, Joint]]:
        return {b.name: (b, j) for b, j in zip(self.bodies, self.joints)}

    @cached_property
    def _children(self) -> dict[str | None, list[Joint]]:
        out: dict[str | None, list[Joint]] = {}
        for j in self.joints:
            out.setdefault(j.parent, []).append(j)
        return out

    def body(self, name: str) -> Body:
        return self._by_name[name][0]

    def joint_of(self, body: str) -> Joint:
        """The joint of ``body`` to its parent (KeyError for an unknown body)."""
        return self._by_name[body][1]

    def children(self, body: str | None) -> list[Joint]:
        """The joints whose parent is ``body`` (None: the inertial frame), in spec order."""
        return list(self._children.get(body, ()))

    @property
    def dof(self) -> int:
        """Degrees of freedom of the joints (the spec's root joint included)."""
        return sum(j.dof for j in self.joints)

    def count(self, kind: str) -> int:
        """How many tree joints of type ``kind`` the system has."""
        return sum(1 for j in self.joints if j.kind == kind)

    def _ancestry(self, body: str | None) -> list[str | None]:
        """``body``, its parent, ..., the inertial frame (None)."""
        out = [body]
        while out[-1] is not None:
            out.append(self.joint_of(out[-1]).parent)
        return out

    def loop(self, closure: Joint) -> tuple[list[str | None], list[Joint]]:
        """The loop ``closure`` closes: its bodies from the closure's parent through the
        tree to its child (None: the inertial frame), and the tree joints on that path in
        the same order."""
        up, down = self._ancestry(closure.parent), self._ancestry(closure.child)
        common = next(b for b in up if b in set(down))
        up, down = up[: up.index(common) + 1], down[: down.index(common)]
        joints = [self.joint_of(b) for b in up[:-1]] + [self.joint_of(b) for b in reversed(down)]
        return up + down[::-1], joints


@dataclass(frozen=True)
class ModelSpec:
    """Everything a spec file defines."""

    systems: tuple[System, ...]
    inertial_bvecs: dict[str, BoundVector] = field(default_factory=dict, compare=False)
    path: str = "<string>"
    text: str = field(default="", compare=False, repr=False)

    def diagnostic(self, loc: Loc, message: str) -> Diagnostic:
        """A located error at ``loc`` of the spec, with its source line (for the checks that
        need a loaded model: a loop closure that cannot be closed)."""
        lines = self.text.splitlines()
        source = lines[loc.line - 1] if 0 < loc.line <= len(lines) else ""
        return Diagnostic(self.path, max(loc.line, 1), max(loc.column, 1), message, source)

    def system(self, name: str | None = None) -> System:
        """The system called ``name``; with None, the only one there is."""
        from .errors import RobotError, did_you_mean

        names = [s.name for s in self.systems]
        if name is None:
            if len(self.systems) == 1:
                return self.systems[0]
            raise RobotError(
                f"{self.path} defines {len(names)} rigidBodySystems ({', '.join(names)}); "
                "choose one with system=NAME (--system NAME on the command line)"
            )
        for s in self.systems:
            if s.name == name:
                return s
        raise RobotError(
            f"{self.path} has no rigidBodySystem '{name}'{did_you_mean(name, names)}; "
            f"it has: {', '.join(names)}"
        )


# --- the thesis's joint geometry (eq. 2.4, 2.12, 2.16), shared by URDF export and
# by the solvers; the tests re-derive it independently.


def axis_angle_matrix(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about unit ``axis``, right-handed (eq. 2.4)."""
    v = np.asarray(axis, dtype=float)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + s * vx + (1.0 - c) * (vx @ vx)


def perpendicular_axis(v: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to unit ``v``: v x e_k for the basis vector e_k
    least aligned with v (lowest index on ties).  Used for antiparallel axes."""
    k = int(np.argmin(np.abs(v)))
    e = np.zeros(3)
    e[k] = 1.0
    w = np.cross(v, e)
    return w / np.linalg.norm(w)


def alignment_matrix(parent_axis: np.ndarray, child_axis: np.ndarray) -> np.ndarray:
    """R_align with ``R_align @ child_axis == parent_axis`` (eq. 2.12).

    Axis v = (o_child x o_parent)/|.|, angle acos(o_parent . o_child).  When the
    axes are antiparallel the cross product vanishes; we then rotate by 180 deg
    about :func:`perpendicular_axis` of the child axis.
    """
    p = np.asarray(parent_axis, dtype=float)
    c = np.asarray(child_axis, dtype=float)
    cross = np.cross(c, p)
    n = np.linalg.norm(cross)
    dot = float(np.clip(np.dot(p, c), -1.0, 1.0))
    if n < 1e-12:
        if dot > 0:
            return np.eye(3)
        return axis_angle_matrix(perpendicular_axis(c), np.pi)
    return axis_angle_matrix(cross / n, np.arctan2(n, dot))


def rotation_vector_matrix(r_deg) -> np.ndarray:
    """Exp(r): rotation by |r| degrees about r/|r| (a rotation vector in degrees); I for r = 0."""
    r = np.radians(np.asarray(r_deg, dtype=float))
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    return axis_angle_matrix(r / angle, angle)


def rest_joint_transform(joint: Joint) -> tuple[np.ndarray, np.ndarray]:
    """(R_ij, d) of ``joint`` at rest, in the parent body's frame: the child's rotation
    relative to the parent (eq. 2.12, 2.16; Exp(r) R_align for a spherical joint) and
    the child end's point relative to the parent end's (offset times the parent end's
    axis for a prismatic joint, else zero)."""
    o_ij = np.asarray(joint.parent_bvec.orient, dtype=float)
    R = alignment_matrix(o_ij, np.asarray(joint.child_bvec.orient, dtype=float))
    if joint.kind == "revolute":
        R = axis_angle_matrix(o_ij, np.radians(joint.default_angle)) @ R
    elif joint.kind == "spherical":
        R = rotation_vector_matrix(joint.default_rotation) @ R
    d = joint.default_offset * o_ij if joint.kind == "prismatic" else np.zeros(3)
    return R, d


def xyz_rotation(angles) -> np.ndarray:
    """Rx(a) Ry(b) Rz(c) for ``angles`` = (a, b, c) in radians: intrinsic rotations about x,
    then the new y, then the new z (a spherical joint's three URDF joints)."""
    a, b, c = (float(x) for x in angles)
    e = np.eye(3)
    return axis_angle_matrix(e[0], a) @ axis_angle_matrix(e[1], b) @ axis_angle_matrix(e[2], c)


def xyz_angles(R: np.ndarray) -> np.ndarray:
    """The angles (a, b, c), radians, with ``xyz_rotation((a, b, c)) == R``: b in
    [-pi/2, pi/2], a and c in (-pi, pi]; at the gimbal singularity (|b| = pi/2) c = 0."""
    R = np.asarray(R, dtype=float)
    cos_b = math.hypot(R[0, 0], R[0, 1])
    b = math.atan2(R[0, 2], cos_b)
    if cos_b < 1e-12:  # the gimbal singularity: only a + c or a - c is defined
        return np.array([math.atan2(R[2, 1], R[1, 1]), b, 0.0])
    return np.array([math.atan2(-R[1, 2], R[2, 2]), b, math.atan2(-R[0, 1], R[0, 0])])
