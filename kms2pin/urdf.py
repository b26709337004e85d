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

A prismatic joint has the same origin and axis; at offset d the child end's point is
d o_ij from the parent end's.  URDF has no spherical joint: one is three revolute
joints ``<joint>_x``, ``_y``, ``_z`` about x, then the new y, then the new z of the
parent's axes at a_ij, through two massless, geometry-free links ``<joint>_x_link``
and ``<joint>_y_link``; the last joint's origin holds R_align, so R_ij =
Rx(a) Ry(b) Rz(c) R_align.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from xml.sax.saxutils import quoteattr

import numpy as np
import pinocchio as pin

from .mesh import MESH_NAME
from .model import WORLD, Joint, System, alignment_matrix, rotation_vector_matrix, xyz_angles

DENSITY = 1000.0  # kg/m^3, a uniform solid inner ellipsoid (about a human body's density)
INNER_RGBA = (0.80, 0.45, 0.20, 1.0)
OUTER_RGBA = (0.35, 0.55, 0.85, 0.25)
MESH_DIR = "meshes"
LIMIT = math.pi  # the thesis's joints have no limits: a full turn either way of 0 is allowed
#: A prismatic joint without limits in the spec: nominal +- this (the language's largest length).
PRISMATIC_LIMIT = 1e6
#: A prismatic joint's URDF effort (N) and velocity (spec length units per second): nominal.
PRISMATIC_EFFORT, PRISMATIC_VELOCITY = 1000.0, 1.0


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


def urdf_number(x: float) -> float:
    """``x`` as the URDF's text gives it back (15 significant digits)."""
    return float(_num(x))


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


def _joint_element(name: str, kind: str, parent: str, child: str, xyz, R: np.ndarray, tail: list[str]) -> str:
    lines = [
        f'  <joint name={quoteattr(name)} type="{kind}">',
        f'    <parent link="{parent}"/>',
        f'    <child link="{child}"/>',
        f'    <origin xyz="{_vec(xyz)}" rpy="{_vec(pin.rpy.matrixToRpy(R))}"/>',
        *tail,
        "  </joint>",
    ]
    return "\n".join(lines)


def _limit(lower: float, upper: float, effort: float = 0.0, velocity: float = 0.0) -> str:
    return (f'    <limit lower="{_num(lower)}" upper="{_num(upper)}" effort="{_num(effort)}" '
            f'velocity="{_num(velocity)}"/>')


def spherical_parts(joint_name: str) -> tuple[tuple[str, str, str], tuple[str, str]]:
    """A spherical joint's URDF joints ``(<j>_x, <j>_y, <j>_z)`` and links ``(<j>_x_link, <j>_y_link)``."""
    joints = tuple(f"{joint_name}_{a}" for a in "xyz")
    return joints, (f"{joints[0]}_link", f"{joints[1]}_link")


def _spherical(joint: Joint, xyz, R_align: np.ndarray) -> str:
    names, links = spherical_parts(joint.name)
    chain = [joint.parent_link, *links, joint.child]
    e = np.eye(3)
    out = []
    for k in range(3):
        last = k == 2
        axis = R_align.T @ e[k] if last else e[k]  # the third turns about z before R_align
        out.append(_joint_element(
            names[k], "revolute", chain[k], chain[k + 1], xyz if k == 0 else np.zeros(3),
            R_align if last else np.eye(3), [f'    <axis xyz="{_vec(axis)}"/>', _limit(-LIMIT, LIMIT)],
        ))
    return "\n".join(out)


