"""Static-update pictures (thesis figures 4.1, 4.2, 4.4, 4.5, 4.8, 4.9, 4.12).

"The intermediate bodies are drawn in a slightly lighter shade ... with red
arrows connecting the means of the primary and intermediate bodies.  The arrows
represent the linear spring forces acting on the bodies" (§4.1.1).  The left
picture is before the static update (primary bodies at ``q_before``), the right
one after it (primary bodies at ``result.q``); both show the same intermediate
bodies (the targets).  Torsional springs are not drawn, as in the thesis.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import meshcat
import meshcat.geometry as g
import numpy as np
import pinocchio as pin
from meshcat.animation import Animation

from ..errors import TargetError
from ..robot import Robot
from ..virtual_work import StaticUpdateResult
from .robot_view import new_visualizer
from .scene import (
    INTERMEDIATE_RGBA,
    ROOT,
    SPRING_RGBA,
    CameraSetup,
    ModelDrawing,
    frame_camera,
    material,
    mesh,
    model_size,
    plain_background,
    set_arrow,
    union_points,
    view_basis,
)

LAYOUTS = ("side-by-side", "animation")


def target_poses(robot: Robot, targets: np.ndarray | Mapping[str, pin.SE3 | np.ndarray]) -> dict[str, pin.SE3]:
    """Targets as ``{body: world_T_body}``: from a dict of SE3 / 7-vectors / 4x4, or an
    ``(n_bodies, 7)`` array of maximal coordinates ``[mu, theta0..theta3]``
    (Euler parameters scalar first, normalised here)."""
    if isinstance(targets, Mapping):
        out = {}
        for name, M in targets.items():
            robot.index(name)  # RobotError with "did you mean" for an unknown body
            if isinstance(M, pin.SE3):
                T = pin.SE3(M)
            else:
                A = np.asarray(M, dtype=float)
                if A.shape == (7,):
                    T = _pose_from_row(A, f"target of body '{name}'")
                elif A.shape == (4, 4) and np.all(np.isfinite(A)):
                    T = pin.SE3(A)
                else:
                    raise TargetError(f"target of body '{name}' must be a pin.SE3, 7 numbers "
                                      "[mu, theta0..theta3] or a finite 4x4 matrix")
            if not (np.all(np.isfinite(T.homogeneous))):
                raise TargetError(f"target of body '{name}' is not finite")
            out[name] = T
        return out
    A = np.asarray(targets, dtype=float)
    if A.shape != (len(robot.bodies), 7):
        raise TargetError(f"targets must be a dict or have shape ({len(robot.bodies)}, 7), not {A.shape}")
    return {name: _pose_from_row(A[i], f"target of body '{name}' (row {i})") for i, name in enumerate(robot.bodies)}


def _pose_from_row(row: np.ndarray, what: str) -> pin.SE3:
    if not np.all(np.isfinite(row)):
        raise TargetError(f"{what} is not finite")
    e = row[3:]
    n = np.linalg.norm(e)
    if n < 1e-9:
        raise TargetError(f"{what} has zero Euler parameters")
    e = e / n
    return pin.SE3(pin.Quaternion(e[0], e[1], e[2], e[3]).toRotationMatrix(), row[:3].copy())


@dataclass
class StaticUpdateDrawing:
    """What :func:`draw_static_update` put in the scene."""

    vis: meshcat.Visualizer
    primaries: dict[str, ModelDrawing]  # "before", "after"
    springs: dict[str, list[str]] = field(default_factory=dict)  # side -> arrow paths, one per sprung body
    intermediate_paths: dict[str, list[str]] = field(default_factory=dict)
    offsets: dict[str, np.ndarray] = field(default_factory=dict)
    camera: CameraSetup | None = None


def _draw_intermediate(vis, path: str, robot: Robot, poses: dict[str, pin.SE3], offset) -> list[str]:
    mat = material(INTERMEDIATE_RGBA)
    # pushed back in depth: where an intermediate body (nearly) coincides with its
    # primary body the primary wins cleanly instead of a z-fighting speckle
    mat.properties.update(polygonOffset=True, polygonOffsetFactor=2.0, polygonOffsetUnits=8.0)
    paths = []
    for name, M in poses.items():
        p = f"{path}/{name}"
        node = vis[p]
        node.set_object(g.Ellipsoid(robot.inner(name).tolist()), mat)
        T = M.homogeneous.copy()
        T[:3, 3] += offset
        node.set_transform(T)
        paths.append(p)
    return paths


def _draw_springs(vis, path: str, starts: dict[str, np.ndarray], ends: dict[str, np.ndarray],
                  radius: float) -> list[str]:
    """One red arrow per sprung body; a red dot where the spring has zero length."""
    paths = []
    for name, end in ends.items():
        p = f"{path}/{name}"
        if not set_arrow(vis[p], starts[name], end, radius, SPRING_RGBA, on_top=True):
            vis[p]["dot"].set_object(mesh(g.Sphere(2.0 * radius), SPRING_RGBA, on_top=True))
            M = np.eye(4)
            M[:3, 3] = end
            vis[p].set_transform(M)
        paths.append(p)
    return paths


def draw_static_update(robot: Robot, q_before: np.ndarray,
                       targets: np.ndarray | Mapping[str, pin.SE3 | np.ndarray],
                       result: StaticUpdateResult | np.ndarray, vis: meshcat.Visualizer | None = None, *,
                       camera: str = "front", layout: str = "side-by-side", aspect: float = 2.0,
                       joint_axes: bool = False) -> StaticUpdateDrawing:
    """Draw a static update (see the module docstring); returns what was drawn.

    ``result`` is a ``StaticUpdateResult`` (only ``.q`` is used) or a bare
    configuration.  ``layout="side-by-side"`` shifts "before" left and "after"
    right on the screen of ``camera``; ``"animation"`` draws both in place and
    plays a two-frame (1 frame/s, looping) animation toggling between them.
    """
    if layout not in LAYOUTS:
        raise TargetError(f"layout must be one of {LAYOUTS}, not {layout!r}")
    q_before = robot._check_q(q_before)
    q_after = robot._check_q(getattr(result, "q", result))
    poses = target_poses(robot, targets)
    if vis is None:
        vis = new_visualizer(serve=False)
    plain_background(vis)
    size = model_size(robot)
    radius = 0.009 * size
    right, _, _ = view_basis(camera)

    def group_points(q, offset) -> np.ndarray:
        tmp = ModelDrawing(robot, vis, size=size, offset=offset, anchor=False)
        pts = [tmp.frame_points(q)]
        pts += [(M.rotation @ (np.asarray(robot.inner(n)) * np.vstack([np.eye(3), -np.eye(3)])).T).T
                + M.translation + offset for n, M in poses.items()]
        return union_points(pts)

    zero = np.zeros(3)
    offsets = {"before": zero, "after": zero}
    if layout == "side-by-side":
        pb, pa = group_points(q_before, zero) @ right, group_points(q_after, zero) @ right
        gap = 0.12 * size
        shift = float(pb.max() - pa.min() + gap)
        offsets = {"before": -0.5 * shift * right, "after": 0.5 * shift * right}
    drawing = StaticUpdateDrawing(vis, {}, offsets=offsets)
    for side, q in (("before", q_before), ("after", q_after)):
        off = offsets[side]
        prim = ModelDrawing(robot, vis, f"static_update/{side}/primary", joint_axes=joint_axes, anchor=False,
                            offset=off, size=size).draw(q)
        drawing.primaries[side] = prim
        if layout == "side-by-side" or side == "before":
            drawing.intermediate_paths[side] = _draw_intermediate(
                vis, f"{ROOT}/static_update/{side}/intermediate", robot, poses, off)
        centres = {n: M.translation + off for n, M in zip(robot.bodies, robot.body_poses(q))}
        ends = {n: M.translation + off for n, M in poses.items()}
        drawing.springs[side] = _draw_springs(vis, f"{ROOT}/static_update/{side}/springs", centres, ends, radius)
    pts = union_points([group_points(q_before, offsets["before"]), group_points(q_after, offsets["after"])])
    drawing.camera = frame_camera(vis, camera, pts, aspect)
    if layout == "animation":
        anim = Animation(default_framerate=1)
        for frame, shown in ((0, "before"), (1, "after"), (2, "after")):
            with anim.at_frame(vis, frame) as f:
                for side in ("before", "after"):
                    for part in ("primary", "springs"):
                        f[f"{ROOT}/static_update/{side}/{part}"].set_property("visible", "bool", side == shown)
        vis.set_animation(anim, play=True, repetitions=1_000_000)
    return drawing


def show_static_update(robot: Robot, q_before: np.ndarray,
                       targets: np.ndarray | Mapping[str, pin.SE3 | np.ndarray],
                       result: StaticUpdateResult | np.ndarray, vis: meshcat.Visualizer | None = None, *,
                       camera: str = "front", layout: str = "side-by-side", aspect: float = 2.0,
                       joint_axes: bool = False) -> meshcat.Visualizer:
    """Draw a static update like the thesis figures and return the Visualizer.

    Primary bodies before (left) and after (right) the update, the intermediate
    bodies (``targets``: ``(n_bodies, 7)`` maximal coordinates or ``{body: SE3}``)
    in a lighter colour, and one red arrow per sprung body from its primary
    centre to its intermediate centre.  Without ``vis`` the scene is recorded
    without a server; write it with :func:`kms2pin.viewer.save_html` /
    :func:`kms2pin.viewer.save_png`.
    """
    return draw_static_update(robot, q_before, targets, result, vis, camera=camera, layout=layout,
                              aspect=aspect, joint_axes=joint_axes).vis
