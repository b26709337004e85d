"""Model -> MJCF text, MuJoCo's own format (``kms2pin export --format mjcf``).

The same tree as the URDF (:mod:`kms2pin.urdf`), in MuJoCo's terms:

- Bodies nest as the joint tree.  A body's frame is its URDF link frame (at its joint
  to its parent, with the body's axes), placed in its parent's by ``pos`` and ``quat``
  (w, x, y, z) = the joint origin (a_ij, R_align; eq. 2.12), so MuJoCo's ``xpos`` and
  ``xquat`` are Pinocchio's BODY frames.
- At the ellipsoid centre (-a_ji in the body frame): the inner ellipsoid as a native
  ``ellipsoid`` geom (class ``kms2pin_inner``, geom group 0; it collides, and its solid
  ellipsoid of density :data:`~kms2pin.urdf.DENSITY` is the body's mass and inertia);
  the outer one for show only (class ``kms2pin_outer``, group 1, ``contype="0"
  conaffinity="0"``, kept out of the inertia by ``inertiagrouprange="0 0"``); and a
  site ``<body>_centre``, Pinocchio's frame of that name.
- Joints, one writer per kind of :class:`~kms2pin.model.Joint` (:data:`JOINT_WRITERS`):
  a revolute joint is a ``hinge`` about o_ji with a ``range`` (radians) only where the
  spec gives limits; a prismatic joint a ``slide`` along o_ji (ranged likewise); a
  spherical joint a ``ball`` at the joint point, whose qpos (w, x, y, z) is the rotation
  in the child body's frame at alignment, R_alignᵀ R R_align for the rotation R in the
  parent body's axes (Pinocchio's quaternion of the joint); a fixed joint welds the body
  to its parent (no element).  A free
  root is ``<freejoint name="root_joint"/>`` on a root body placed at its rest pose
  (a free joint's qpos is the body's world pose: x y z, then w x y z).
- A keyframe ``rest`` holds the spec's rest pose (with loops, its projection onto them:
  ``rest``); ``<contact><exclude>`` the adjacent pairs the SRDF excludes (a loop
  closure's two bodies too); gravity is 9.81 along -y (the thesis's models and cameras
  have +y up; lengths in the spec's units, metres in the thesis's models).
- Loop closures (``System.closures``) are equality constraints between sites on their two
  bodies (the worldbody for the inertial frame): ``<closure>_parent`` at the parent end's
  point with the parent body's axes and ``<closure>_child`` at the child end's point with
  the axes R_0j R_alignᵀ (:mod:`kms2pin.closures`'s frames), which coincide when the
  closure holds.  A spherical closure is a ``connect``, a fixed one a ``weld``, a
  revolute one two ``connect``s: at the joint point and at a point on the axis
  (``<closure>_parent_axis``, ``<closure>_child_axis``, :func:`axis_length` along o_ij
  and o_ji).  MuJoCo has no equality for a prismatic closure (a point on a line with the
  orientation held): it is left out, with a comment in the file and a warning.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping

import numpy as np
import pinocchio as pin

from .model import Body, Joint, System, alignment_matrix, rotation_vector_matrix
from .urdf import (
    DENSITY,
    INNER_RGBA,
    OUTER_RGBA,
    ROOT_JOINT,
    centre_offset,
    check_root_joint_name,
    joint_origin,
    rest_angle,
    root_rest_placement,
)
from .xmltext import attr, comment, num, vec

GRAVITY = (0.0, -9.81, 0.0)  # spec units / s^2 (m/s^2 in the thesis's models), +y up
INNER_GROUP = 0  # geom group of the inner ellipsoids (collide, carry the mass)
OUTER_GROUP = 1  # geom group of the outer ellipsoids (drawn only)


def _hinge(joint: Joint) -> tuple[list[str], list[float]]:
    """A revolute joint: a hinge about o_ji in the child frame, ranged where the spec limits it."""
    span = "" if joint.limits is None else f' range="{vec(np.radians(joint.limits))}"'
    return [f'<joint name={attr(joint.name)} type="hinge" axis="{vec(joint.child_bvec.orient)}"{span}/>'], [
        rest_angle(joint)
    ]


def _slide(joint: Joint) -> tuple[list[str], list[float]]:
    """A prismatic joint: a slide along o_ji in the child frame, ranged where the spec limits it."""
    span = "" if joint.limits is None else f' range="{vec(joint.limits)}"'
    return [f'<joint name={attr(joint.name)} type="slide" axis="{vec(joint.child_bvec.orient)}"{span}/>'], [
        joint.default_offset
    ]


def ball_alignment(joint: Joint) -> np.ndarray:
    """R_align of a spherical joint (eq. 2.12): its ball's qpos B is the rotation R (in the
    parent body's axes, Pinocchio's) seen in the child body's aligned frame, B = R_alignᵀ R R_align."""
    return alignment_matrix(np.asarray(joint.parent_bvec.orient), np.asarray(joint.child_bvec.orient))


