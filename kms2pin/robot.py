"""A compiled system loaded into Pinocchio: body poses, maximal coordinates, Jacobians.

``q`` is always Pinocchio's configuration vector (``model.nq``) in the order of
``Robot.joint_names``; with ``root="free"`` its first 7 entries are the root
free flyer: position, then Pinocchio's quaternion (x, y, z, w), scalar LAST.  The
thesis's Euler parameters (eq. 2.5-2.7), and so :meth:`Robot.maximal_coordinates`
and :func:`euler_parameters`, put the scalar FIRST: (theta0, theta1, theta2, theta3)
= (w, x, y, z).  Body poses are ``world_T_body``: the ellipsoid centre with the
body's axes (thesis eq. 2.1).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from functools import cached_property
from importlib import resources

import numpy as np
import pinocchio as pin

from .closures import Closures, open_loops, project
from .coordinates import Coordinates, quaternion_matrix
from .coordinates import JointCoordinates as JointCoordinates  # where it was first
from .errors import RobotError, SpecError, did_you_mean
from .lang import looks_like_path, parse, parse_text, read_spec
from .model import Joint, ModelSpec, System, rest_joint_transform, xyz_rotation
from .native import kernels
from .pinmodel import build_model
from .urdf import (
    ROOT_JOINT,
    centre_offset,
    check_root_joint_name,
    rest_values,
    root_joint_clash,
    to_srdf,
    to_urdf,
    urdf_number,
)

ROOTS = ("spec", "free")

#: A free root's quaternion q[3:7] is renormalized when its squared norm is off by more.
_UNIT_TOL = 1e-12
_UNIT_LO2, _UNIT_HI2 = 1.0 - _UNIT_TOL, 1.0 + _UNIT_TOL  # squared norms a quaternion passes as unit
#: Below this norm a free root's quaternion is refused as zero (it has no direction).
_ZERO_NORM = 1e-12
#: Largest |R R^T - I| entry :func:`euler_parameters` accepts as a rotation.
_ROTATION_TOL = 1e-6
#: A loop closure holds when its residual is below this times the model's size (its largest
#: bound-vector coordinate, at least 1).
CLOSURE_TOL = 1e-9


def check_free_root(system: System, spec: ModelSpec | None = None) -> None:
    """Raise unless ``system`` can take ``root="free"``: exactly one joint to the inertial
    frame (the one the free flyer replaces; RobotError) and no other joint already called
    :data:`~kms2pin.urdf.ROOT_JOINT`, the free flyer's name (SpecError at that joint's
    ``constraint`` in ``spec``; without ``spec``, ExportError)."""
    anchored = [j.child for j in system.children(None)]
    if len(anchored) != 1:
        raise RobotError(
            f"root='free' replaces the joint to the inertial frame by a free flyer, but "
            f"'{system.name}' has {len(anchored)} such joints ({', '.join(anchored)}); "
            "use root='spec' or keep one"
        )
    if spec is None:
        check_root_joint_name(system)
        return
    j = root_joint_clash(system)
    if j is not None:
        raise SpecError([spec.diagnostic(j.loc, (
            f"this joint of '{system.name}' is called '{ROOT_JOINT}' (body '{j.child}'), the name a free "
            "root's joint takes; rename the body or its bound vector, or keep the spec's root"))])


def mesh_package_dir() -> str:
    """Folder holding ``meshes/unit_sphere.obj`` for Pinocchio's ``package_dirs``."""
    return str(resources.files("kms2pin") / "data")


