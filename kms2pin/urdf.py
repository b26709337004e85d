"""Model -> URDF and SRDF text (thesis eq. 2.12-2.16 expressed as URDF joints).

Link frames.  A URDF joint rotates its child about an axis through the child
link's origin, so a body's *link* frame sits at the point of its joint to its
parent (the child bound vector's ``pos``, a_ji) with the body's axes; the
ellipsoid centre (the thesis's body frame) is at ``-a_ji`` in that link frame and
is where the collision shape, the visuals and the inertial are placed.

Joints.  With parent bound vector (a_ij, o_ij) and child (a_ji, o_ji):
origin xyz = a_ij expressed in the parent link frame, origin rpy = R_align with
R_align o_ji = o_ij (eq. 2.12), axis = o_ji in the child frame, so that at angle
theta the child's orientation is Rot(o_ij, theta) R_align = R_align Rot(o_ji, theta)
(eq. 2.16) and its centre obeys eq. 2.14.  Angle 0 means the axes are aligned;
the spec's default angles are the SRDF group state "rest".

Two flavours of the same tree (``for_model``).  The exported URDF is for other tools:
a revolute joint the spec leaves unlimited is ``continuous``, every movable joint has
placeholder effort and velocity limits (:data:`EFFORT`, :data:`VELOCITY`: the spec has
no dynamics), and a free root is a ``floating`` joint :data:`ROOT_JOINT` from ``world``
whose rest placement is in the SRDF's ``rest`` state.  kms2pin's own Pinocchio model
(:class:`~kms2pin.robot.Robot`) is built from the other flavour: unlimited joints are
``revolute`` with nominal +-pi limits (one coordinate each, where Pinocchio's parser
makes a ``continuous`` joint two: cos, sin) and a free root is left to the caller's
free flyer.  Both have the same joints in the same order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from .errors import ExportError
from .mesh import MESH_NAME
from .model import WORLD, Joint, System, alignment_matrix, axis_angle_matrix
from .xmltext import attr, comment, num, vec

DENSITY = 1000.0  # kg/m^3, a uniform solid inner ellipsoid (about a human body's density)
INNER_RGBA = (0.80, 0.45, 0.20, 1.0)
OUTER_RGBA = (0.35, 0.55, 0.85, 0.25)
MESH_DIR = "meshes"
LIMIT = math.pi  # kms2pin's own model: a joint without limits may turn a full turn either way of 0
#: Placeholder joint effort limit (N m) of every movable joint: the spec has no dynamics,
#: but simulators and planners read 0 as "cannot move".  Large enough for a person or an arm.
EFFORT = 1000.0
#: Placeholder joint velocity limit (rad/s, about 570 deg/s), as for :data:`EFFORT`.
VELOCITY = 10.0
#: Name of a free root's joint: Pinocchio's name for the free flyer it adds as root, the
#: exported URDF's ``floating`` joint and the SRDF's ``virtual_joint``.
ROOT_JOINT = "root_joint"


def wrap_angle(a: float) -> float:
    """The same angle in (-pi, pi] (rest angles beyond a half turn stay within the limits)."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def rest_angle(joint: Joint) -> float:
    """A revolute joint's rest angle (radians): the default angle, in (-pi, pi] unless the
    spec's limits place it elsewhere."""
    a = math.radians(joint.default_angle)
    return a if joint.limits is not None else wrap_angle(a)


def joint_origin(system: System, joint: Joint) -> tuple[np.ndarray, np.ndarray]:
    """(xyz, R) of ``joint``'s frame at angle 0 in its parent's link frame."""
    a_ij = np.asarray(joint.parent_bvec.pos)
    if joint.parent is not None:
        a_ij = a_ij - np.asarray(system.joint_of(joint.parent).child_bvec.pos)
    R = alignment_matrix(np.asarray(joint.parent_bvec.orient), np.asarray(joint.child_bvec.orient))
    return a_ij, R


def root_rest_placement(system: System) -> pin.SE3:
    """world_T_link of the root body at rest (its link frame at the joint point, eq. 2.12,
    2.16): what a free root's configuration is at the spec's rest pose."""
    j = system.joints[0]
    R = axis_angle_matrix(np.asarray(j.parent_bvec.orient), np.radians(j.default_angle))
    R = R @ alignment_matrix(np.asarray(j.parent_bvec.orient), np.asarray(j.child_bvec.orient))
    return pin.SE3(R, np.asarray(j.parent_bvec.pos, dtype=float))


