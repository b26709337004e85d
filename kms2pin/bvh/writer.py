"""A model's trajectory as BVH: ``motion.bvh`` of ``kms2pin track`` and ``kms2pin convert``.

Hierarchy: one BVH joint per body, named after it, in the spec's body tree with the root
body as ROOT; each at the body's joint point (its link frame's origin, a_ji: the point of its
joint to its parent, or to the inertial frame for the root).  A leaf body ends in an End Site
at the far end of its inner ellipsoid (its joint point reflected through the centre, or the
end of its longest semi-axis when the joint is at the centre).

Frames: BVH has no rest rotations, so at the model's rest pose every joint's frame has the
world's axes: joint J's frame at q is (p_J(q), R_0J(q) R_0J(q_rest)^T), and its channels
give its rotation relative to its parent's frame.  The OFFSETs are the rest pose's joint
points relative to their parent's; the root's OFFSET is 0 and its position channels are its
joint point (so both readings of a root's position, :mod:`kms2pin.bvh.motion`, agree).
A body on a fixed joint keeps constant (zero) channels.

Channels: the root ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``, every
other joint ``Zrotation Xrotation Yrotation``, i.e. R = Rz(z) Rx(x) Ry(y) in degrees (the
original Biovision order; a singular decomposition only at x = +-90 deg).  Lengths are the
spec's units (metres for the thesis's models) and +y is up, Blender's default reading.

A model with several joints to the inertial frame, or a prismatic joint below the root (BVH
joints turn about a point), cannot be written: :class:`~kms2pin.errors.BvhError`.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import BvhError
from ..robot import Robot

#: The rotation channels of every joint, in file order (R = Rz Rx Ry).
ROTATION_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
#: Indentation stops growing at this depth (a chain of thousands of bodies stays readable).
MAX_INDENT = 32


def _num(x: float) -> str:
    s = f"{x:.10g}"
    return "0" if s == "-0" else s


def check_bvh_model(robot: Robot) -> None:
    """BvhError if ``robot``'s model cannot be written as BVH (module docstring)."""
    anchored = [j.child for j in robot.system.children(None)]
    if len(anchored) != 1:
        raise BvhError(f"'{robot.system.name}' has {len(anchored)} joints to the inertial frame "
                       f"({', '.join(anchored)}); a BVH skeleton has one root")
    sliding = [j.name for j in robot.system.joints if j.kind == "prismatic" and j.parent is not None]
    if sliding:
        raise BvhError(f"'{robot.system.name}' has prismatic joints ({', '.join(sliding)}); BVH joints below "
                       "the root turn about a point and cannot slide")


def _frames(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every body's joint point (n, 3) and rotation R_0J (n, 3, 3) at ``q``."""
    poses = robot.body_poses(q)
    points = np.array([M.act(np.asarray(robot.system.joint_of(b).child_bvec.pos, dtype=float))
                       for b, M in zip(robot.bodies, poses)])
    return points, np.array([M.rotation for M in poses])


def _hierarchy(robot: Robot, rest_points: np.ndarray, rest_R: np.ndarray) -> tuple[list[str], list[int]]:
    """The HIERARCHY lines and the bodies (indices) in the order their channels come."""
    system, index = robot.system, {b: k for k, b in enumerate(robot.bodies)}
    root = system.children(None)[0].child
    lines, order = ["HIERARCHY"], []
    stack: list[tuple[str, int, bool]] = [(root, 0, False)]
    while stack:
        body, depth, closing = stack.pop()
        pad = "\t" * min(depth, MAX_INDENT)
        if closing:
            lines.append(f"{pad}}}")
            continue
        k = index[body]
        parent = system.joint_of(body).parent
        offset = np.zeros(3) if parent is None else rest_points[k] - rest_points[index[parent]]
        channels = ("Xposition", "Yposition", "Zposition", *ROTATION_CHANNELS) if parent is None else ROTATION_CHANNELS
        lines += [f"{pad}{'ROOT' if parent is None else 'JOINT'} {body}", f"{pad}{{",
                  f"{pad}\tOFFSET {' '.join(_num(x) for x in offset)}",
                  f"{pad}\tCHANNELS {len(channels)} {' '.join(channels)}"]
        order.append(k)
        kids = [j.child for j in system.children(body)]
        stack.append((body, depth, True))
        if not kids:
            lines += [f"{pad}\tEnd Site", f"{pad}\t{{",
                      f"{pad}\t\tOFFSET {' '.join(_num(x) for x in _end(robot, body, rest_R[k]))}", f"{pad}\t}}"]
        stack.extend((kid, depth + 1, False) for kid in reversed(kids))
    return lines, order


def _end(robot: Robot, body: str, R: np.ndarray) -> np.ndarray:
    """A leaf body's End Site relative to its joint point (world axes at rest)."""
    a_ji = np.asarray(robot.system.joint_of(body).child_bvec.pos, dtype=float)
    inner = robot.inner(body)
    if np.linalg.norm(a_ji) > 1e-9 * inner.max():
        return R @ (-2.0 * a_ji)
    k = int(np.argmax(inner))
    return R[:, k] * inner[k]


def to_bvh(robot: Robot, q: np.ndarray, fps: float) -> str:
    """BVH text of ``robot`` moving through the configurations ``q`` (frames, nq) at ``fps``
    frames per second (module docstring)."""
    check_bvh_model(robot)
    q = np.asarray(q, dtype=float).reshape(-1, robot.nq)
    rest_points, rest_R = _frames(robot, robot.q_rest)
    lines, order = _hierarchy(robot, rest_points, rest_R)
    parents = [robot.system.joint_of(b).parent for b in robot.bodies]
    parent_index = [None if p is None else robot.bodies.index(p) for p in parents]
    lines += ["MOTION", f"Frames: {len(q)}", f"Frame Time: {_num(1.0 / fps)}"]
    for qk in q:
        points, R = _frames(robot, qk)
        G = R @ np.transpose(rest_R, (0, 2, 1))  # each BVH joint's frame: the world's axes at rest
        local = np.array([G[k] if p is None else G[p].T @ G[k] for k, p in enumerate(parent_index)])[order]
        with warnings.catch_warnings():  # at x = +-90 deg scipy notes the gimbal lock it resolves
            warnings.simplefilter("ignore", UserWarning)
            angles = Rotation.from_matrix(local).as_euler("ZXY", degrees=True)
        root = points[order[0]]
        lines.append(" ".join(_num(x) for x in (*root, *angles.ravel())))
    return "\n".join(lines) + "\n"
