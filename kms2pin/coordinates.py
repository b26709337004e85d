"""A robot's named coordinates: each Pinocchio joint's slots in ``q``, and ``q`` written
as the trajectory CSV's columns and the SRDF's joint values.

The CSV's columns (:attr:`Coordinates.names`): a free root's seven entries
``root_x, root_y, root_z, root_qx, root_qy, root_qz, root_qw`` as they are (Pinocchio's
quaternion, scalar LAST), each revolute joint's angle in degrees, each prismatic joint's
offset in spec length units, and a spherical joint's X-Y-Z angles ``<joint>_x, _y, _z``
in degrees (R = Rx Ry Rz: the three URDF joints it is exported as).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pinocchio as pin

from .model import Joint, System, xyz_angles, xyz_rotation
from .urdf import ROOT_JOINT, spherical_parts, wrap_angle

#: Names of a free root's 7 coordinates of q (``root_<part>``, also the trajectory CSV's columns).
FREE_FLYER_COORDINATES = tuple(f"root_{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw"))


@dataclass(frozen=True)
class JointCoordinates:
    """One Pinocchio joint of a :class:`~kms2pin.robot.Robot` and its coordinates.

    ``kind`` is ``"free"`` for a free-flyer root, else the spec joint's type (``spec``;
    None for the free flyer); ``idx_q``, ``idx_v``, ``nq`` locate it in q and v;
    ``names`` are its columns of a trajectory CSV (:meth:`Coordinates.to_csv`).
    """

    name: str
    kind: str
    idx_q: int
    idx_v: int
    nq: int
    names: tuple[str, ...]
    spec: Joint | None


def quaternion_matrix(xyzw: np.ndarray) -> np.ndarray:
    """The rotation of a Pinocchio quaternion (x, y, z, w), normalized."""
    x = np.asarray(xyzw, dtype=float)
    return pin.Quaternion(x[3], x[0], x[1], x[2]).normalized().toRotationMatrix()


def _quaternion(angles_deg: np.ndarray) -> np.ndarray:
    """Pinocchio's quaternion (x, y, z, w) of X-Y-Z angles in degrees (R = Rx Ry Rz)."""
    return pin.Quaternion(xyz_rotation(np.radians(angles_deg))).coeffs()


def _angles(xyzw: np.ndarray) -> np.ndarray:
    """The X-Y-Z angles in degrees (R = Rx Ry Rz) of a Pinocchio quaternion (x, y, z, w)."""
    return np.degrees(xyz_angles(quaternion_matrix(xyzw)))


class Coordinates:
    """The joints of a Pinocchio ``model`` built from ``system`` (its joints by name; the
    one without a spec joint is the free root) and the conversions of ``q`` (module
    docstring).  None of the conversions validates ``q``."""

    def __init__(self, model: pin.Model, system: System) -> None:
        by_name = {j.name: j for j in system.joints}
        joints = []
        for jid in range(1, model.njoints):
            jm, name = model.joints[jid], model.names[jid]
            spec = by_name.get(name)
            kind = "free" if spec is None else spec.kind
            names = {"free": FREE_FLYER_COORDINATES, "spherical": tuple(f"{name}_{a}" for a in "xyz")}
            joints.append(JointCoordinates(name, kind, jm.idx_q, jm.idx_v, jm.nq, names.get(kind, (name,)), spec))
        self.joints: tuple[JointCoordinates, ...] = tuple(joints)
        self.names: tuple[str, ...] = tuple(n for j in self.joints for n in j.names)
        self.nq = model.nq

    @cached_property
    def slots(self) -> dict[str, tuple[JointCoordinates, int]]:
        """Coordinate name -> (its joint, its position among the joint's coordinates)."""
        return {n: (j, k) for j in self.joints for k, n in enumerate(j.names)}

    def blocks(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Each joint's entries of ``q`` by joint name (a free root's seven as ``root_joint``)."""
        return {j.name: np.array(q[j.idx_q : j.idx_q + j.nq], dtype=float) for j in self.joints}

    def urdf_values(self, q: np.ndarray) -> dict[str, object]:
        """The URDF joints' values at ``q`` (the SRDF's group state): revolute angles (radians;
        in (-pi, pi] without limits), a spherical joint's three angles (radians), prismatic
        offsets, a free root's 7 numbers (x, y, z, qx, qy, qz, qw)."""
        out: dict[str, object] = {}
        for j in self.joints:
            block = q[j.idx_q : j.idx_q + j.nq]
            if j.kind == "free":
                out[ROOT_JOINT] = block.copy()
            elif j.kind == "spherical":
                out.update(zip(spherical_parts(j.name)[0], (float(a) for a in xyz_angles(quaternion_matrix(block)))))
            elif j.kind == "revolute":
                out[j.name] = float(block[0]) if j.spec.limits is not None else wrap_angle(float(block[0]))
            elif j.nq:
                out[j.name] = float(block[0])
        return out

    def to_csv(self, q: np.ndarray) -> np.ndarray:
        """Configurations ``q`` (nq,) or (T, nq) as the CSV's coordinates (:attr:`names`)."""
        q = np.asarray(q, dtype=float)
        rows = q.reshape(-1, self.nq)
        out = np.empty((len(rows), len(self.names)))
        c = 0
        for j in self.joints:
            block = rows[:, j.idx_q : j.idx_q + j.nq]
            if j.kind == "spherical":
                out[:, c : c + 3] = np.reshape([_angles(x) for x in block], (-1, 3))
            elif j.kind == "revolute":
                out[:, c] = np.degrees(block[:, 0])
            else:
                out[:, c : c + j.nq] = block
            c += len(j.names)
        return out.reshape(*q.shape[:-1], c)

    def from_csv(self, coordinates: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`to_csv`: (n_names,) or (T, n_names) coordinates to Pinocchio
        configurations (a spherical joint's quaternion from its three angles)."""
        c = np.asarray(coordinates, dtype=float)
        rows = c.reshape(-1, len(self.names))
        q = np.empty((len(rows), self.nq))
        k = 0
        for j in self.joints:
            block = rows[:, k : k + len(j.names)]
            if j.kind == "spherical":
                q[:, j.idx_q : j.idx_q + 4] = np.reshape([_quaternion(a) for a in block], (-1, 4))
            elif j.kind == "revolute":
                q[:, j.idx_q] = np.radians(block[:, 0])
            else:
                q[:, j.idx_q : j.idx_q + j.nq] = block
            k += len(j.names)
        return q.reshape(*c.shape[:-1], self.nq)

    def with_values(self, q: np.ndarray, values: Mapping[str, float]) -> np.ndarray:
        """A copy of ``q`` with the named coordinates set (in the CSV's units); a spherical
        joint's angles left out keep their values at ``q``.  KeyError for an unknown name."""
        q = np.array(q, dtype=float)
        spherical: dict[JointCoordinates, np.ndarray] = {}
        for name, value in values.items():
            j, k = self.slots[name]
            if j.kind == "spherical":
                if j not in spherical:
                    spherical[j] = _angles(q[j.idx_q : j.idx_q + 4])
                spherical[j][k] = value
            else:
                q[j.idx_q + k] = math.radians(value) if j.kind == "revolute" else value
        for j, angles in spherical.items():
            q[j.idx_q : j.idx_q + 4] = _quaternion(angles)
        return q

    def joints_of(self, names: Sequence[str]) -> set[JointCoordinates]:
        """The joints that hold the named coordinates (KeyError for an unknown name)."""
        return {self.slots[n][0] for n in names}
