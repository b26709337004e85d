"""Exact images of ellipsoids: conics, ellipse parameters and bounding boxes.

An ellipsoid is ``world_T_body`` (a ``pin.SE3``: centre and axes in the world)
plus three semi-axes along the body's x, y, z (world units).  Its dual quadric
``Q* = T diag(L1², L2², L3², -1) Tᵀ`` projects to the dual conic
``C* = P Q* Pᵀ``; the silhouette conic is ``C ∝ (C*)⁻¹``.  Conics are in ideal
(undistorted) pixel coordinates ``(u, v, 1)`` of ``camera.P``: with a distorted
camera, test :meth:`Camera.undistort_pixels` of observed pixels.

The image is an ellipse only when the whole ellipsoid is in front of the
camera; :func:`ellipsoid_visibility` tells, and :func:`ellipsoid_conic` raises
:class:`ProjectionError` otherwise (a straddling ellipsoid projects to a
hyperbola whose "inside" mixes rays that hit the body behind the camera).
"""

from __future__ import annotations

import enum
import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pinocchio as pin

from kms2pin.ecm._se3 import pose_arrays, semi_axes_array
from kms2pin.ecm.camera import Camera


class ProjectionError(ValueError):
    """The image of an ellipsoid is not a bounded ellipse (camera inside, or body behind)."""


class Visibility(enum.Enum):
    """Where an ellipsoid is relative to a camera."""

    FRONT = "front"  # entirely in front of the camera plane: the image is an ellipse
    BEHIND = "behind"  # entirely behind the camera plane: invisible
    STRADDLES = "straddles"  # crosses the camera plane: unbounded image, not an ellipse
    CONTAINS_CAMERA = "contains camera"  # the camera centre is inside: every ray hits it


@dataclass(frozen=True)
class BBox:
    """Half-open pixel box: columns ``u0 <= u < u1``, rows ``v0 <= v < v1``."""

    u0: int
    v0: int
    u1: int
    v1: int

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the region."""
        return (max(self.v1 - self.v0, 0), max(self.u1 - self.u0, 0))

    @property
    def slices(self) -> tuple[slice, slice]:
        """Index an (H, W) image with ``image[bbox.slices]``."""
        return (slice(self.v0, self.v1), slice(self.u0, self.u1))

    @property
    def empty(self) -> bool:
        return self.u1 <= self.u0 or self.v1 <= self.v0

    def intersect(self, other: BBox) -> BBox | None:
        """The common region, or None when the boxes do not overlap."""
        b = BBox(
            max(self.u0, other.u0),
            max(self.v0, other.v0),
            min(self.u1, other.u1),
            min(self.v1, other.v1),
        )
        return None if b.empty else b

    @staticmethod
    def full(camera: Camera) -> BBox:
        """The whole image of ``camera``."""
        return BBox(0, 0, camera.width, camera.height)


class Ellipse(NamedTuple):
    """An image ellipse in pixels, as ``cv2.ellipse`` takes it (centre, axes, angle).

    ``semi_axes`` is (major, minor); ``angle_deg`` is the direction of the major
    axis, from +u towards +v (clockwise on screen), in [0, 180).
    """

    centre: np.ndarray
    semi_axes: np.ndarray
    angle_deg: float


def ellipsoid_visibility(camera: Camera, world_T_body: pin.SE3, semi_axes: Sequence[float] | np.ndarray) -> Visibility:
    """Classify an ellipsoid against the camera centre and the camera plane (depth 0)."""
    return _in_camera(camera, world_T_body, semi_axes)[0]


def _in_camera(
    camera: Camera, world_T_body: pin.SE3, semi_axes: Sequence[float] | np.ndarray
) -> tuple[Visibility, np.ndarray, np.ndarray]:
    """Visibility, centre ``mu`` and shape ``Sigma = R L² Rᵀ`` in the camera frame."""
    L = semi_axes_array(semi_axes)
    R, t = pose_arrays(world_T_body)
    Rwc = camera.world_R_camera
    R_cb = Rwc.T @ R
    mu = (t - camera.centre) @ Rwc
    sigma = (R_cb * L**2) @ R_cb.T
    c_body = -(mu @ R_cb)  # camera centre in the body frame
    if ((c_body / L) ** 2).sum() <= 1.0:
        vis = Visibility.CONTAINS_CAMERA
    else:
        half = math.sqrt(sigma[2, 2])  # support of the ellipsoid along the optical axis
        if mu[2] + half <= 0:
            vis = Visibility.BEHIND
        elif mu[2] - half <= 0:
            vis = Visibility.STRADDLES
        else:
            vis = Visibility.FRONT
    return vis, mu, sigma


def dual_quadric(world_T_body: pin.SE3, semi_axes: Sequence[float] | np.ndarray) -> np.ndarray:
    """4x4 dual quadric ``T diag(L², -1) Tᵀ`` of the ellipsoid (world coordinates)."""
    L = semi_axes_array(semi_axes)
    R, t = pose_arrays(world_T_body)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T @ np.diag([*(L**2), -1.0]) @ T.T


def dual_conic(camera: Camera, world_T_body: pin.SE3, semi_axes: Sequence[float] | np.ndarray) -> np.ndarray:
    """3x3 dual conic ``P Q* Pᵀ`` (lines tangent to the silhouette satisfy lᵀC*l = 0); any sign."""
    P = camera.P
    return P @ dual_quadric(world_T_body, semi_axes) @ P.T


def ellipsoid_conic(camera: Camera, world_T_body: pin.SE3, semi_axes: Sequence[float] | np.ndarray) -> np.ndarray:
    """3x3 silhouette conic of an ellipsoid in ideal pixel coordinates.

    Normalized to unit Frobenius norm with ``xᵀCx < 0`` inside the image
    ellipse.  Raises :class:`ProjectionError` unless the ellipsoid is entirely
    in front of the camera (see :func:`ellipsoid_visibility`).
    """
    vis = ellipsoid_visibility(camera, world_T_body, semi_axes)
    if vis is not Visibility.FRONT:
        raise ProjectionError(f"the ellipsoid's image is not an ellipse: {vis.value} ({camera.name or 'camera'})")
    # No sign fix needed: with P = K[R|t] (K positive), C* = K (S - m mᵀ) Kᵀ for the
    # camera-frame shape S and centre m, and by Sherman-Morrison the centre's image
    # x = K m gives xᵀCx = q / (1 - q) < 0, q = mᵀS⁻¹m > 1 (camera outside).
    C = np.linalg.inv(dual_conic(camera, world_T_body, semi_axes))
    C = 0.5 * (C + C.T)
    return C / np.linalg.norm(C)


def inside_conic(conic: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Boolean ``xᵀCx < 0`` for pixels ``(..., 2)`` (ideal pixel coordinates) -> ``(...)``."""
    return conic_values(conic, pixels) < 0