def centre_offset(system: System, body: str) -> np.ndarray:
    """The ellipsoid centre of ``body`` in its link frame: -a_ji (spec units)."""
    return -np.asarray(system.joint_of(body).child_bvec.pos, dtype=float)


def ellipsoid_mass(semi_axes: Sequence[float]) -> tuple[float, np.ndarray]:
    """Mass and diagonal inertia (about the centre, body axes) of a solid ellipsoid."""
    a, b, c = semi_axes
    m = DENSITY * 4.0 / 3.0 * math.pi * a * b * c
    return m, m / 5.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


def check_root_joint_name(system: System) -> None:
    """ExportError if a joint of ``system`` is already called :data:`ROOT_JOINT` (a free root's name)."""
    for j in system.joints:
        if j.name == ROOT_JOINT and j.parent is not None:
            raise ExportError(
                f"'{system.name}' has a joint called '{ROOT_JOINT}' (body '{j.child}'), the name a free root's "
                "joint takes; rename the body or its bound vector, or keep the spec's root"
            )


def _material(name: str, rgba) -> str:
    return f"  <material name={attr(name)}>\n    <color rgba=\"{vec(rgba)}\"/>\n  </material>"


def _geometry(origin: str, scale: Sequence[float]) -> str:
    return (f"      {origin}\n      <geometry>\n        <mesh filename=\"{MESH_DIR}/{MESH_NAME}\" "
            f"scale=\"{vec(scale)}\"/>\n      </geometry>\n")


def _link(system: System, body_name: str) -> str:
    """The link: inertial, then the collision shape (named ``<body>_collision``), then the
    unnamed inner and outer visuals (collision first: MuJoCo's URDF reader otherwise gives it
    the last visual's colour; unnamed visuals: urdf_parser_py warns of a name there)."""
    body = system.body(body_name)
    origin = f'<origin xyz="{vec(centre_offset(system, body_name))}" rpy="0 0 0"/>'
    m, inertia = ellipsoid_mass(body.inner)
    out = [f"  <link name={attr(body.name)}>"]
    out.append(
        f"    <inertial>\n      {origin}\n      <mass value=\"{num(m)}\"/>\n"
        f'      <inertia ixx="{num(inertia[0])}" ixy="0" ixz="0" iyy="{num(inertia[1])}" '
        f'iyz="0" izz="{num(inertia[2])}"/>\n    </inertial>'
    )
    out.append(f"    <collision name={attr(body.name + '_collision')}>\n{_geometry(origin, body.inner)}    </collision>")
    for kind, lam in (("inner", body.inner), ("outer", body.outer)):
        out.append(f"    <visual>\n{_geometry(origin, lam)}      <material name=\"kms2pin_{kind}\"/>\n    </visual>")
    out.append("  </link>")
    return "\n".join(out)


def _limit(lower: float | None = None, upper: float | None = None) -> str:
    """A ``<limit>`` with the placeholder effort and velocity, and the range if given (radians)."""
    span = "" if lower is None else f'lower="{num(lower)}" upper="{num(upper)}" '
    return f'    <limit {span}effort="{num(EFFORT)}" velocity="{num(VELOCITY)}"/>'


def _revolute(joint: Joint, for_model: bool) -> tuple[str, list[str]]:
    """URDF type and lines after the origin of a revolute joint (module docstring)."""
    axis = f'    <axis xyz="{vec(joint.child_bvec.orient)}"/>'
    if joint.limits is not None:
        return "revolute", [axis, _limit(*(math.radians(a) for a in joint.limits))]
    if for_model:
        return "revolute", [axis, _limit(-LIMIT, LIMIT)]
    return "continuous", [axis, _limit()]


#: Per joint kind of the model: (URDF type, lines after <origin>) of a joint.
_JOINT_WRITERS = {
    "fixed": lambda joint, for_model: ("fixed", []),
    "revolute": _revolute,
}


def _joint(system: System, joint: Joint, for_model: bool) -> str:
    xyz, R = joint_origin(system, joint)
    kind, tail = _JOINT_WRITERS[joint.kind](joint, for_model)
    lines = [
        f'  <joint name={attr(joint.name)} type="{kind}">',
        f"    <parent link={attr(joint.parent_link)}/>",
        f"    <child link={attr(joint.child)}/>",
        f'    <origin xyz="{vec(xyz)}" rpy="{vec(pin.rpy.matrixToRpy(R))}"/>',
        *tail,
        "  </joint>",
    ]
    return "\n".join(lines)