def _joint(system: System, joint: Joint) -> str:
    xyz, R = joint_origin(system, joint)
    if joint.kind == "spherical":
        return _spherical(joint, xyz, R)
    tail = []
    if joint.kind == "revolute":
        tail.append(f'    <axis xyz="{_vec(joint.child_bvec.orient)}"/>')
        lower, upper = (-LIMIT, LIMIT) if joint.limits is None else (math.radians(a) for a in joint.limits)
        tail.append(_limit(lower, upper))
    elif joint.kind == "prismatic":
        tail.append(f'    <axis xyz="{_vec(joint.child_bvec.orient)}"/>')
        lower, upper = (-PRISMATIC_LIMIT, PRISMATIC_LIMIT) if joint.limits is None else joint.limits
        tail.append(_limit(lower, upper, PRISMATIC_EFFORT, PRISMATIC_VELOCITY))
    return _joint_element(joint.name, joint.kind, joint.parent_link, joint.child, xyz, R, tail)


def to_urdf(system: System, source: str = "", free_root: bool = False) -> str:
    """URDF text of one system.  With ``free_root`` the world link and the joint to
    the inertial frame are left out (a caller adds a free-flyer root joint)."""
    head = [
        '<?xml version="1.0"?>',
        f"<!-- generated by kms2pin from {source or 'a spec'}; do not edit."
        " Link frames sit at each body's joint to its parent; ellipsoid centres are the"
        " visual origins. "
        + (
            "Revolute limits are the spec's where it gives them, nominal (+-180 deg) elsewhere."
            if any(j.limits is not None for j in system.joints)
            else "Revolute limits are nominal: the thesis's joints have none."
        )
        + _new_joints_note(system)
        + " -->",
        f"<robot name={quoteattr(system.name)}>",
        _material("kms2pin_inner", INNER_RGBA),
        _material("kms2pin_outer", OUTER_RGBA),
    ]
    body = []
    if not free_root:
        body.append(f'  <link name="{WORLD}"/>')
    for b in system.bodies:
        body.append(_link(system, b.name))
    joints = [j for j in system.joints if not (free_root and j.parent is None)]
    body += [f"  <link name={quoteattr(n)}/>" for j in joints if j.kind == "spherical" for n in spherical_parts(j.name)[1]]
    body += [_joint(system, j) for j in joints]
    return "\n".join(head + body + ["</robot>"]) + "\n"


def _new_joints_note(system: System) -> str:
    """The header comment's words on spherical and prismatic joints (none without them)."""
    note = ""
    if system.count("spherical"):
        note += (" A spherical joint J is three revolute joints J_x, J_y, J_z (intrinsic rotations about x,"
                 " the new y, the new z of the parent's axes) through two massless links J_x_link, J_y_link.")
    if system.count("prismatic"):
        note += (f" Prismatic limits are the spec's where it gives them, nominal (+-{PRISMATIC_LIMIT:g})"
                 " elsewhere.")
    return note


def rest_values(joint: Joint) -> list[tuple[str, float]]:
    """(URDF joint name, rest value) of ``joint``: radians for revolute joints and a spherical
    joint's three angles (Exp(r) = Rx Ry Rz), spec length units for a prismatic joint; none
    for a fixed joint."""
    if joint.kind == "revolute":
        return [(joint.name, rest_angle(joint))]
    if joint.kind == "prismatic":
        return [(joint.name, joint.default_offset)]
    if joint.kind == "spherical":
        angles = xyz_angles(rotation_vector_matrix(joint.default_rotation))
        return list(zip(spherical_parts(joint.name)[0], (float(a) for a in angles)))
    return []


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
    names = [n for j in joints for n in (spherical_parts(j.name)[0] if j.kind == "spherical" else (j.name,))]
    lines += [f"    <joint name={quoteattr(n)}/>" for n in names]
    lines.append("  </group>")
    lines.append(f'  <group_state name="rest" group={quoteattr(system.name)}>')
    lines += [f'    <joint name={quoteattr(n)} value="{_num(v)}"/>' for j in joints for n, v in rest_values(j)]
    lines.append("  </group_state>")
    for j in system.joints:
        if j.parent is not None:
            lines.append(f'  <disable_collisions link1="{j.parent}" link2="{j.child}" reason="Adjacent"/>')
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