def conic_values(conic: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """``xᵀCx`` with ``x = (u, v, 1)`` for pixels ``(..., 2)`` -> ``(...)``."""
    p = np.asarray(pixels, dtype=float)
    u, v = p[..., 0], p[..., 1]
    C = conic
    return C[0, 0] * u * u + 2 * C[0, 1] * u * v + C[1, 1] * v * v + 2 * C[0, 2] * u + 2 * C[1, 2] * v + C[2, 2]


def ellipse_parameters(conic: np.ndarray) -> Ellipse:
    """Centre, semi-axes (major, minor) and angle of an ellipse conic (either sign)."""
    C = np.asarray(conic, dtype=float)
    A = C[:2, :2]
    b = C[:2, 2]
    if np.linalg.det(A) <= 0:
        raise ProjectionError("the conic is not an ellipse (its 2x2 part is not definite)")
    centre = -np.linalg.solve(A, b)
    f0 = C[2, 2] + b @ centre  # value at the centre
    M = A / -f0  # (x - c)ᵀ M (x - c) = 1 on the ellipse
    w, V = np.linalg.eigh(M)
    if np.any(w <= 0):
        raise ProjectionError("the conic is not a real ellipse (empty or imaginary)")
    axes = 1.0 / np.sqrt(w)  # w ascending -> axes descending: major first
    major = V[:, 0]
    angle = math.degrees(math.atan2(major[1], major[0])) % 180.0
    return Ellipse(centre, axes, angle)


def conic_bbox(dual: np.ndarray) -> tuple[float, float, float, float]:
    """Continuous extent ``(u_min, v_min, u_max, v_max)`` of an ellipse from its dual conic.

    The vertical tangent ``u = k`` is the line ``(1, 0, -k)``; it touches the
    ellipse iff ``lᵀC*l = 0``, a quadratic in ``k`` (likewise for rows).
    """
    D = np.asarray(dual, dtype=float)
    out = []
    for i in (0, 1):
        a, b, c = D[2, 2], D[i, 2], D[i, i]  # a k² - 2 b k + c = 0
        disc = max(b * b - a * c, 0.0)
        r = math.sqrt(disc)
        out.append(sorted(((b - r) / a, (b + r) / a)))
    (u0, u1), (v0, v1) = out
    return u0, v0, u1, v1


def body_bbox(
    camera: Camera, world_T_body: pin.SE3, semi_axes: Sequence[float] | np.ndarray, margin: int = 1
) -> BBox | None:
    """Pixel box holding every pixel centre whose ray hits the ellipsoid, clipped to the image.

    None when the ellipsoid is behind the camera or its image misses the image.
    The full image when the image is unbounded (straddling / camera inside).
    ``margin`` pixels are added on every side (ideal pixels under distortion).
    """
    vis, mu, sigma = _in_camera(camera, world_T_body, semi_axes)
    if vis is Visibility.BEHIND:
        return None
    full = BBox.full(camera)
    if vis is not Visibility.FRONT:
        return full
    K = camera.K
    u0, v0, u1, v1 = conic_bbox(K @ (sigma - np.outer(mu, mu)) @ K.T)  # = P Q* Pᵀ
    if not all(map(math.isfinite, (u0, v0, u1, v1))):
        return full
    if camera.dist is None:
        box = BBox(
            math.ceil(u0) - margin,
            math.ceil(v0) - margin,
            math.floor(u1) + 1 + margin,
            math.floor(v1) + 1 + margin,
        )
        return box.intersect(full)
    # Distorted camera: keep every column (row) whose pixels' ideal u (v) range
    # meets [u0, u1] ([v0, v1]); a superset of the silhouette, immune to folds.
    umin, umax, vmin, vmax = _ideal_extents(camera)
    cols = np.nonzero((umax >= u0 - margin) & (umin <= u1 + margin))[0]
    rows = np.nonzero((vmax >= v0 - margin) & (vmin <= v1 + margin))[0]
    if len(cols) == 0 or len(rows) == 0:
        return None
    return BBox(int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)


_EXTENTS: weakref.WeakKeyDictionary[Camera, tuple[np.ndarray, ...]] = weakref.WeakKeyDictionary()


def _ideal_extents(camera: Camera) -> tuple[np.ndarray, ...]:
    """Per column min/max ideal u and per row min/max ideal v of the pixel centres (cached)."""
    ext = _EXTENTS.get(camera)
    if ext is None:
        ideal = camera.ray_grid @ camera.K.T  # (H, W, 3) with third component 1
        u, v = ideal[..., 0], ideal[..., 1]
        ext = (u.min(0), u.max(0), v.min(1), v.max(1))
        _EXTENTS[camera] = ext
    return ext