def _floating_root(system: System) -> str:
    return "\n".join([
        f'  <joint name="{ROOT_JOINT}" type="floating">',
        f'    <parent link="{WORLD}"/>',
        f"    <child link={attr(system.root.name)}/>",
        '    <origin xyz="0 0 0" rpy="0 0 0"/>',
        "  </joint>",
    ])


def _header(source: str, what: str = "") -> str:
    return comment(f"generated by kms2pin from {source or 'a spec'}; do not edit" + (f". {what}" if what else ""))


def to_urdf(system: System, source: str = "", free_root: bool = False, *, for_model: bool = False) -> str:
    """URDF text of one system (``source``: the spec's file name, for the header comment).

    ``free_root``: the joint to the inertial frame is replaced by a free root, the
    ``floating`` joint :data:`ROOT_JOINT` from ``world`` (its origin the identity, so
    its configuration is the root link's world placement).  ``for_model``: the flavour
    kms2pin builds its own Pinocchio model from (module docstring): no world link and
    no floating joint with ``free_root`` (the caller adds the free flyer).
    """
    if free_root:
        check_root_joint_name(system)
    notes = (
        "Link frames sit at each body's joint to its parent; ellipsoid centres are the collision and visual "
        "origins. Joint ranges are the spec's; "
        + ("joints it leaves unlimited have nominal +-pi ones (kms2pin's own model). " if for_model
           else "joints it leaves unlimited are continuous. ")
        + f"Effort and velocity limits are placeholders ({num(EFFORT)} N m, {num(VELOCITY)} rad/s): "
        "the spec has no dynamics."
    )
    if free_root and not for_model:
        notes += f" The floating {ROOT_JOINT}'s rest placement is in the SRDF's rest state."
    out = [
        '<?xml version="1.0"?>',
        _header(source, notes),
        f"<robot name={attr(system.name)}>",
        _material("kms2pin_inner", INNER_RGBA),
        _material("kms2pin_outer", OUTER_RGBA),
    ]
    if not (free_root and for_model):
        out.append(f'  <link name="{WORLD}"/>')
    out += [_link(system, b.name) for b in system.bodies]
    if free_root and not for_model:
        out.append(_floating_root(system))
    out += [_joint(system, j, for_model) for j in system.joints if not (free_root and j.parent is None)]
    return "\n".join(out + ["</robot>"]) + "\n"


def _rest_value(joint: Joint) -> str | None:
    """A joint's value in the SRDF ``rest`` state (radians), None for a fixed joint."""
    return num(rest_angle(joint)) if joint.kind == "revolute" else None


def to_srdf(system: System, source: str = "", free_root: bool = False) -> str:
    """SRDF text: a group with every joint, the "rest" group state (default angles,
    radians; ROS/MoveIt convention read by pinocchio.loadReferenceConfigurations) and
    adjacent-link collision exclusions.  With ``free_root`` the floating root is also a
    ``virtual_joint`` and its rest placement is the state's ``x y z qx qy qz qw`` value
    (Pinocchio's free-flyer order, as MoveIt's floating joint)."""
    joints = [j for j in system.joints if not (free_root and j.parent is None)]
    group = attr(system.name)
    lines = ['<?xml version="1.0"?>', _header(source), f"<robot name={group}>"]
    if free_root:
        check_root_joint_name(system)
        lines.append(f'  <virtual_joint name="{ROOT_JOINT}" type="floating" parent_frame="{WORLD}" '
                     f"child_link={attr(system.root.name)}/>")
    lines.append(f"  <group name={group}>")
    lines += [f'    <joint name="{ROOT_JOINT}"/>'] if free_root else []
    lines += [f"    <joint name={attr(j.name)}/>" for j in joints]
    lines.append("  </group>")
    lines.append(f'  <group_state name="rest" group={group}>')
    if free_root:
        lines.append(f'    <joint name="{ROOT_JOINT}" value="{vec(pin.SE3ToXYZQUAT(root_rest_placement(system)))}"/>')
    values = [(j, _rest_value(j)) for j in joints]
    lines += [f"    <joint name={attr(j.name)} value=\"{v}\"/>" for j, v in values if v is not None]
    lines.append("  </group_state>")
    for j in system.joints:
        if j.parent is not None:
            lines.append(f"  <disable_collisions link1={attr(j.parent)} link2={attr(j.child)} reason=\"Adjacent\"/>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
