"""Exact ray casting of ellipsoids, for synthetic silhouettes and depth maps.

Deliberately independent of :mod:`kms2pin.ecm.projection` and
:mod:`kms2pin.ecm.density` (it works with the world-frame quadric and unit
rays from :meth:`Camera.rays`), so that tests can use it as ground truth.
Each pixel's ray goes through the pixel centre (integer ``(u, v)``); with a
distorted camera the pixel is undistorted first, so renders match
:meth:`Camera.project`.  Depth is the camera-frame z of the hit (world units).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from kms2pin.ecm._se3 import pose_arrays, semi_axes_array
from kms2pin.ecm.camera import Camera

Body = tuple[pin.SE3, Sequence[float] | np.ndarray]


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


def pixel_centres(camera: Camera) -> np.ndarray:
    """(H*W, 2) pixel-centre coordinates ``(u, v)`` in row-major order."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    return np.stack([u.ravel(), v.ravel()], axis=1).astype(float)


def render_labels(camera: Camera, bodies: Sequence[Body]) -> tuple[np.ndarray, np.ndarray]:
    """Label and depth images of ellipsoids ``(world_T_body, semi_axes)``.

    Returns ``labels`` (H,W) int32 with the index of the nearest body hit by
    each pixel's ray (-1 for background) and ``depth`` (H,W) float64, the
    camera z of that first hit (``inf`` on background; 0 where the camera is
    inside the body).
    """
    dirs, centre = camera.rays(pixel_centres(camera))
    z_axis = camera.world_R_camera[:, 2]
    dz = dirs @ z_axis  # depth per unit of t
    n = len(dirs)
    best = np.full(n, np.inf)
    labels = np.full(n, -1, dtype=np.int32)
    for i, (pose, axes) in enumerate(bodies):
        t_near, t_far = intersect_ellipsoid(centre, dirs, pose, axes)
        with np.errstate(invalid="ignore"):
            hit = t_far > 0
        t_hit = np.where(hit, np.maximum(t_near, 0.0), np.inf)
        depth = np.where(hit, t_hit * dz, np.inf)
        nearer = depth < best
        best[nearer] = depth[nearer]
        labels[nearer] = i
    shape = camera.shape
    return labels.reshape(shape), best.reshape(shape)


def render_mask(camera: Camera, bodies: Sequence[Body]) -> np.ndarray:
    """(H,W) bool silhouette: True where any ellipsoid is hit."""
    return render_labels(camera, bodies)[0] >= 0
