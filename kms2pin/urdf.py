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

A prismatic joint has the same origin and axis; at offset d the child end's point is
d o_ij from the parent end's.  URDF has no spherical joint: one is three revolute
joints ``<joint>_x``, ``_y``, ``_z`` about x, then the new y, then the new z of the
parent's axes at a_ij, through two massless, geometry-free links ``<joint>_x_link``
and ``<joint>_y_link``; the last joint's origin holds R_align, so R_ij =
Rx(a) Ry(b) Rz(c) R_align.  MuJoCo refuses a moving body without mass: a model with
spherical joints carries MuJoCo's ``<mujoco><compiler boundmass boundinertia/></mujoco>``
extension, which other readers ignore.

Loops.  URDF describes a tree: a system with loop closures (``System.closures``) is
exported as its spanning tree, the header comment says so, and the closures go to a side
file ``<system>.closures.json`` (:func:`closures_json`: each closure's two frames in its
links and what must hold between them); the SRDF's rest state is then the rest pose
closed (``rest`` of :func:`to_srdf`) and it excludes the collisions of each closure's
two links.

For other tools: a revolute joint the spec leaves unlimited (and each of a spherical
joint's three) is ``continuous``; a prismatic joint without spec limits has nominal
ones (:data:`PRISMATIC_LIMIT`: URDF requires them); every movable joint has placeholder
effort and velocity limits (:data:`EFFORT`, :data:`VELOCITY`, :data:`PRISMATIC_VELOCITY`:
the spec has no dynamics); a free root is a ``floating`` joint :data:`ROOT_JOINT` from
``world`` whose rest placement is in the SRDF's ``rest`` state.  kms2pin's own Pinocchio
model is built from the compiled model directly (:mod:`kms2pin.pinmodel`), with the same
joints; there a spherical joint is one joint (a quaternion).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence

import numpy as np
import pinocchio as pin

from .errors import ExportError
from .mesh import MESH_NAME
from .model import WORLD, Joint, System, alignment_matrix, rest_joint_transform, rotation_vector_matrix, xyz_angles
from .xmltext import attr, comment, num, vec

DENSITY = 1000.0  # kg/m^3, a uniform solid inner ellipsoid (about a human body's density)
INNER_RGBA = (0.80, 0.45, 0.20, 1.0)
OUTER_RGBA = (0.35, 0.55, 0.85, 0.25)
MESH_DIR = "meshes"
#: Placeholder joint effort limit (N m) of every movable joint: the spec has no dynamics,
#: but simulators and planners read 0 as "cannot move".  Large enough for a person or an arm.
EFFORT = 1000.0
#: Placeholder joint velocity limit (rad/s, about 570 deg/s), as for :data:`EFFORT`.
VELOCITY = 10.0
#: A prismatic joint without limits in the spec: nominal +- this (the language's largest length).
PRISMATIC_LIMIT = 1e6
#: A prismatic joint's placeholder velocity limit (spec length units per second).
PRISMATIC_VELOCITY = 1.0
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


def urdf_number(x: float) -> float:
    """``x`` as the URDF's text gives it back (15 significant digits)."""
    return float(num(x))


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
    R, d = rest_joint_transform(j)
    return pin.SE3(R, np.asarray(j.parent_bvec.pos, dtype=float) + d)


def centre_offset(system: System, body: str) -> np.ndarray:
    """The ellipsoid centre of ``body`` in its link frame: -a_ji (spec units)."""
    return -np.asarray(system.joint_of(body).child_bvec.pos, dtype=float)


def ellipsoid_mass(semi_axes: Sequence[float]) -> tuple[float, np.ndarray]:
    """Mass and diagonal inertia (about the centre, body axes) of a solid ellipsoid."""
    a, b, c = semi_axes
    m = DENSITY * 4.0 / 3.0 * math.pi * a * b * c
    return m, m / 5.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


def root_joint_clash(system: System) -> Joint | None:
    """The joint of ``system`` (not the one to the inertial frame) already called
    :data:`ROOT_JOINT`, a free root's name, or None."""
    return next((j for j in system.joints if j.name == ROOT_JOINT and j.parent is not None), None)


def check_root_joint_name(system: System) -> None:
    """ExportError if a joint of ``system`` is already called :data:`ROOT_JOINT` (a free root's name)."""
    j = root_joint_clash(system)
    if j is not None:
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


def _limit(lower: float | None = None, upper: float | None = None, velocity: float = VELOCITY) -> str:
    """A ``<limit>`` with the placeholder effort and velocity, and the range if given."""
    span = "" if lower is None else f'lower="{num(lower)}" upper="{num(upper)}" '
    return f'    <limit {span}effort="{num(EFFORT)}" velocity="{num(velocity)}"/>'


def _axis(v) -> str:
    return f'    <axis xyz="{vec(v)}"/>'


def _joint_element(name: str, kind: str, parent: str, child: str, xyz, R: np.ndarray, tail: list[str]) -> str:
    lines = [
        f"  <joint name={attr(name)} type=\"{kind}\">",
        f"    <parent link={attr(parent)}/>",
        f"    <child link={attr(child)}/>",
        f'    <origin xyz="{vec(xyz)}" rpy="{vec(pin.rpy.matrixToRpy(R))}"/>',
        *tail,
        "  </joint>",
    ]
    return "\n".join(lines)


def spherical_parts(joint_name: str) -> tuple[tuple[str, str, str], tuple[str, str]]:
    """A spherical joint's URDF joints ``(<j>_x, <j>_y, <j>_z)`` and links ``(<j>_x_link, <j>_y_link)``."""
    joints = tuple(f"{joint_name}_{a}" for a in "xyz")
    return joints, (f"{joints[0]}_link", f"{joints[1]}_link")


def _spherical(joint: Joint, xyz, R_align: np.ndarray) -> str:
    """Three continuous joints through two massless links (module docstring)."""
    names, links = spherical_parts(joint.name)
    chain = [joint.parent_link, *links, joint.child]
    e = np.eye(3)
    out = []
    for k in range(3):
        last = k == 2
        axis = R_align.T @ e[k] if last else e[k]  # the third turns about z before R_align
        out.append(_joint_element(names[k], "continuous", chain[k], chain[k + 1], xyz if k == 0 else np.zeros(3),
                                  R_align if last else np.eye(3), [_axis(axis), _limit()]))
    return "\n".join(out)


def _revolute(joint: Joint) -> tuple[str, list[str]]:
    """URDF type and lines after the origin of a revolute joint (module docstring)."""
    if joint.limits is not None:
        return "revolute", [_axis(joint.child_bvec.orient), _limit(*(math.radians(a) for a in joint.limits))]
    return "continuous", [_axis(joint.child_bvec.orient), _limit()]


def _prismatic(joint: Joint) -> tuple[str, list[str]]:
    lower, upper = (-PRISMATIC_LIMIT, PRISMATIC_LIMIT) if joint.limits is None else joint.limits
    return "prismatic", [_axis(joint.child_bvec.orient), _limit(lower, upper, PRISMATIC_VELOCITY)]


#: Per joint kind of the model: (URDF type, lines after <origin>) of a joint (spherical
#: joints are three: :func:`_spherical`).
_JOINT_WRITERS = {
    "fixed": lambda joint: ("fixed", []),
    "revolute": _revolute,
    "prismatic": _prismatic,
}


def _joint(system: System, joint: Joint) -> str:
    xyz, R = joint_origin(system, joint)
    if joint.kind == "spherical":
        return _spherical(joint, xyz, R)
    kind, tail = _JOINT_WRITERS[joint.kind](joint)
    return _joint_element(joint.name, kind, joint.parent_link, joint.child, xyz, R, tail)


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


def to_urdf(system: System, source: str = "", free_root: bool = False) -> str:
    """URDF text of one system (``source``: the spec's file name, for the header comment).

    ``free_root``: the joint to the inertial frame is replaced by a free root, the
    ``floating`` joint :data:`ROOT_JOINT` from ``world`` (its origin the identity, so
    its configuration is the root link's world placement).
    """
    if free_root:
        check_root_joint_name(system)
    notes = (
        "Link frames sit at each body's joint to its parent; ellipsoid centres are the collision and visual "
        "origins. Joint ranges are the spec's; joints it leaves unlimited are continuous. "
        f"Effort and velocity limits are placeholders ({num(EFFORT)} N m, {num(VELOCITY)} rad/s): "
        "the spec has no dynamics." + _new_joints_note(system)
    )
    if free_root:
        notes += f" The floating {ROOT_JOINT}'s rest placement is in the SRDF's rest state."
    if system.closures:
        notes += (f" The model has kinematic loops, which URDF cannot express: this is its spanning tree, and its "
                  f"{len(system.closures)} loop closures ({', '.join(j.name for j in system.closures)}) are in "
                  f"{system.name}.closures.json; the SRDF's rest state closes them.")
    out = [
        '<?xml version="1.0"?>',
        _header(source, notes),
        f"<robot name={attr(system.name)}>",
        *(_MUJOCO_MASSLESS if system.count("spherical") else []),
        _material("kms2pin_inner", INNER_RGBA),
        _material("kms2pin_outer", OUTER_RGBA),
        f'  <link name="{WORLD}"/>',
    ]
    out += [_link(system, b.name) for b in system.bodies]
    joints = [j for j in system.joints if not (free_root and j.parent is None)]
    out += [f"  <link name={attr(n)}/>" for j in joints if j.kind == "spherical" for n in spherical_parts(j.name)[1]]
    if free_root:
        out.append(_floating_root(system))
    out += [_joint(system, j) for j in joints]
    return "\n".join(out + ["</robot>"]) + "\n"


#: MuJoCo's URDF extension for a model with spherical joints: their two massless links move,
#: and MuJoCo refuses a moving body without mass unless told a least mass and inertia
#: (other URDF readers ignore the element)
_MUJOCO_MASSLESS = ["  <mujoco>", '    <compiler boundmass="1e-9" boundinertia="1e-12"/>', "  </mujoco>"]


def _new_joints_note(system: System) -> str:
    """The header comment's words on spherical and prismatic joints (none without them)."""
    note = ""
    if system.count("spherical"):
        note += (" A spherical joint J is three continuous joints J_x, J_y, J_z (intrinsic rotations about x,"
                 " the new y, the new z of the parent's axes) through two massless links J_x_link, J_y_link.")
    if system.count("prismatic"):
        note += (f" Prismatic limits are the spec's where it gives them, nominal (+-{PRISMATIC_LIMIT:g})"
                 f" elsewhere; their velocity limit is {num(PRISMATIC_VELOCITY)} length units/s.")
    return note


#: What must hold between a loop closure's two frames, per joint type (closures_json's "holds").
CLOSURE_CONDITIONS = {
    "fixed": "the two frames coincide",
    "spherical": "the two frames' origins coincide",
    "revolute": "the two frames' origins coincide and their 'axis' vectors (in each frame) are one world "
                "vector: the child frame turns about it",
    "prismatic": "the two frames' axes are parallel (equal orientations) and the child frame's origin lies on "
                 "the line through the parent frame's origin along 'axis'",
}


def closures_json(system: System, source: str = "") -> str:
    """The loop closures of ``system`` as JSON text (the side file of its spanning-tree URDF):
    per closure its name, type, parent and child links (``world`` for the inertial frame),
    each end's frame in its link (``xyz``, ``rpy`` as a URDF origin: the parent end's point
    with the parent body's axes; the child end's point with the axes R_0j R_alignᵀ, eq.
    2.12), the joint axis o_ij in both frames, the condition that closes it, and the loop
    it closes (the links from its parent through the tree to its child)."""
    closures = []
    for j in system.closures:
        o_ij = np.asarray(j.parent_bvec.orient, dtype=float)
        R_align = alignment_matrix(o_ij, np.asarray(j.child_bvec.orient, dtype=float))
        frames = {}
        for side, body, bvec, R in (("parent", j.parent, j.parent_bvec, np.eye(3)),
                                    ("child", j.child, j.child_bvec, R_align.T)):
            xyz = np.asarray(bvec.pos, dtype=float) + (centre_offset(system, body) if body is not None else 0.0)
            frames[side] = {"xyz": [float(num(x)) for x in xyz],
                            "rpy": [float(num(x)) for x in pin.rpy.matrixToRpy(R)]}
        bodies, _ = system.loop(j)
        closures.append({
            "name": j.name,
            "type": j.kind,
            "parent_link": j.parent_link,
            "child_link": j.child_link,
            "parent_frame": frames["parent"],
            "child_frame": frames["child"],
            "axis": [float(num(x)) for x in o_ij],
            "holds": CLOSURE_CONDITIONS[j.kind],
            "loop": [b if b is not None else WORLD for b in bodies],
            "line": j.loc.line,
        })
    doc = {
        "generated_by": f"kms2pin from {source or 'a spec'}; do not edit",
        "system": system.name,
        "urdf": f"{system.name}.urdf",
        "note": "URDF cannot express a kinematic loop: the URDF is the spanning tree, and each closure here joins "
                "a frame on its parent link to a frame on its child link (frames as URDF origins in the links' "
                "frames); the SRDF's rest state closes every loop",
        "closures": closures,
    }
    return json.dumps(doc, indent=2) + "\n"


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


def to_srdf(system: System, source: str = "", free_root: bool = False, rest: Mapping[str, object] | None = None) -> str:
    """SRDF text: a group with every joint, the "rest" group state (default angles,
    radians; ROS/MoveIt convention read by pinocchio.loadReferenceConfigurations) and
    adjacent-link collision exclusions (a loop closure's two links too).  With
    ``free_root`` the floating root is also a ``virtual_joint`` and its rest placement is
    the state's ``x y z qx qy qz qw`` value (Pinocchio's free-flyer order, as MoveIt's
    floating joint).  ``rest``: the state's values by URDF joint name instead of the
    spec's (a model with loops: the rest pose closed, :meth:`kms2pin.Robot.urdf_values`)."""
    joints = [j for j in system.joints if not (free_root and j.parent is None)]
    group = attr(system.name)
    lines = ['<?xml version="1.0"?>', _header(source), f"<robot name={group}>"]
    if free_root:
        check_root_joint_name(system)
        lines.append(f'  <virtual_joint name="{ROOT_JOINT}" type="floating" parent_frame="{WORLD}" '
                     f"child_link={attr(system.root.name)}/>")
    lines.append(f"  <group name={group}>")
    lines += [f'    <joint name="{ROOT_JOINT}"/>'] if free_root else []
    names = [n for j in joints for n in (spherical_parts(j.name)[0] if j.kind == "spherical" else (j.name,))]
    lines += [f"    <joint name={attr(n)}/>" for n in names]
    lines.append("  </group>")
    lines.append(f'  <group_state name="rest" group={group}>')
    if free_root:
        root = pin.SE3ToXYZQUAT(root_rest_placement(system)) if rest is None else rest[ROOT_JOINT]
        lines.append(f'    <joint name="{ROOT_JOINT}" value="{vec(root)}"/>')
    values = [(n, v if rest is None else rest[n]) for j in joints for n, v in rest_values(j)]
    lines += [f"    <joint name={attr(n)} value=\"{num(v)}\"/>" for n, v in values]
    lines.append("  </group_state>")
    for j in (*system.joints, *system.closures):
        if j.parent is not None and j.child is not None:
            lines.append(f"  <disable_collisions link1={attr(j.parent)} link2={attr(j.child)} reason=\"Adjacent\"/>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
