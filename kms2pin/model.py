"""The syntax-free kinematic model a spec compiles to (thesis §2.1.1, §2.2).

Frames and units: every body frame is its ellipsoid centre with the ellipsoid's
axes (thesis mu_0,i and R_0,i, eq. 2.1); bound-vector positions are in the frame
of the body that owns them (or in the inertial frame for inertial bvecs); lengths
are in the spec's units (metres in the thesis models); angles in degrees.

A :class:`System` is a tree rooted at the inertial frame: each body has exactly
one joint to its parent (``Joint.parent is None`` means the inertial frame) and
``System.bodies`` lists the bodies in preorder traversal (thesis §3.2.1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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


@dataclass(frozen=True)
class Joint:
    """A fixed or revolute joint, oriented parent (lower) -> child (upper).

    ``parent`` is None for a joint to the inertial frame; then ``parent_bvec`` is
    an inertial bvec.  ``default_angle`` (degrees) is a right-handed rotation of
    the child about the parent end's axis (eq. 2.16); it is 0 for fixed joints.
    ``limits`` (degrees) bound a revolute joint's angle when the spec gives them
    (``revolute(a, b, angle, lower, upper)``, a kms2pin extension); None: no limits.
    """

    name: str
    kind: str  # "fixed" | "revolute"
    parent: str | None
    child: str
    parent_bvec: BoundVector
    child_bvec: BoundVector
    default_angle: float = 0.0
    loc: Loc = Loc()
    limits: tuple[float, float] | None = None

    @property
    def parent_link(self) -> str:
        return self.parent if self.parent is not None else WORLD


@dataclass(frozen=True)
class System:
    """One ``rigidBodySystem``: bodies in preorder and one joint per body."""

    name: str
    bodies: tuple[Body, ...]
    joints: tuple[Joint, ...]  # joints[i] connects bodies[i] to its parent
    loc: Loc = Loc()

    @property
    def root(self) -> Body:
        return self.bodies[0]

    def body(self, name: str) -> Body:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(name)

    def joint_of(self, body: str) -> Joint:
        for j in self.joints:
            if j.child == body:
                return j
        raise KeyError(body)

    def children(self, body: str | None) -> list[Joint]:
        return [j for j in self.joints if j.parent == body]

    @property
    def dof(self) -> int:
        return sum(1 for j in self.joints if j.kind == "revolute")


@dataclass(frozen=True)
class ModelSpec:
    """Everything a spec file defines."""

    systems: tuple[System, ...]
    inertial_bvecs: dict[str, BoundVector] = field(default_factory=dict, compare=False)
    path: str = "<string>"

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