def _ball(joint: Joint) -> tuple[list[str], list[float]]:
    """A spherical joint: a ball at the joint point; its rest qpos (w x y z) is
    R_alignᵀ Exp(r) R_align (module docstring)."""
    A = ball_alignment(joint)
    q = pin.Quaternion(A.T @ rotation_vector_matrix(joint.default_rotation) @ A)
    return [f'<joint name={attr(joint.name)} type="ball"/>'], [q.w, q.x, q.y, q.z]


#: Per joint kind of the model: the MJCF elements inside the child body and the joint's
#: rest qpos (MuJoCo's coordinates, in element order).
JOINT_WRITERS: dict[str, Callable[[Joint], tuple[list[str], list[float]]]] = {
    "fixed": lambda joint: ([], []),
    "revolute": _hinge,
    "prismatic": _slide,
    "spherical": _ball,
}


def _free_root(system: System) -> tuple[str, list[str], list[float]]:
    """The root body's placement attributes, its ``freejoint`` and rest qpos (x y z w x y z)."""
    M = root_rest_placement(system)
    q = pin.Quaternion(M.rotation)
    wxyz = [q.w, q.x, q.y, q.z]
    place = f'pos="{vec(M.translation)}" quat="{vec(wxyz)}"'
    return place, [f'<freejoint name="{ROOT_JOINT}"/>'], [*M.translation, *wxyz]


def _rest_qpos(joint: Joint, block: np.ndarray) -> list[float]:
    """MuJoCo's qpos of ``joint`` for its Pinocchio coordinates ``block``: a hinge's angle, a
    slide's offset, a ball's quaternion (w x y z) R_alignᵀ R R_align, a free joint's x y z w x y z."""
    if joint.kind == "spherical":
        A = ball_alignment(joint)
        q = pin.Quaternion(A.T @ pin.Quaternion(block[3], block[0], block[1], block[2]).toRotationMatrix() @ A)
        return [q.w, q.x, q.y, q.z]
    if len(block) == 7:
        return [*block[:3], block[6], *block[3:6]]
    return [float(x) for x in block]


def _open_body(system: System, body: Body, joint: Joint, free_root: bool,
               rest: Mapping[str, np.ndarray] | None, sites: list[str]) -> tuple[list[str], list[float]]:
    """The lines that open ``body`` (up to its children), the child of ``joint``, and its rest
    qpos (``rest``: Pinocchio's coordinates by joint name, instead of the spec's); ``sites``:
    the loop closures' sites on it."""
    if free_root and joint.parent is None:
        place, elements, qpos = _free_root(system)
        if rest is not None:
            qpos = _rest_qpos(joint, rest[ROOT_JOINT])
    else:
        xyz, R = joint_origin(system, joint)
        q = pin.Quaternion(R)
        place = f'pos="{vec(xyz)}" quat="{vec([q.w, q.x, q.y, q.z])}"'
        elements, qpos = JOINT_WRITERS[joint.kind](joint)
        if rest is not None and qpos:
            qpos = _rest_qpos(joint, rest[joint.name])
    centre = vec(-np.asarray(joint.child_bvec.pos, dtype=float))
    name = body.name
    lines = [f"<body name={attr(name)} {place}>", *("  " + e for e in elements)]
    lines += [
        f'  <geom name={attr(name + "_inner")} class="kms2pin_inner" size="{vec(body.inner)}" pos="{centre}"/>',
        f'  <geom name={attr(name + "_outer")} class="kms2pin_outer" size="{vec(body.outer)}" pos="{centre}"/>',
        f'  <site name={attr(name + "_centre")} pos="{centre}"/>',
        *("  " + site for site in sites),
    ]
    return lines, qpos


def _worldbody(system: System, free_root: bool, rest: Mapping[str, np.ndarray] | None,
               sites: Mapping[str | None, list[str]]) -> tuple[list[str], list[float]]:
    """The nested bodies (depth first, with an explicit stack: no recursion limit) and the
    rest qpos in MuJoCo's order (bodies depth first, joints in element order); ``sites``:
    the closures' sites per body (None: the worldbody)."""
    bodies = {b.name: b for b in system.bodies}
    children: dict[str | None, list[Joint]] = {}
    for j in system.joints:
        children.setdefault(j.parent, []).append(j)
    lines: list[str] = ["    " + site for site in sites.get(None, [])]
    qpos: list[float] = []
    stack: list[tuple[Joint, bool]] = [(j, False) for j in reversed(children.get(None, []))]
    depth = 2
    while stack:
        joint, opened = stack.pop()
        if opened:
            depth -= 1
            lines.append("  " * depth + "</body>")
            continue
        body_lines, body_qpos = _open_body(system, bodies[joint.child], joint, free_root, rest,
                                           sites.get(joint.child, []))
        lines += ["  " * depth + line for line in body_lines]
        qpos += body_qpos
        depth += 1
        stack.append((joint, True))
        stack += [(c, False) for c in reversed(children.get(joint.child, []))]
    return lines, qpos


def axis_length(system: System, closure: Joint) -> float:
    """How far along a revolute closure's axis its second ``connect`` sits: the largest inner
    semi-axis of its parent body (its child's if the parent is the inertial frame)."""
    return float(max(system.body(closure.parent or closure.child).inner))


