"""Exact ray casting of ellipsoids and capsules, for synthetic silhouettes and depth maps.

Deliberately independent of :mod:`kms2pin.ecm.projection` and
:mod:`kms2pin.ecm.density` (it works with the world-frame quadric and unit
rays from :meth:`Camera.rays`), so that tests can use it as ground truth.
A body is an ellipsoid ``(world_T_body, semi_axes)`` or a :class:`Capsule`
(``kms2pin synth --shape capsule``: a subject whose outline the ellipsoid model
does not have exactly).
Each pixel's ray goes through the pixel centre (integer ``(u, v)``); with a
distorted camera the pixel is undistorted first, so renders match
:meth:`Camera.project`.  Depth is the camera-frame z of the hit (world units).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from kms2pin.ecm._se3 import pose_arrays, semi_axes_array
from kms2pin.ecm.camera import Camera


@dataclass(frozen=True)
class Capsule:
    """The points within ``radius`` of the segment from ``start`` to ``end`` (world frame,
    world units): a cylinder with hemispherical ends."""

    start: np.ndarray
    end: np.ndarray
    radius: float

    @classmethod
    def of_ellipsoid(cls, world_T_body: pin.SE3, semi_axes: Sequence[float] | np.ndarray) -> Capsule:
        """The capsule standing in for an ellipsoid: along its longest semi-axis a (the first
        of equal ones), end to end 2a, radius r the mean of the other two semi-axes (so the
        segment between the ends' centres is a - r to either side of the centre)."""
        L = semi_axes_array(semi_axes)
        R, t = pose_arrays(world_T_body)
        k = int(np.argmax(L))
        r = float(np.delete(L, k).mean())
        half = (L[k] - r) * R[:, k]
        return cls(t - half, t + half, r)


Body = tuple[pin.SE3, Sequence[float] | np.ndarray] | Capsule


def intersect_ellipsoid(
    origin: np.ndarray,
    directions: np.ndarray,
    world_T_body: pin.SE3,
    semi_axes: Sequence[float] | np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameters ``(t_near, t_far)`` (N,) where ``origin + t d`` meets the ellipsoid.

    World frame; ``directions`` (N,3) need not be unit (t is in their units).
    NaN where the line misses.  Both may be negative (the body is behind).
    """
    L = semi_axes_array(semi_axes)
    R, t = pose_arrays(world_T_body)
    A = R @ np.diag(1.0 / L**2) @ R.T  # (x - t)ᵀ A (x - t) = 1 on the surface
    o = np.asarray(origin, dtype=float) - t
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    Ad = d @ A
    qa = np.einsum("ij,ij->i", Ad, d)
    qb = Ad @ o
    qc = o @ A @ o - 1.0
    disc = qb * qb - qa * qc
    with np.errstate(invalid="ignore"):
        r = np.sqrt(disc)
    miss = disc < 0
    t_near = np.where(miss, np.nan, (-qb - r) / qa)
    t_far = np.where(miss, np.nan, (-qb + r) / qa)
    return t_near, t_far


def intersect_capsule(origin: np.ndarray, directions: np.ndarray, capsule: Capsule) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameters ``(t_near, t_far)`` (N,) where ``origin + t d`` meets ``capsule``, as
    :func:`intersect_ellipsoid`.

    The capsule is the union of two balls at the segment's ends and the flat-ended
    cylinder between them, all convex and their union convex, so the line meets it in
    one interval: from the least entry to the greatest exit over the three parts.
    """
    o = np.asarray(origin, dtype=float)
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    p0, p1, r = np.asarray(capsule.start, float), np.asarray(capsule.end, float), float(capsule.radius)
    near, far = np.full(len(d), np.inf), np.full(len(d), -np.inf)
    for centre in (p0, p1):  # |o + t d - c|^2 = r^2
        oc = o - centre
        qa, qb, qc = np.einsum("ij,ij->i", d, d), d @ oc, oc @ oc - r * r
        _take(near, far, qa, qb, np.full(len(d), qc))
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    if length > 0:
        u = axis / length
        oc = o - p0
        dp, op = d - np.outer(d @ u, u), oc - (oc @ u) * u  # parts across the axis
        qa, qb, qc = np.einsum("ij,ij->i", dp, dp), dp @ op, np.full(len(d), op @ op - r * r)
        c_near, c_far = np.full(len(d), np.inf), np.full(len(d), -np.inf)
        _take(c_near, c_far, qa, qb, qc)
        du, ou = d @ u, oc @ u  # the axial coordinate ou + t du within [0, length]
        with np.errstate(divide="ignore", invalid="ignore"):
            s0, s1 = (0.0 - ou) / du, (length - ou) / du
        s_near = np.where(du != 0, np.minimum(s0, s1), np.where((ou >= 0) & (ou <= length), -np.inf, np.inf))
        s_far = np.where(du != 0, np.maximum(s0, s1), np.where((ou >= 0) & (ou <= length), np.inf, -np.inf))
        lo, hi = np.maximum(c_near, s_near), np.minimum(c_far, s_far)
        ok = lo <= hi
        near[ok] = np.minimum(near[ok], lo[ok])
        far[ok] = np.maximum(far[ok], hi[ok])
    miss = ~(near <= far)
    near[miss], far[miss] = np.nan, np.nan
    return near, far


def _take(near: np.ndarray, far: np.ndarray, qa: np.ndarray, qb: np.ndarray, qc: np.ndarray) -> None:
    """Widen ``[near, far]`` by the roots of qa t^2 + 2 qb t + qc = 0 where there are two (in place).
    qa = 0 (a ray along a cylinder's axis): inside for every t if qc <= 0, else never."""
    disc = qb * qb - qa * qc
    with np.errstate(invalid="ignore", divide="ignore"):
        root = np.sqrt(disc)
        t0, t1 = (-qb - root) / qa, (-qb + root) / qa
    flat = qa <= 0
    t0 = np.where(flat, np.where(qc <= 0, -np.inf, np.nan), t0)
    t1 = np.where(flat, np.where(qc <= 0, np.inf, np.nan), t1)
    hit = flat & (qc <= 0) | ~flat & (disc >= 0)
    np.minimum(near, np.where(hit, t0, np.inf), out=near)
    np.maximum(far, np.where(hit, t1, -np.inf), out=far)


def intersect(origin: np.ndarray, directions: np.ndarray, body: Body) -> tuple[np.ndarray, np.ndarray]:
    """``(t_near, t_far)`` of :func:`intersect_ellipsoid` or :func:`intersect_capsule`, by the body's kind."""
    if isinstance(body, Capsule):
        return intersect_capsule(origin, directions, body)
    return intersect_ellipsoid(origin, directions, *body)


def pixel_centres(camera: Camera) -> np.ndarray:
    """(H*W, 2) pixel-centre coordinates ``(u, v)`` in row-major order."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    return np.stack([u.ravel(), v.ravel()], axis=1).astype(float)


def render_labels(camera: Camera, bodies: Sequence[Body]) -> tuple[np.ndarray, np.ndarray]:
    """Label and depth images of bodies: ellipsoids ``(world_T_body, semi_axes)`` or :class:`Capsule` objects.

    Returns ``labels`` (H,W) int32 with the index of the nearest body hit by
    each pixel's ray (-1 for background) and ``depth`` (H,W) float64, the
    camera z of that first hit (``inf`` on background; 0 where the camera is
    inside the body).  Each body's rays are cast only in the image box of its
    world-axis bounding box (:func:`_pixel_box`).
    """
    dirs, centre = camera.rays(pixel_centres(camera))
    z_axis = camera.world_R_camera[:, 2]
    dz = dirs @ z_axis  # depth per unit of t
    n = len(dirs)
    best = np.full(n, np.inf)
    labels = np.full(n, -1, dtype=np.int32)
    grid = np.arange(n).reshape(camera.shape)
    for i, body in enumerate(bodies):
        box = _pixel_box(camera, body)
        if box is None:
            continue
        rows, cols = box
        idx = grid[rows, cols].ravel()
        t_near, t_far = intersect(centre, dirs[idx], body)
        with np.errstate(invalid="ignore"):
            hit = t_far > 0
        t_hit = np.where(hit, np.maximum(t_near, 0.0), np.inf)
        depth = np.where(hit, t_hit * dz[idx], np.inf)
        nearer = depth < best[idx]
        best[idx[nearer]] = depth[nearer]
        labels[idx[nearer]] = i
    shape = camera.shape
    return labels.reshape(shape), best.reshape(shape)


def _world_box(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """The body's bounding box along the world axes: (lowest corner, highest corner)."""
    if isinstance(body, Capsule):
        ends = np.stack([np.asarray(body.start, float), np.asarray(body.end, float)])
        return ends.min(axis=0) - body.radius, ends.max(axis=0) + body.radius
    R, t = pose_arrays(body[0])
    half = np.sqrt(((R * semi_axes_array(body[1])) ** 2).sum(axis=1))  # the support along each world axis
    return t - half, t + half


def _pixel_box(camera: Camera, body: Body) -> tuple[slice, slice] | None:
    """The rows and columns that can see ``body``: the image box of its world bounding
    box's corners, all pixels when a corner is not in front of the camera or the camera
    has lens distortion (a projected box then need not hold the body's image), None when
    the box is off the image."""
    full = (slice(0, camera.height), slice(0, camera.width))
    if camera.dist is not None and np.any(camera.dist):
        return full
    lo, hi = _world_box(body)
    corners = np.array([[a[0], b[1], c[2]] for a in (lo, hi) for b in (lo, hi) for c in (lo, hi)])
    if np.any(camera.depth(corners) <= 0):
        return full
    uv = camera.project(corners)
    u0, v0 = np.floor(uv.min(axis=0)).astype(int)
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int)
    u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, camera.width - 1), min(v1, camera.height - 1)
    if u0 > u1 or v0 > v1:
        return None
    return slice(v0, v1 + 1), slice(u0, u1 + 1)


def render_mask(camera: Camera, bodies: Sequence[Body]) -> np.ndarray:
    """(H,W) bool silhouette: True where any body is hit."""
    return render_labels(camera, bodies)[0] >= 0
