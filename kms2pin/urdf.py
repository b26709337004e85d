"""Model -> URDF and SRDF text (thesis eq. 2.12-2.16 expressed as URDF joints).

Link frames.  A URDF joint rotates its child about an axis through the child
link's origin, so a body's *link* frame sits at the point of its joint to its
parent (the child bound vector's ``pos``, a_ji) with the body's axes; the
ellipsoid centre (the thesis's body frame) is at ``-a_ji`` in that link frame and
is where the visuals, the collision shape and the inertial are placed.

Joints.  With parent bound vector (a_ij, o_ij) and child (a_ji, o_ji):
origin xyz = a_ij expressed in the parent link frame, origin rpy = R_align with
R_align o_ji = o_ij (eq. 2.12), axis = o_ji in the child frame, so that at angle
theta the child's orientation is Rot(o_ij, theta) R_align = R_align Rot(o_ji, theta)
(eq. 2.16) and its centre obeys eq. 2.14.  Angle 0 means the axes are aligned;
the spec's default angles are the SRDF group state "rest".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from xml.sax.saxutils import quoteattr

import numpy as np
import pinocchio as pin

from .mesh import MESH_NAME
from .model import WORLD, Joint, System, alignment_matrix

DENSITY = 1000.0  # kg/m^3, a uniform solid inner ellipsoid (about a human body's density)
INNER_RGBA = (0.80, 0.45, 0.20, 1.0)
OUTER_RGBA = (0.35, 0.55, 0.85, 0.25)
MESH_DIR = "meshes"
LIMIT = math.pi  # the thesis's joints have no limits: a full turn either way of 0 is allowed


def wrap_angle(a: float) -> float:
    """The same angle in (-pi, pi] (rest angles beyond a half turn stay within the limits)."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def rest_angle(joint: Joint) -> float:
    """A revolute joint's rest angle (radians): the default angle, in (-pi, pi] unless the
    spec's limits place it elsewhere."""
    a = math.radians(joint.default_angle)
    return a if joint.limits is not None else wrap_angle(a)


def _num(x: float) -> str:
    s = f"{x:.15g}"
    return "0" if s in ("-0", "0") else s


def _vec(v) -> str:
    return " ".join(_num(float(x)) for x in v)


def joint_origin(system: System, joint: Joint) -> tuple[np.ndarray, np.ndarray]:
    """(xyz, R) of ``joint``'s frame at angle 0 in its parent's link frame."""
    a_ij = np.asarray(joint.parent_bvec.pos)
    if joint.parent is not None:
        a_ij = a_ij - np.asarray(system.joint_of(joint.parent).child_bvec.pos)
    R = alignment_matrix(np.asarray(joint.parent_bvec.orient), np.asarray(joint.child_bvec.orient))
    return a_ij, R


def ellipsoid_mass(semi_axes: Sequence[float]) -> tuple[float, np.ndarray]:
    """Mass and diagonal inertia (about the centre, body axes) of a solid ellipsoid."""
    a, b, c = semi_axes
    m = DENSITY * 4.0 / 3.0 * math.pi * a * b * c
    return m, m / 5.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


def _material(name: str, rgba) -> str:
    return f'  <material name="{name}">\n    <color rgba="{_vec(rgba)}"/>\n  </material>'


def _link(system: System, body_name: str) -> str:
    body = system.body(body_name)
    centre = -np.asarray(system.joint_of(body_name).child_bvec.pos)
    m, inertia = ellipsoid_mass(body.inner)
    origin = f'<origin xyz="{_vec(centre)}" rpy="0 0 0"/>'
    mesh = f"{MESH_DIR}/{MESH_NAME}"
    out = [f"  <link name={quoteattr(body.name)}>"]
    out.append(
        f"    <inertial>\n      {origin}\n      <mass value=\"{_num(m)}\"/>\n"
        f'      <inertia ixx="{_num(inertia[0])}" ixy="0" ixz="0" iyy="{_num(inertia[1])}" '
        f'iyz="0" izz="{_num(inertia[2])}"/>\n    </inertial>'
    )
    for kind, lam in (("inner", body.inner), ("outer", body.outer)):
        out.append(
            f'    <visual name="{body.name}_{kind}">\n      {origin}\n'
            f'      <geometry>\n        <mesh filename="{mesh}" scale="{_vec(lam)}"/>\n      </geometry>\n'
            f'      <material name="kms2pin_{kind}"/>\n    </visual>'
        )
    out.append(
        f'    <collision name="{body.name}_inner">\n      {origin}\n'
        f'      <geometry>\n        <mesh filename="{mesh}" scale="{_vec(body.inner)}"/>\n      </geometry>\n'
        "    </collision>"
    )
    out.append("  </link>")
    return "\n".join(out)


