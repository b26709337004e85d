"""Drawing a compiled robot in meshcat: ellipsoids, joint axes, anchor, axes, camera.

Frames.  The thesis models have world +y up (and the thesis camera looks along
+z from the world origin).  meshcat's world is +z up: its three.js scene root is
rotated by -90 deg about x, and its default camera sits under
``/Cameras/default/rotated`` (rotated by +90 deg about x) so that the camera's
own coordinates are three.js's y-up coordinates.  Everything kms2pin draws lives
under ``/meshcat/kms2pin``, whose transform is ``Rx(+90 deg) @ T(-c)``: it turns
the thesis's y-up world into meshcat's z-up world and moves the point ``c`` (the
centre of the framed model) to the origin.  The two rotations cancel, so the
camera position and the OrbitControls "up" (three.js +y) are simply thesis world
coordinates relative to ``c``, and thesis +y is up on the screen.

Views (:data:`VIEWS`): ``front`` looks along the thesis camera's +z with +y up
(a right-handed picture, so world +x points to the *left* of the screen);
``side`` looks along -x (+z to the left, the models' -z front to the right);
``top`` looks down along -y with +z up on the screen (the front, -z, at the
bottom; +x to the left as in ``front``); ``iso`` looks from the front, from the
-x side and from above.  The camera is a 30 deg perspective camera placed so
the outer ellipsoids fill about 90 % of the frame for the given aspect ratio.

Scene paths (relative to ``/meshcat/kms2pin``): ``<name>/bodies/<body>`` is the
body frame (ellipsoid centre, body axes; set by ``set_transform`` only when the
pose changes) with ``inner``, ``outer`` and ``axis_<joint>`` (the axis of each
revolute or prismatic joint whose parent is this body, at the joint point) below it;
``<name>/world/axis_<root joint>`` and ``<name>/world/anchor`` are the root
joint's axis and the inertial anchor; ``world_axes`` is the world-axes triad
(x red, y green, z blue), drawn at the inertial anchor with world orientation
so that it stays in the picture (the thesis models sit metres from the world
origin).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import meshcat
import meshcat.geometry as g
import numpy as np
import pinocchio as pin

from ..model import Joint
from ..robot import Robot
from ..urdf import INNER_RGBA, OUTER_RGBA
from .errors import ViewerError

ROOT = "kms2pin"
FOV_DEG = 30.0
FILL = 0.9
VIEWS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    # name: (direction from the framed centre to the camera, screen-up direction)
    "front": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "side": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "top": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "iso": ((-1.0, 0.8, -1.2), (0.0, 1.0, 0.0)),
}
TOP_TILT = 1e-3  # OrbitControls cannot look exactly along its up axis

AXIS_RGBA = (0.12, 0.12, 0.12, 1.0)
ANCHOR_RGBA = (0.05, 0.05, 0.05, 1.0)
WORLD_AXES_RGBA = ((0.85, 0.1, 0.1, 1.0), (0.1, 0.65, 0.1, 1.0), (0.1, 0.2, 0.9, 1.0))
INTERMEDIATE_RGBA = (0.97, 0.80, 0.62, 0.75)  # a lighter shade of the inner colour
SPRING_RGBA = (0.9, 0.0, 0.0, 1.0)

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # Rx(+90 deg)


def hex_colour(rgba: Sequence[float]) -> int:
    r, gr, b = (int(round(255 * min(max(c, 0.0), 1.0))) for c in rgba[:3])
    return (r << 16) | (gr << 8) | b


def material(rgba: Sequence[float], on_top: bool = False) -> g.MeshLambertMaterial:
    """A Lambert material; translucent colours do not write depth (no sorting holes);
    ``on_top`` draws it over everything else (used for the spring arrows)."""
    opacity = float(rgba[3]) if len(rgba) > 3 else 1.0
    extra = {}
    if opacity < 1.0:
        extra["depthWrite"] = False
    if on_top:
        extra["depthTest"] = False
        extra["depthWrite"] = False
    return g.MeshLambertMaterial(
        color=hex_colour(rgba), opacity=opacity, transparent=opacity < 1.0 or on_top, **extra
    )


class OnTopMesh(g.Mesh):
    """A mesh drawn after everything else (three.js ``renderOrder``); with a
    ``material(..., on_top=True)`` it shows through other bodies."""

    RENDER_ORDER = 10

    def lower(self) -> dict[str, Any]:
        data = super().lower()
        data["object"]["renderOrder"] = self.RENDER_ORDER
        return data


def mesh(geometry: g.Geometry, rgba: Sequence[float], on_top: bool = False) -> g.Mesh:
    """A meshcat object: ``geometry`` with :func:`material` ``rgba``."""
    return (OnTopMesh if on_top else g.Mesh)(geometry, material(rgba, on_top))


def homogeneous(M: pin.SE3 | np.ndarray) -> np.ndarray:
    return np.asarray(M.homogeneous if isinstance(M, pin.SE3) else M, dtype=float)


def rotation_y_to(direction: Sequence[float]) -> np.ndarray:
    """A rotation taking +y (three.js's cylinder axis) to ``direction``."""
    d = np.asarray(direction, dtype=float)
    n = np.linalg.norm(d)
    if not np.isfinite(n) or n == 0:
        raise ViewerError(f"cannot draw an arrow along {tuple(d)}")
    d = d / n
    y = np.array([0.0, 1.0, 0.0])
    c = float(y @ d)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    return pin.Quaternion.FromTwoVectors(y, d).matrix()


def set_arrow(vis: meshcat.Visualizer, start: np.ndarray | Sequence[float], end: np.ndarray | Sequence[float],
              radius: float, rgba: Sequence[float], head: float = 3.0,
              on_top: bool = False) -> bool:
    """Draw an arrow (cylinder + cone) from ``start`` to ``end`` under ``vis``'s path,
    as the objects ``shaft`` and ``head``.  Returns False (nothing drawn) for a
    zero-length arrow."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    v = end - start
    length = float(np.linalg.norm(v))
    if length < 1e-12:
        vis.delete()
        return False
    head_len = min(head * 2.0 * radius, 0.5 * length)
    head_radius = head_len / 2.0  # a short arrow gets a proportionally small head
    shaft_len = length - head_len
    M = np.eye(4)
    M[:3, :3] = rotation_y_to(v)
    M[:3, 3] = start
    vis.set_transform(M)
    shaft = vis["shaft"]
    shaft.set_object(mesh(g.Cylinder(shaft_len, min(radius, 0.6 * head_radius)), rgba, on_top))
    shaft.set_transform(_translation((0.0, shaft_len / 2, 0.0)))
    tip = vis["head"]
    tip.set_object(mesh(g.Cylinder(head_len, radiusTop=0.0, radiusBottom=head_radius), rgba, on_top))
    tip.set_transform(_translation((0.0, shaft_len + head_len / 2, 0.0)))
    return True


def _translation(p) -> np.ndarray:
    M = np.eye(4)
    M[:3, 3] = p
    return M


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = math.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


_SPHERE = np.vstack([_fibonacci_sphere(64), np.eye(3), -np.eye(3)])


def ellipsoid_points(M: pin.SE3, radii: Sequence[float]) -> np.ndarray:
    """Points on an ellipsoid (for framing): (70, 3) in the world."""
    return (M.rotation @ (_SPHERE * np.asarray(radii)).T).T + M.translation


def extent_along(M: pin.SE3, radii: Sequence[float], direction: Sequence[float]) -> tuple[float, float]:
    """(min, max) of ``direction . x`` over the ellipsoid (exact support function)."""
    e = np.asarray(direction, float)
    h = float(np.linalg.norm(np.asarray(radii) * (M.rotation.T @ e)))
    c = float(e @ M.translation)
    return c - h, c + h


def projected_box(robot: Robot, q: np.ndarray, right: np.ndarray | Sequence[float], up: np.ndarray | Sequence[float],
                  which: str = "inner") -> tuple[float, float, float, float]:
    """Orthographic bounding box (right_min, right_max, up_min, up_max) of the robot's
    inner (or outer) ellipsoids at ``q`` along two view directions."""
    lo_r = lo_u = np.inf
    hi_r = hi_u = -np.inf
    for name, M in zip(robot.bodies, robot.body_poses(q)):
        radii = robot.inner(name) if which == "inner" else robot.outer(name)
        a, b = extent_along(M, radii, right)
        c, d = extent_along(M, radii, up)
        lo_r, hi_r, lo_u, hi_u = min(lo_r, a), max(hi_r, b), min(lo_u, c), max(hi_u, d)
    return lo_r, hi_r, lo_u, hi_u


@dataclass(frozen=True)
class CameraSetup:
    """Where :func:`frame_camera` put the camera (thesis world coordinates)."""

    view: str
    centre: np.ndarray  # framed centre (moved to meshcat's origin)
    position: np.ndarray  # camera position
    right: np.ndarray  # screen right
    up: np.ndarray  # screen up
    forward: np.ndarray  # viewing direction
    distance: float
    fov_deg: float
    aspect: float


def view_basis(view: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) unit vectors of a named view, in thesis world coordinates."""
    if view not in VIEWS:
        from ..errors import did_you_mean

        raise ViewerError(f"unknown camera view {view!r}{did_you_mean(view, VIEWS)}; "
                          f"choose one of {', '.join(VIEWS)}")
    to_camera, up_hint = (np.asarray(v, float) for v in VIEWS[view])
    forward = -to_camera / np.linalg.norm(to_camera)
    right = np.cross(forward, up_hint)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return right, up, forward


def frame_camera(vis: meshcat.Visualizer, view: str, points: np.ndarray, aspect: float = 1.0,
                 fill: float = FILL, fov_deg: float = FOV_DEG, set_lens: bool = True) -> CameraSetup:
    """Point meshcat's camera at ``points`` (thesis world coordinates, (N, 3)) from a
    named view so that they fill ``fill`` of a ``aspect`` = width/height frame.

    Sets the ``/meshcat/kms2pin`` transform (y-up -> z-up, centre to origin) and
    replaces the default camera by a ``fov_deg`` perspective camera (with
    ``set_lens=False`` only the camera position is sent: a live viewer then keeps
    its camera object and mouse controls).
    """
    points = np.asarray(points, float).reshape(-1, 3)
    if not len(points) or not np.all(np.isfinite(points)):
        raise ViewerError("nothing finite to frame")
    if not (aspect > 0 and math.isfinite(aspect)):
        raise ViewerError(f"aspect must be positive, not {aspect}")
    right, up, forward = view_basis(view)
    B = np.stack([right, up, forward])  # world -> camera-aligned coordinates
    local = points @ B.T
    lo, hi = local.min(axis=0), local.max(axis=0)
    centre = B.T @ ((lo + hi) / 2)
    rel = (points - centre) @ B.T
    tv = math.tan(math.radians(fov_deg) / 2)
    th = tv * aspect
    need = np.maximum(np.abs(rel[:, 0]) / (fill * th), np.abs(rel[:, 1]) / (fill * tv)) - rel[:, 2]
    size = float(np.max(hi - lo)) or 1.0
    distance = float(max(need.max(), (-rel[:, 2]).max() + 0.05 * size, 1e-6))
    position = -forward * distance
    if view == "top":
        position = position - up * TOP_TILT * distance
    root = Y_UP_TO_Z_UP @ _translation(-centre)
    vis[ROOT].set_transform(root)
    if set_lens:
        cam = g.PerspectiveCamera(fov=fov_deg, aspect=aspect, near=0.01 * distance, far=100 * distance + 10 * size)
        vis["/Cameras/default/rotated"].set_object(cam)
    vis["/Cameras/default/rotated/<object>"].set_property("position", [float(x) for x in position])
    return CameraSetup(view, centre, centre + position, right, up, forward, distance, fov_deg, aspect)


def plain_background(vis: meshcat.Visualizer) -> None:
    """White page background: no sky gradient, no grid, no meshcat axes."""
    vis["/Background"].set_property("top_color", [1.0, 1.0, 1.0])
    vis["/Background"].set_property("bottom_color", [1.0, 1.0, 1.0])
    vis["/Background"].set_property("visible", False)
    vis["/Grid"].set_property("visible", False)
    vis["/Axes"].set_property("visible", False)


def model_size(robot: Robot, q: np.ndarray | None = None) -> float:
    """Largest side of the outer ellipsoids' bounding box (for arrow sizes)."""
    q = robot.q_rest if q is None else q
    pts = np.vstack([ellipsoid_points(M, robot.outer(n)) for n, M in zip(robot.bodies, robot.body_poses(q))])
    return float(np.max(pts.max(axis=0) - pts.min(axis=0))) or 1.0


def body_scales(robot: Robot, scales) -> np.ndarray:
    """``scales`` checked as (n_bodies, 3) positive finite factors of ``robot``'s body sizes
    (None: ones, the spec's sizes); a :class:`ViewerError` otherwise."""
    n = len(robot.bodies)
    if scales is None:
        return np.ones((n, 3))
    try:
        sc = np.array(scales, dtype=float)
    except (TypeError, ValueError):
        raise ViewerError(f"scales must be numbers, (n_bodies, 3) = ({n}, 3)") from None
    if sc.shape != (n, 3) or not np.all(np.isfinite(sc)) or not np.all(sc > 0):
        raise ViewerError(f"scales must be positive, finite and of shape ({n}, 3) (one factor per body and "
                          f"semi-axis), not shape {sc.shape}")
    return sc


class ModelDrawing:
    """One robot drawn under ``/meshcat/kms2pin/<name>``.

    Geometry is uploaded once by :meth:`draw`; :meth:`set_configuration` only
    sends one ``set_transform`` per body (recorded in :attr:`transform_log` as
    ``(path, 4x4 matrix)``).  ``offset`` shifts the whole drawing (thesis world
    coordinates), e.g. to put two poses side by side.  ``scales`` (n_bodies, 3) multiply
    each body's inner and outer semi-axes (a tracker's measured sizes,
    :attr:`~kms2pin.ecm.tracker.Tracker.scales`; default the spec's).
    """

    def __init__(self, robot: Robot, vis: meshcat.Visualizer, name: str = "model", *,
                 inner_rgba=INNER_RGBA, outer_rgba=OUTER_RGBA, outer: bool = True,
                 joint_axes: bool = True, anchor: bool = True, offset=(0.0, 0.0, 0.0),
                 size: float | None = None, scales: np.ndarray | None = None):
        self.robot = robot
        self.scales = body_scales(robot, scales)
        self.vis = vis
        self.name = name
        self.inner_rgba = tuple(inner_rgba)
        self.outer_rgba = tuple(outer_rgba)
        self.outer = outer
        self.joint_axes = joint_axes
        self.anchor = anchor and robot.root == "spec"
        self.offset = np.asarray(offset, dtype=float)
        self.size = model_size(robot) if size is None else float(size)
        self.transform_log: list[tuple[str, np.ndarray]] = []
        self.q: np.ndarray | None = None

    # ---------------------------------------------------------------- paths
    @property
    def path(self) -> str:
        return f"{ROOT}/{self.name}"

    def body_path(self, body: str) -> str:
        return f"{self.path}/bodies/{body}"

    @property
    def axis_radius(self) -> float:
        return 0.006 * self.size

    @property
    def axis_length(self) -> float:
        return 0.12 * self.size

    def semi_axes(self, body: str, kind: str) -> np.ndarray:
        """``body``'s ``kind`` ("inner" or "outer") semi-axes as drawn (the spec's times :attr:`scales`)."""
        spec = self.robot.inner(body) if kind == "inner" else self.robot.outer(body)
        return np.asarray(spec, dtype=float) * self.scales[self.robot.bodies.index(body)]

    def root_joint(self) -> Joint | None:
        return self.robot.system.joints[0] if self.robot.system.joints[0].parent is None else None

    def anchor_point(self) -> np.ndarray:
        j = self.root_joint()
        return np.asarray(j.parent_bvec.pos, float) + self.offset

    # ---------------------------------------------------------------- drawing
    def draw(self, q: np.ndarray | None = None) -> ModelDrawing:
        """Upload the geometry and pose it at ``q`` (default: rest)."""
        robot, vis = self.robot, self.vis
        inner_mat = material(self.inner_rgba)
        outer_mat = material(self.outer_rgba)
        for body in robot.bodies:
            node = vis[self.body_path(body)]
            node["inner"].set_object(g.Ellipsoid(self.semi_axes(body, "inner").tolist()), inner_mat)
            if self.outer:
                node["outer"].set_object(g.Ellipsoid(self.semi_axes(body, "outer").tolist()), outer_mat)
        if self.joint_axes:
            for j in robot.system.joints:
                if j.kind not in ("revolute", "prismatic"):  # a hinge's axis or a slide's direction
                    continue
                if j.parent is None:
                    if robot.root != "spec":
                        continue
                    node = vis[f"{self.path}/world/axis_{j.name}"]
                    origin = np.asarray(j.parent_bvec.pos) + self.offset
                else:
                    node = vis[f"{self.body_path(j.parent)}/axis_{j.name}"]
                    origin = np.asarray(j.parent_bvec.pos)
                a = np.asarray(j.parent_bvec.orient, float)
                a = a / np.linalg.norm(a)
                half = self.axis_length / 2
                set_arrow(node, origin - half * a, origin + half * a, self.axis_radius, AXIS_RGBA)
        if self.anchor:
            node = vis[f"{self.path}/world/anchor"]
            node.set_object(mesh(g.Sphere(2.5 * self.axis_radius), ANCHOR_RGBA, on_top=True))
            node.set_transform(_translation(self.anchor_point()))
        self.set_configuration(robot.q_rest if q is None else q)
        return self

    def transforms(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """``set_transform`` matrices per body path at ``q`` (offset included)."""
        out = {}
        for body, M in zip(self.robot.bodies, self.robot.body_poses(q)):
            T = homogeneous(M).copy()
            T[:3, 3] += self.offset
            out[self.body_path(body)] = T
        return out

    def set_configuration(self, q: np.ndarray) -> None:
        """Move every body to ``q`` (one ``set_transform`` per body, no geometry)."""
        q = np.array(q, dtype=float)
        for path, T in self.transforms(q).items():
            self.vis[path].set_transform(T)
            self.transform_log.append((path, T))
        self.q = q

    def frame_points(self, q: np.ndarray | None = None) -> np.ndarray:
        """Points to frame: the outer (or inner) ellipsoids, axes and anchor at ``q``."""
        q = self.q if q is None else q
        pts = [ellipsoid_points(M, self.semi_axes(n, "outer" if self.outer else "inner")) + self.offset
               for n, M in zip(self.robot.bodies, self.robot.body_poses(q))]
        if self.anchor:
            pts.append(self.anchor_point()[None])
        return np.vstack(pts)

    def delete(self) -> None:
        self.vis[self.path].delete()


def draw_world_axes(vis: meshcat.Visualizer, origin: np.ndarray | Sequence[float], length: float, radius: float) -> None:
    """Three arrows along world x (red), y (green), z (blue) from ``origin``."""
    origin = np.asarray(origin, float)
    for k, rgba in enumerate(WORLD_AXES_RGBA):
        e = np.zeros(3)
        e[k] = length
        set_arrow(vis[f"{ROOT}/world_axes/{'xyz'[k]}"], origin, origin + e, radius, rgba)


def draw_springs(vis: meshcat.Visualizer, path: str, starts: dict[str, np.ndarray],
                 ends: dict[str, np.ndarray], radius: float, rgba: Sequence[float] = SPRING_RGBA) -> list[str]:
    """Red arrows ``starts[b] -> ends[b]`` for every body in ``ends``; returns their paths
    (bodies whose two points coincide get no arrow)."""
    drawn = []
    vis[path].delete()
    for body, end in ends.items():
        p = f"{path}/{body}"
        if set_arrow(vis[p], starts[body], end, radius, rgba, on_top=True):
            drawn.append(p)
    return drawn


def union_points(parts: Iterable[np.ndarray]) -> np.ndarray:
    return np.vstack([np.asarray(p, float).reshape(-1, 3) for p in parts])
