"""Model -> Pinocchio model, built directly (the URDF cannot carry a spherical joint).

The result is the model Pinocchio's URDF parser makes of :func:`kms2pin.urdf.to_urdf`
for systems without spherical joints (the same joints, in the same order, the same
frames, placements, inertias and limits; a test compares the two), with two
differences the URDF cannot express:

* a spherical joint is one Pinocchio spherical joint (nq 4: a unit quaternion
  (x, y, z, w), scalar last; nv 3) with the parent's axes at the joint point, where
  the URDF has three revolute joints; its child body frame sits at R_align in the
  joint's frame, so R_ij = R(quaternion) R_align and the quaternion of R =
  Rx(a) Ry(b) Rz(c) stands for the URDF's three angles (a, b, c);
* nothing is parsed: the model is built in one pass over the joints, without
  recursion (a chain of any length) and without Pinocchio's ``Data``.

Joint order: as the URDF parser's, depth first from the root, each body's children
sorted by their (first) URDF joint name.  Frames: for each joint a JOINT frame and the
child's BODY frame (a fixed joint: a FIXED_JOINT frame, and the child's inertia joins
its parent joint's), as the parser makes them.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from .model import WORLD, Joint, System
from .urdf import (
    EFFORT,
    PRISMATIC_LIMIT,
    PRISMATIC_VELOCITY,
    ROOT_JOINT,
    VELOCITY,
    ellipsoid_mass,
    joint_origin,
    spherical_parts,
    urdf_number,
)

#: kms2pin's own model: a revolute joint the spec leaves unlimited may turn a full turn
#: either way of 0 (one coordinate, where Pinocchio's URDF parser makes a continuous joint
#: two: cos, sin)
LIMIT = np.pi


def _axis_joint(kind: str, axis: np.ndarray) -> pin.JointModel:
    """Pinocchio's joint for a revolute or prismatic joint about/along ``axis`` (the child
    frame's): RX/RY/RZ (PX/PY/PZ) for a basis axis, the unaligned joint otherwise, as the
    URDF parser chooses."""
    basis = {"revolute": (pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ),
             "prismatic": (pin.JointModelPX, pin.JointModelPY, pin.JointModelPZ)}[kind]
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        if np.linalg.norm(axis - e) <= 1e-12 * min(1.0, float(np.linalg.norm(axis))):
            return basis[k]()
    unaligned = pin.JointModelRevoluteUnaligned if kind == "revolute" else pin.JointModelPrismaticUnaligned
    return unaligned(axis / np.linalg.norm(axis))


def _inertia(system: System, body: str) -> pin.Inertia:
    """The URDF link's inertial: a solid inner ellipsoid about its centre, -a_ji in the link frame."""
    m, diag = ellipsoid_mass(system.body(body).inner)
    return pin.Inertia(m, -np.asarray(system.joint_of(body).child_bvec.pos, dtype=float), np.diag(diag))


def _sort_key(joint: Joint) -> str:
    return spherical_parts(joint.name)[0][0] if joint.kind == "spherical" else joint.name


def _add_joint(model: pin.Model, system: System, joint: Joint, parent_frame: int) -> int:
    """Add ``joint`` and its child body below the BODY frame ``parent_frame``; returns the
    child's BODY frame."""
    frame = model.frames[parent_frame]
    xyz, R_align = joint_origin(system, joint)
    Y = _inertia(system, joint.child)
    if joint.kind == "fixed":
        placement = frame.placement * pin.SE3(R_align, xyz)
        fid = model.addFrame(pin.Frame(joint.name, frame.parentJoint, parent_frame, placement,
                                       pin.FrameType.FIXED_JOINT, Y))
        return model.addBodyFrame(joint.child, frame.parentJoint, placement, fid)
    body_in_joint = pin.SE3.Identity()
    if joint.kind == "spherical":
        body_in_joint = pin.SE3(R_align, np.zeros(3))
        jid = model.addJoint(frame.parentJoint, pin.JointModelSpherical(),
                             frame.placement * pin.SE3(np.eye(3), xyz), joint.name)
    else:
        if joint.kind == "revolute":
            lower, upper = (-LIMIT, LIMIT) if joint.limits is None else np.radians(joint.limits)
            effort, velocity = EFFORT, VELOCITY
        else:
            lower, upper = (-PRISMATIC_LIMIT, PRISMATIC_LIMIT) if joint.limits is None else joint.limits
            effort, velocity = EFFORT, PRISMATIC_VELOCITY
        jmodel = _axis_joint(joint.kind, np.asarray(joint.child_bvec.orient, dtype=float))
        bounds = [np.array([urdf_number(x)]) for x in (effort, velocity, lower, upper)]  # as the URDF's text
        jid = model.addJoint(frame.parentJoint, jmodel, frame.placement * pin.SE3(R_align, xyz), joint.name, *bounds)
    fid = model.addJointFrame(jid, parent_frame)
    model.appendBodyToJoint(jid, Y, body_in_joint)
    return model.addBodyFrame(joint.child, jid, body_in_joint, fid)


def build_model(system: System, free_root: bool = False) -> tuple[pin.Model, dict[str, int]]:
    """The Pinocchio model of ``system`` (see the module docstring) and each body's BODY
    frame index (``Model.getFrameId`` searches every frame).  With ``free_root`` the
    joint to the inertial frame is replaced by a free flyer ``root_joint`` placing the
    root body's link frame (its joint point, with its axes)."""
    model = pin.Model()
    model.name = system.name
    children: dict[str | None, list[Joint]] = {}
    for j in system.joints:
        children.setdefault(j.parent, []).append(j)
    for kids in children.values():
        kids.sort(key=_sort_key)
    if free_root:
        top: str | None = system.joints[0].child
        jid = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), ROOT_JOINT)
        fid = model.addJointFrame(jid, 0)
        model.appendBodyToJoint(jid, _inertia(system, top), pin.SE3.Identity())
        top_frame = model.addBodyFrame(top, jid, pin.SE3.Identity(), fid)
        frames = {top: top_frame}
    else:
        top, top_frame, frames = None, model.addBodyFrame(WORLD, 0, pin.SE3.Identity(), 0), {}
    stack = [(j, top_frame) for j in reversed(children.get(top, []))]
    while stack:  # depth first (no recursion), each body's children in sorted order
        joint, parent_frame = stack.pop()
        frame = frames[joint.child] = _add_joint(model, system, joint, parent_frame)
        stack.extend((k, frame) for k in reversed(children.get(joint.child, [])))
    return model, frames