def _joint(system: System, joint: Joint) -> str:
    xyz, R = joint_origin(system, joint)
    rpy = pin.rpy.matrixToRpy(R)
    lines = [
        f'  <joint name={quoteattr(joint.name)} type="{joint.kind}">',
        f'    <parent link="{joint.parent_link}"/>',
        f'    <child link="{joint.child}"/>',
        f'    <origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>',
    ]
    if joint.kind == "revolute":
        lines.append(f'    <axis xyz="{_vec(joint.child_bvec.orient)}"/>')
        lower, upper = (-LIMIT, LIMIT) if joint.limits is None else (math.radians(a) for a in joint.limits)
        lines.append(f'    <limit lower="{_num(lower)}" upper="{_num(upper)}" effort="0" velocity="0"/>')
    lines.append("  </joint>")
    return "\n".join(lines)


def to_urdf(system: System, source: str = "", free_root: bool = False) -> str:
    """URDF text of one system.  With ``free_root`` the world link and the joint to
    the inertial frame are left out (a caller adds a free-flyer root joint)."""
    head = [
        '<?xml version="1.0"?>',
        f"<!-- generated by kms2pin from {source or 'a spec'}; do not edit."
        " Link frames sit at each body's joint to its parent; ellipsoid centres are the"
        " visual origins. "
        + (
            "Revolute limits are the spec's where it gives them, nominal (+-180 deg) elsewhere. -->"
            if any(j.limits is not None for j in system.joints)
            else "Revolute limits are nominal: the thesis's joints have none. -->"
        ),
        f"<robot name={quoteattr(system.name)}>",
        _material("kms2pin_inner", INNER_RGBA),
        _material("kms2pin_outer", OUTER_RGBA),
    ]
    body = []
    if not free_root:
        body.append(f'  <link name="{WORLD}"/>')
    for b in system.bodies:
        body.append(_link(system, b.name))
    for j in system.joints:
        if free_root and j.parent is None:
            continue
        body.append(_joint(system, j))
    return "\n".join(head + body + ["</robot>"]) + "\n"


def to_srdf(system: System, source: str = "", free_root: bool = False) -> str:
    """SRDF text: a group with every joint, the "rest" group state (default angles,
    radians; ROS/MoveIt convention read by pinocchio.loadReferenceConfigurations) and
    adjacent-link collision exclusions."""
    joints = [j for j in system.joints if not (free_root and j.parent is None)]
    lines = [
        '<?xml version="1.0"?>',
        f"<!-- generated by kms2pin from {source or 'a spec'}; do not edit -->",
        f"<robot name={quoteattr(system.name)}>",
        f"  <group name={quoteattr(system.name)}>",
    ]
    lines += [f"    <joint name={quoteattr(j.name)}/>" for j in joints]
    lines.append("  </group>")
    lines.append(f'  <group_state name="rest" group={quoteattr(system.name)}>')
    lines += [
        f'    <joint name={quoteattr(j.name)} value="{_num(rest_angle(j))}"/>'
        for j in joints
        if j.kind == "revolute"
    ]
    lines.append("  </group_state>")
    for j in system.joints:
        if j.parent is not None:
            lines.append(f'  <disable_collisions link1="{j.parent}" link2="{j.child}" reason="Adjacent"/>')
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