class Robot:
    """One rigid-body system of a spec, compiled to URDF and loaded in Pinocchio.

    Attributes:
        model, data: Pinocchio model (built by :func:`kms2pin.pinmodel.build_model`) and
            data (made on first use).  Each body has a BODY frame (its link, at the
            joint to its parent) and an OP_FRAME ``"<body>_centre"`` at the ellipsoid
            centre with the body axes.
        urdf, srdf: the generated text (meshes referenced as ``meshes/unit_sphere.obj``).
        bodies: body names in traversal (preorder) order.
        joint_names: Pinocchio joint names in ``q`` order.
        coords: the named coordinates (:class:`~kms2pin.coordinates.Coordinates`).
        joints: a :class:`~kms2pin.coordinates.JointCoordinates` per Pinocchio joint, in ``q`` order.
        coordinate_names: the columns of a trajectory CSV (:meth:`coordinates`): a free
            root's ``root_x, root_y, root_z, root_qx, root_qy, root_qz, root_qw``, then
            each revolute or prismatic joint's name and a spherical joint's
            ``<joint>_x, <joint>_y, <joint>_z`` (its URDF joints).
        q_rest: the spec's rest configuration (default joint angles, rotations and
            offsets), a Pinocchio ``q``; also ``model.referenceConfigurations["rest"]``.
            With loop closures, its projection onto them (:meth:`project`).
        closures: the joints that close kinematic loops (``system.closures``: model
            :class:`~kms2pin.model.Joint` objects), each a constraint between the frames
            ``<closure>_parent`` and ``<closure>_child`` (:mod:`kms2pin.closures`).
        lower_limits, upper_limits: (nq,) bounds of ``q`` from the spec's joint limits
            (radians for revolute joints, spec length units for prismatic ones); -inf /
            +inf where the spec gives none (the free flyer, spherical joints, and every
            joint of the thesis's own models).

    Quaternion order: every ``q`` (and ``q_rest``) is Pinocchio's, so with
    ``root="free"`` ``q[3:7]`` is the root's quaternion (x, y, z, w), scalar LAST, and
    a spherical joint's four entries are its quaternion (x, y, z, w); the thesis's
    Euler parameters in :meth:`maximal_coordinates` are scalar FIRST (theta0, theta1,
    theta2, theta3) = (w, x, y, z) (eq. 2.7).  Methods taking ``q`` raise RobotError
    for a wrong shape, a non-finite entry or a zero quaternion, and use a non-unit
    quaternion divided by its norm (as ``pin.integrate`` would give it).
    """

    def __init__(self, spec: ModelSpec, system: System, root: str = "spec") -> None:
        if root not in ROOTS:
            raise RobotError(f"root must be one of {ROOTS}, not {root!r}")
        self.spec = spec
        self.system = system
        self.root = root
        free = root == "free"
        if free:
            check_free_root(system, spec)
        source = os.path.basename(spec.path)
        self.urdf = to_urdf(system, source, free_root=free)
        self.model, links = build_model(system, free)
        self.bodies = tuple(b.name for b in system.bodies)
        self._index = {n: i for i, n in enumerate(self.bodies)}
        self.frame_ids = tuple(self._add_centre_frame(b, links[b]) for b in self.bodies)
        self._closures = Closures(self.model, system, links, {b: centre_offset(system, b) for b in self.bodies})
        # a closure holds when its residual is below this (spec length units; radians)
        scale = max([1.0] + [abs(x) for b in system.bodies for v in b.bvecs.values() for x in v.pos])
        self._closure_tol = CLOSURE_TOL * scale
        self.joint_names = tuple(self.model.names[1:])
        self.coords = Coordinates(self.model, system)
        self.joints = self.coords.joints
        self.coordinate_names = self.coords.names
        self.lower_limits = np.full(self.model.nq, -np.inf)
        self.upper_limits = np.full(self.model.nq, np.inf)
        for j in self.joints:
            if j.spec is not None and j.spec.limits is not None:
                lo, hi = j.spec.limits
                scale = math.pi / 180.0 if j.kind == "revolute" else 1.0
                self.lower_limits[j.idx_q], self.upper_limits[j.idx_q] = lo * scale, hi * scale
        self.q_rest = self._rest_configuration()
        rest = None
        if self.closures:
            self.q_rest = self._closed_rest(self.q_rest)
            rest = self.urdf_values(self.q_rest)
        self.srdf = to_srdf(system, source, free_root=free, rest=rest)
        self.model.referenceConfigurations["rest"] = self.q_rest.copy()

    @cached_property
    def data(self) -> pin.Data:
        """Pinocchio's ``Data`` of :attr:`model`, made on first use (its size grows with nv^2)."""
        return self.model.createData()

    @property
    def has_limits(self) -> bool:
        """Whether any joint has limits from the spec."""
        return bool(np.isfinite(self.lower_limits).any())

    def clamp(self, q: np.ndarray) -> np.ndarray:
        """``q`` with every limited joint coordinate (a revolute angle, a prismatic offset)
        clipped into the spec's limits.

        Pure element-wise clipping: broadcasts over (..., nq) arrays and does not
        validate (see :meth:`forward` for the checks of a single ``q``)."""
        return np.clip(q, self.lower_limits, self.upper_limits)

    def _add_centre_frame(self, body: str, link: int) -> int:
        """Add the OP_FRAME ``<body>_centre`` below ``body``'s BODY frame ``link``."""
        frame = self.model.frames[link]
        placement = frame.placement * pin.SE3(np.eye(3), centre_offset(self.system, body))
        return self.model.addFrame(
            pin.Frame(f"{body}_centre", frame.parentJoint, link, placement, pin.FrameType.OP_FRAME)
        )

    def _rest_configuration(self) -> np.ndarray:
        """The spec's rest pose as a Pinocchio q: the SRDF's group state "rest" (its
        numbers as written, :func:`kms2pin.urdf.rest_values`; a spherical joint's
        quaternion from its three angles) and the root's rest pose for a free root."""
        q = pin.neutral(self.model)
        for j in self.joints:
            if j.kind == "free":
                R, d = rest_joint_transform(self.system.joints[0])
                q[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, np.asarray(self.system.joints[0].parent_bvec.pos) + d))
                continue
            values = [urdf_number(v) for _, v in rest_values(j.spec)]
            if j.kind == "spherical":
                q[j.idx_q : j.idx_q + 4] = pin.Quaternion(xyz_rotation(values)).coeffs()
            elif values:
                q[j.idx_q] = values[0]
        return q

    # ------------------------------------------------------------------ loop closures
    @property
    def closures(self) -> tuple[Joint, ...]:
        """The joints that close kinematic loops, in spec order (none for a tree)."""
        return self.system.closures

    @cached_property
    def mobility(self) -> int:
        """Degrees of freedom with the loops closed: nv less the rank of the closures'
        Jacobian at :attr:`q_rest` (singular values above 1e-9 of the largest); nv for a tree."""
        if not self.closures:
            return self.model.nv
        pin.computeJointJacobians(self.model, self.data, self.q_rest)
        sig = np.linalg.svd(self._closures.jacobian(self.model, self.data), compute_uv=False)
        return self.model.nv - int((sig > 1e-9 * sig[0]).sum()) if sig.size and sig[0] > 0 else self.model.nv

    def closure_residual(self, q: np.ndarray) -> np.ndarray:
        """Each closure's residual norm at ``q`` (:attr:`closures` order; spec length units and
        radians, :mod:`kms2pin.closures`): zero where the loops are closed."""
        pin.forwardKinematics(self.model, self.data, self._check_q(q))
        return self._closures.norms(self._closures.residual(self.model, self.data))

    def project(self, q: np.ndarray, hold: np.ndarray | None = None) -> np.ndarray:
        """The configuration nearest ``q`` that closes every loop: Gauss-Newton on the closures'
        residual, each correction dq the least in the tangent-space metric with
        ``q' = pin.integrate(q, dq)`` (:func:`kms2pin.closures.project`), within the joint
        limits.  ``hold``: velocity indices (or an (nv,) mask) that must not move (a slider's
        joint).  A tree's ``q`` is returned as it is (checked)."""
        q = self._check_q(q)
        if not self.closures:
            return q
        held = np.zeros(self.model.nv, dtype=bool)
        if hold is not None:
            held[np.asarray(hold)] = True
        q, r = project(self._closures, self.model, self.data, self.clamp(q), self.lower_limits, self.upper_limits,
                       held)
        norms = self._closures.norms(r)
        if (norms > self._closure_tol).any():
            k = int(np.argmax(norms))
            raise RobotError(
                f"the loops of '{self.system.name}' cannot be closed from this configuration: closure "
                f"'{self.closures[k].name}' stays open by {norms[k]:.3g} (a configuration nearer a closed one, "
                "or fewer held joints, may close them)"
            )
        return q

    def _closed_rest(self, q0: np.ndarray) -> np.ndarray:
        """The spec's rest pose projected onto the closures; SpecError (at each closure that
        stays open, with its loop, its gap and the joints to change) if it cannot be closed."""
        q, r = project(self._closures, self.model, self.data, q0, self.lower_limits, self.upper_limits,
                       np.zeros(self.model.nv, dtype=bool))
        norms = self._closures.norms(r)
        if (norms <= self._closure_tol).all():
            return q
        problems = open_loops(self._closures, self.data, norms, self._closure_tol, self.system, self.spec)
        raise SpecError(problems)

    # ------------------------------------------------------------------ coordinates
    def joint_blocks(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Each Pinocchio joint's coordinates in ``q`` by joint name (a free root's seven as
        ``root_joint``)."""
        return self.coords.blocks(q)

    def urdf_values(self, q: np.ndarray) -> dict[str, object]:
        """The URDF joints' values at ``q`` (the SRDF's group state): revolute angles (radians;
        in (-pi, pi] without limits), a spherical joint's three angles, prismatic offsets, a
        free root's 7 numbers (x, y, z, qx, qy, qz, qw)."""
        return self.coords.urdf_values(q)

    def coordinates(self, q: np.ndarray) -> np.ndarray:
        """Configurations ``q`` (nq,) or (T, nq) as the trajectory CSV's coordinates
        (:attr:`coordinate_names`): a free root's 7 entries as they are, revolute angles
        and a spherical joint's X-Y-Z angles (R = Rx Ry Rz, the URDF's three joints) in
        degrees, prismatic offsets in spec length units.  Does not validate ``q``."""
        return self.coords.to_csv(q)

    def configuration(self, coordinates: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`coordinates`: (n_coordinates,) or (T, n_coordinates) CSV
        coordinates to Pinocchio configurations (a spherical joint's quaternion from its
        three angles).  Does not validate."""
        return self.coords.from_csv(coordinates)

    def with_coordinates(self, q: np.ndarray, values: Mapping[str, float]) -> np.ndarray:
        """A copy of ``q`` with the named coordinates (:attr:`coordinate_names`, in the CSV's
        units: degrees, spec length units, a free root's raw entries) set; a spherical joint's
        angles left out keep their values at ``q``.  KeyError for an unknown name; the
        values are not checked against limits."""
        return self.coords.with_values(q, values)

    # ------------------------------------------------------------------ shapes
    def _body(self, name: str):
        if not isinstance(name, str):
            raise TypeError(f"a body is given by its name (a str), not a {type(name).__name__}")
        if name not in self._index:
            raise RobotError(f"'{self.system.name}' has no body '{name}'{did_you_mean(name, self.bodies)}")
        return self.system.bodies[self._index[name]]

    def index(self, name: str) -> int:
        """Position of body ``name`` in :attr:`bodies`."""
        self._body(name)
        return self._index[name]

    def inner(self, name: str) -> np.ndarray:
        """Inner-ellipsoid semi-axes (x, y, z) of body ``name``."""
        return np.array(self._body(name).inner)

    def outer(self, name: str) -> np.ndarray:
        """Outer-ellipsoid semi-axes (x, y, z) of body ``name``."""
        return np.array(self._body(name).outer)

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    # ------------------------------------------------------------------ kinematics
    def _check_q(self, q: np.ndarray) -> np.ndarray:
        """``q`` as a float (nq,) array, checked once for every method taking a ``q``.

        Raises RobotError for a wrong shape, for the first non-finite coordinate (named
        with its joint) and for a quaternion (x, y, z, w) of zero norm (a free root's
        ``q[3:7]``, a spherical joint's four entries); a non-unit one is divided by its
        norm, on a copy.
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (self.model.nq,):
            raise RobotError(f"q must have shape ({self.model.nq},) for '{self.system.name}', not {q.shape}")
        starts, blocks, float_starts = self._quaternions
        if kernels.all_unit(q, float_starts, _UNIT_LO2, _UNIT_HI2):
            return q  # the usual case: finite, every quaternion unit
        if not np.isfinite(q).all():
            raise RobotError(self._non_finite_message(q))
        if not len(starts):
            return q
        b = q[blocks]
        n2 = np.einsum("ij,ij->i", b, b)
        off = np.abs(n2 - 1.0) > _UNIT_TOL
        if not off.any():  # unit after all (a squared norm at the tolerance, summed in another order)
            return q
        q = q.copy()
        for k in np.flatnonzero(off):
            a, norm = int(starts[k]), math.sqrt(n2[k])
            if norm < _ZERO_NORM:
                j = next(j for j in self.joints if j.idx_q <= a < j.idx_q + j.nq)
                whose = "the free root's quaternion" if j.kind == "free" else f"the quaternion of joint '{j.name}',"
                raise RobotError(
                    f"{whose} q[{a}:{a + 4}] = {q[a : a + 4].tolist()} (x, y, z, w; scalar last) of "
                    f"'{self.system.name}' has zero norm ({norm:.3g}); it must be a non-zero quaternion, "
                    "e.g. [0, 0, 0, 1] for no rotation"
                )
            q[a : a + 4] /= norm
        return q

    @cached_property
    def _quaternions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where q holds quaternions (a free root's, the spherical joints'): their first
        indices (k,), all four indices (k, 4), and the first as floats (the kernels')."""
        starts = np.array([j.idx_q + (3 if j.kind == "free" else 0) for j in self.joints
                           if j.kind in ("free", "spherical")], dtype=int)
        return starts, starts[:, None] + np.arange(4)[None], starts.astype(float)

    def _non_finite_message(self, q: np.ndarray) -> str:
        k = int(np.flatnonzero(~np.isfinite(q))[0])
        j = next(j for j in self.joints if j.idx_q <= k < j.idx_q + j.nq)
        if j.kind == "free":  # root_qx -> "quaternion x of joint 'root_joint'"
            part = j.names[k - j.idx_q].removeprefix("root_")
            part = f"quaternion {part[1:]}" if part.startswith("q") else part
            joint = f"{part} of joint '{j.name}'"
        elif j.kind == "spherical":
            joint = f"quaternion {'xyzw'[k - j.idx_q]} of joint '{j.name}'"
        else:
            joint = f"joint '{j.name}'"
        return f"q[{k}] ({joint}) of '{self.system.name}' is {q[k]}; every coordinate of q must be finite"

    def forward(self, q: np.ndarray) -> None:
        """Forward kinematics of every frame into :attr:`data` (no Jacobians).

        ``q``: Pinocchio configuration (nq,), radians; a free root's ``q[3:7]`` is the
        quaternion (x, y, z, w), scalar last.  Raises RobotError for a wrong shape, a
        non-finite entry or a zero root quaternion (see :class:`Robot`)."""
        pin.framesForwardKinematics(self.model, self.data, self._check_q(q))

    def body_pose(self, q: np.ndarray, name: str) -> pin.SE3:
        """world_T_body of ``name`` at ``q`` (as in :meth:`forward`): ellipsoid centre and
        body axes (eq. 2.1, 2.14)."""
        i = self.index(name)
        self.forward(q)
        return pin.SE3(self.data.oMf[self.frame_ids[i]])

    def body_poses(self, q: np.ndarray) -> list[pin.SE3]:
        """world_T_body of every body at ``q`` (as in :meth:`forward`), in :attr:`bodies` order."""
        self.forward(q)
        return [pin.SE3(self.data.oMf[f]) for f in self.frame_ids]

    def body_pose_arrays(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`body_poses` as rotations (n, 3, 3) and centres (n, 3), world, read from
        Pinocchio's frames without a ``pin.SE3`` per body (the same numbers)."""
        self.forward(q)
        placements = self.data.oMf.tolist()
        frames = [placements[f] for f in self.frame_ids]
        # np.array copies each at once: ``rotation`` is a view of Pinocchio's memory
        return (np.array([M.rotation for M in frames]).reshape(-1, 3, 3),
                np.array([M.translation for M in frames]).reshape(-1, 3))

    def maximal_coordinates(self, q: np.ndarray, convention: str = "positive") -> np.ndarray:
        """The thesis's q_i = [mu, theta0, theta1, theta2, theta3] per body (eq. 2.8), (n, 7).

        ``q`` is checked as in :meth:`forward` (a free root's quaternion there is
        (x, y, z, w), scalar last); the Euler parameters here are scalar FIRST
        (theta0 = w) and satisfy eq. 2.7.  They are unique only
        up to sign; ``convention="positive"`` takes theta0 >= 0 (continuous except at
        half turns), ``"thesis"`` takes the thesis's rule (§2.2.1): the first nonzero
        of theta1, theta2, theta3 positive.
        """
        self.forward(q)
        out = np.empty((len(self.bodies), 7))
        for i, f in enumerate(self.frame_ids):
            M = self.data.oMf[f]
            out[i, :3] = M.translation
            out[i, 3:] = _euler_parameters(M.rotation, convention)
        return out

    def body_jacobian(self, q: np.ndarray, name: str) -> np.ndarray:
        """6 x nv Jacobian of body ``name`` at its ellipsoid centre, world-aligned axes,
        rows (linear; angular) as in Pinocchio's LOCAL_WORLD_ALIGNED; ``q`` as in
        :meth:`forward`."""
        i = self.index(name)
        q = self._check_q(q)
        return pin.computeFrameJacobian(
            self.model, self.data, q, self.frame_ids[i], pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )

    def random_configuration(self, rng: np.random.Generator, spread_deg: float = 180.0) -> np.ndarray:
        """Rest pose (a Pinocchio ``q``) with every revolute angle moved uniformly within
        +-spread_deg, every spherical joint turned by up to spread_deg about a uniformly
        random axis and every prismatic offset uniform within its limits (at rest without
        limits); the free root stays at rest.  With loop closures, that configuration
        projected onto them (:meth:`project`); where it cannot be closed, another is drawn
        with half the spread (and prismatic offsets moved half as far from rest)."""
        share = 1.0
        while self.closures and share > 1e-6:
            try:
                return self.project(self._random_tree(rng, spread_deg * share, share))
            except RobotError:
                share *= 0.5
        return self._random_tree(rng, spread_deg, share) if not self.closures else self.q_rest.copy()

    def _random_tree(self, rng: np.random.Generator, spread_deg: float, share: float) -> np.ndarray:
        """:meth:`random_configuration` of the joints, closures left open; prismatic offsets
        ``share`` of the way from rest to their random value."""
        q = self.q_rest.copy()
        for j in self.joints:
            if j.kind == "revolute":
                q[j.idx_q] += math.radians(rng.uniform(-spread_deg, spread_deg))
            elif j.kind == "spherical":
                axis = rng.normal(size=3)
                turn = axis / np.linalg.norm(axis) * math.radians(rng.uniform(0.0, spread_deg))
                R = pin.exp3(turn) @ quaternion_matrix(q[j.idx_q : j.idx_q + 4])
                q[j.idx_q : j.idx_q + 4] = pin.Quaternion(R).coeffs()
            elif j.kind == "prismatic" and np.isfinite(self.lower_limits[j.idx_q]):
                value = rng.uniform(self.lower_limits[j.idx_q], self.upper_limits[j.idx_q])
                q[j.idx_q] = value if share == 1.0 else q[j.idx_q] + share * (value - q[j.idx_q])
        return q

    # ------------------------------------------------------------------ geometry
    @cached_property
    def visual_model(self) -> pin.GeometryModel:
        """Pinocchio visuals from the URDF (inner opaque, outer translucent)."""
        return pin.buildGeomFromUrdfString(
            self.model, self.urdf, pin.GeometryType.VISUAL, package_dirs=[mesh_package_dir()]
        )

    @cached_property
    def collision_model(self) -> pin.GeometryModel:
        """Inner ellipsoids as collision meshes, adjacent pairs excluded (from the SRDF)."""
        geom = pin.buildGeomFromUrdfString(
            self.model, self.urdf, pin.GeometryType.COLLISION, package_dirs=[mesh_package_dir()]
        )
        geom.addAllCollisionPairs()
        pin.removeCollisionPairsFromXML(self.model, geom, self.srdf, False)
        return geom

    @cached_property
    def height(self) -> float:
        """Vertical (world y) extent of the inner ellipsoids at rest, in spec units."""
        lo, hi = np.inf, -np.inf
        for name, M in zip(self.bodies, self.body_poses(self.q_rest)):
            r = np.abs(M.rotation) @ self.inner(name)  # half extents of the bounding box
            lo = min(lo, M.translation[1] - r[1])
            hi = max(hi, M.translation[1] + r[1])
        return float(hi - lo)

    def __repr__(self) -> str:
        return f"Robot('{self.system.name}', bodies={len(self.bodies)}, nq={self.nq}, root={self.root!r})"


def euler_parameters(R: np.ndarray, convention: str = "positive") -> np.ndarray:
    """Unit Euler parameters [theta0, theta1, theta2, theta3] of rotation R (eq. 2.7).

    Scalar FIRST (theta0 = w), unlike Pinocchio's (x, y, z, w) quaternions.  ``R``
    must be a 3 x 3 rotation: |R R^T - I| <= 1e-6 entry-wise and det R > 0, else
    RobotError (a reflection such as diag(1, 1, -1) has no Euler parameters).
    ``convention`` as in :meth:`Robot.maximal_coordinates`.
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        raise RobotError(f"R must be a 3 x 3 rotation matrix, not shape {R.shape}")
    if not np.isfinite(R).all():
        raise RobotError(f"R must be a rotation matrix, but it is not finite: {R.tolist()}")
    off, det = rotation_error(R)
    if off > _ROTATION_TOL:
        raise RobotError(
            f"R is not a rotation matrix: R R^T differs from the identity by {off:.3g} "
            f"(tolerance {_ROTATION_TOL:g})"
        )
    if det < 0:
        raise RobotError(f"R is not a rotation matrix: det R = {det:.6g} (a reflection; a rotation has det R = +1)")
    return _euler_parameters(R, convention)


def rotation_error(R: np.ndarray) -> tuple[float, float]:
    """How far a finite 3 x 3 matrix ``R`` is from a rotation: (the largest entry of
    |R R^T - I|, det R).  A rotation gives (0, 1) up to rounding; each caller applies its
    own tolerance (a reflection is orthogonal with det -1).  A matrix with an entry
    beyond 2 in magnitude, which no rotation has, gives (inf, nan) (R R^T could overflow)."""
    R = np.asarray(R, dtype=float)
    if not np.abs(R).max() <= 2.0:
        return math.inf, math.nan
    return float(np.abs(R @ R.T - np.eye(3)).max()), float(np.linalg.det(R))


def _euler_parameters(R: np.ndarray, convention: str) -> np.ndarray:
    """:func:`euler_parameters` of a matrix known to be a rotation (Pinocchio's own)."""
    quat = pin.Quaternion(R)
    e = np.array([quat.w, quat.x, quat.y, quat.z])
    e /= np.linalg.norm(e)
    if convention == "positive":
        if e[0] < 0:
            e = -e
    elif convention == "thesis":
        nz = np.flatnonzero(np.abs(e[1:]) > 1e-12)  # below that it is rounding noise
        if len(nz) and e[1 + nz[0]] < 0:
            e = -e
        elif not len(nz) and e[0] < 0:
            e = -e
    else:
        raise RobotError(f"convention must be 'positive' or 'thesis', not {convention!r}")
    return e


def load(spec: str | os.PathLike | ModelSpec, root: str = "spec", system: str | None = None) -> Robot:
    """Compile a spec (path, text or parsed ModelSpec) and load one system in Pinocchio.

    Args:
        spec: a ``.kms`` path, spec text, or the result of :func:`kms2pin.parse`.
        root: ``"spec"`` keeps the spec's joint to the inertial frame; ``"free"``
            replaces it by a 6-DoF free flyer, the first 7 entries of every ``q``:
            position, then Pinocchio's quaternion (x, y, z, w), scalar LAST (the
            thesis's Euler parameters, eq. 2.7, are scalar FIRST).
        system: which rigidBodySystem, when the spec has more than one.
    """
    if isinstance(spec, ModelSpec):
        model_spec = spec
    elif looks_like_path(spec):
        text, shown = read_spec(spec)
        model_spec = parse_text(text, shown)
    else:
        model_spec = parse(spec)
    return Robot(model_spec, model_spec.system(system), root)