def _closure_site(system: System, name: str, body: str | None, pos, R: np.ndarray) -> str:
    """A site at ``pos`` (the body's centre frame, or the world) with axes ``R`` in the body."""
    if body is not None:
        pos = np.asarray(pos, dtype=float) + centre_offset(system, body)
    q = pin.Quaternion(R)
    return f'<site name={attr(name)} pos="{vec(pos)}" quat="{vec([q.w, q.x, q.y, q.z])}"/>'


def _closures(system: System) -> tuple[dict[str | None, list[str]], list[str], list[str]]:
    """The loop closures: their sites per body, their equality elements, and the comments on
    those MuJoCo cannot express (prismatic closures, also warned about)."""
    sites: dict[str | None, list[str]] = {}
    equality, notes = [], []
    for j in system.closures:
        if j.kind == "prismatic":
            note = (f"loop closure '{j.name}' ({j.parent_link} -> {j.child_link}) is prismatic: MuJoCo has no "
                    "equality constraint for a point on a line with the orientation held, so it is not exported")
            notes.append(note)
            warnings.warn(note, stacklevel=3)
            continue
        o_ij, o_ji = np.asarray(j.parent_bvec.orient), np.asarray(j.child_bvec.orient)
        R_align = alignment_matrix(o_ij, o_ji)
        ends = [(j.parent, f"{j.name}_parent", j.parent_bvec.pos, np.eye(3), o_ij),
                (j.child, f"{j.name}_child", j.child_bvec.pos, R_align.T, o_ji)]
        for body, name, pos, R, _ in ends:
            sites.setdefault(body, []).append(_closure_site(system, name, body, pos, R))
        kind = "weld" if j.kind == "fixed" else "connect"
        equality.append(f'    <{kind} name={attr(j.name)} site1={attr(ends[0][1])} site2={attr(ends[1][1])}/>')
        if j.kind == "revolute":
            L = axis_length(system, j)
            for body, name, pos, R, o in ends:
                sites[body].append(_closure_site(system, f"{name}_axis", body, np.asarray(pos) + L * o, R))
            equality.append(f'    <connect name={attr(j.name + "_axis")} site1={attr(ends[0][1] + "_axis")} '
                            f'site2={attr(ends[1][1] + "_axis")}/>')
    return sites, equality, notes


def to_mjcf(system: System, source: str = "", free_root: bool = False,
            rest: Mapping[str, np.ndarray] | None = None) -> str:
    """MJCF text of one system (module docstring); ``source`` is the spec's file name for
    the header comment.  ``free_root``: the joint to the inertial frame is replaced by a
    free joint :data:`~kms2pin.urdf.ROOT_JOINT`.  ``rest``: the keyframe's configuration as
    Pinocchio's coordinates by joint name (:meth:`kms2pin.Robot.joint_blocks`: a model
    with loops, its rest pose closed) instead of the spec's.  A prismatic loop closure is
    left out with a warning (``UserWarning``)."""
    if free_root:
        check_root_joint_name(system)
    sites, equality, notes = _closures(system)
    bodies, qpos = _worldbody(system, free_root, rest, sites)
    head = comment(
        f"generated by kms2pin from {source or 'a spec'}; do not edit. Body frames sit at each body's joint to its "
        "parent; the ellipsoids and the <body>_centre sites at the ellipsoid centres. Inner ellipsoids (group "
        f"{INNER_GROUP}) collide and carry the mass; outer ones (group {OUTER_GROUP}) are drawn only. "
        "+y is up; keyframe 'rest' is the spec's rest pose."
    )
    out = [
        head,
        f"<mujoco model={attr(system.name)}>",
        f'  <compiler angle="radian" autolimits="true" inertiagrouprange="{INNER_GROUP} {INNER_GROUP}"/>',
        f'  <option gravity="{vec(GRAVITY)}"/>',
        "  <default>",
        '    <default class="kms2pin_inner">',
        f'      <geom type="ellipsoid" group="{INNER_GROUP}" density="{num(DENSITY)}" rgba="{vec(INNER_RGBA)}"/>',
        "    </default>",
        '    <default class="kms2pin_outer">',
        f'      <geom type="ellipsoid" group="{OUTER_GROUP}" contype="0" conaffinity="0" rgba="{vec(OUTER_RGBA)}"/>',
        "    </default>",
        "  </default>",
        "  <worldbody>",
        *bodies,
        "  </worldbody>",
    ]
    out += ["  " + comment(note) for note in notes]
    if equality:
        out += ["  <equality>", *equality, "  </equality>"]
    pairs = [j for j in (*system.joints, *system.closures) if j.parent is not None and j.child is not None]
    if pairs:
        out.append("  <contact>")
        out += [f"    <exclude body1={attr(j.parent)} body2={attr(j.child)}/>" for j in pairs]
        out.append("  </contact>")
    rest = f' qpos="{vec(qpos)}"' if qpos else ""
    out += ["  <keyframe>", f'    <key name="rest"{rest}/>', "  </keyframe>", "</mujoco>"]
    return "\n".join(out) + "\n"
