"""Projected generalized densities and per-pixel depths of ellipsoidal bodies (thesis §2.1.1).

Definition.  In the body frame, let ``ρ_E(p) = sqrt(pᵀ diag(1/L_E²) p)`` be
the ellipsoid-normalized radius (1 on the surface of ellipsoid E).  The 3-D
density is 1 inside the inner ellipsoid, 0 outside the outer one and *linear
along every radial line from the centre* in between: on the ray from the centre
through p, it falls linearly from 1 at the inner surface (distance
``|p|/ρ_in``) to 0 at the outer surface (distance ``|p|/ρ_out``)::

    g(p) = clip( ρ_in (1 - ρ_out) / (ρ_in - ρ_out), 0, 1 )

(for ``outer = k * inner`` this is ``(k - ρ_in) / (k - 1)``).

For a pixel, with the forward ray ``r(s) = c + s d`` (``s >= 0``), let
``a = min_s ρ_in(r(s))`` and ``b = min_s ρ_out(r(s))`` (closed form: the
minimum of a quadratic on a half-line).  The projected density is::

    f = 1                              if a <= 1   (ray hits the inner ellipsoid)
    f = 0                              if b >= 1   (ray misses the outer one)
    f = a (1 - b) / (a - b)            otherwise   (in (0, 1))

i.e. ``g``'s formula applied to the two closest approaches.  Because that
formula decreases in both radii, ``f >= max_s g(r(s))`` along the ray, with
equality when the outer ellipsoid is a scaled copy of the inner one (both
minima are then reached at the same point): ``f`` is the largest 3-D density
the pixel's ray meets.  ``f`` is continuous, exactly 1 on the inner
silhouette, exactly 0 off the outer one, and non-increasing along any image
line leaving the projected centre.  It is exact for every pose (bodies behind
the camera give 0, a camera inside the inner ellipsoid gives 1 everywhere).

Pixels are observed ``(u, v)`` (column, row); with a distorted camera they are
undistorted first.  Depth is the camera-frame z, in world units.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from kms2pin.ecm._se3 import inner_outer_arrays, pose_arrays, semi_axes_array
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.projection import BBox, body_bbox

Axes = Sequence[float] | np.ndarray


def ray_monomials(dirs: np.ndarray) -> np.ndarray:
    """``(x², 2xy, y², 2x, 2y, 1)`` of camera rays ``(x, y, 1)`` (..., 3) -> (..., 6).

    Quadratic forms of the rays are then one matrix-vector product.
    """
    x, y = dirs[..., 0], dirs[..., 1]
    return np.stack([x * x, 2 * x * y, y * y, 2 * x, 2 * y, np.ones_like(x)], axis=-1)


_GRID_MONOMIALS: weakref.WeakKeyDictionary[Camera, np.ndarray] = weakref.WeakKeyDictionary()


def grid_monomials(camera: Camera) -> np.ndarray:
    """:func:`ray_monomials` of ``camera.ray_grid`` (H, W, 6), cached per camera."""
    m = _GRID_MONOMIALS.get(camera)
    if m is None:
        m = ray_monomials(camera.ray_grid)
        m.flags.writeable = False
        _GRID_MONOMIALS[camera] = m
    return m


class BodyRays:
    """The rays of a set of pixels expressed in one body's frame.

    For semi-axes L, :meth:`terms` gives the coefficients of
    ``ρ(r(s))² = cc + 2 s dot + s² nn`` for every pixel, where ``r(s)`` has
    depth ``s`` (camera z).  ``mono`` are the :func:`ray_monomials` of the
    pixels' camera-frame rays ``(x, y, 1)``, of any leading shape.
    """

    def __init__(self, camera: Camera, world_T_body: pin.SE3, mono: np.ndarray):
        R, t = pose_arrays(world_T_body)
        self.c = (camera.centre - t) @ R  # camera centre, body frame
        self.M = R.T @ camera.world_R_camera  # body <- camera rotation
        self.mono = mono

    def terms(self, semi_axes: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """``(cc, dot, nn)`` for the ellipsoid with these semi-axes (body frame)."""
        w = 1.0 / np.asarray(semi_axes, dtype=float) ** 2
        cc = float((self.c * self.c * w).sum())
        g = self.M.T @ (self.c * w)  # dot = g . (x, y, 1)
        G = self.M.T @ (w[:, None] * self.M)  # nn = (x, y, 1) G (x, y, 1)ᵀ
        coef = np.array([G[0, 0], G[0, 1], G[1, 1], G[0, 2], G[1, 2], G[2, 2]])
        dot = self.mono[..., 3:] @ (g * [0.5, 0.5, 1.0])
        nn = self.mono @ coef
        return cc, dot, nn


def min_radius_sq(cc: float, dot: np.ndarray, nn: np.ndarray) -> np.ndarray:
    """Squared minimum of ρ over the forward ray (s >= 0) from :meth:`BodyRays.terms`."""
    p = np.minimum(dot, 0.0)
    p *= p
    p /= nn
    np.subtract(cc, p, out=p)
    return np.maximum(p, 0.0, out=p)


def density_from_radii(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The projected density ``f(a, b)`` of the module docstring (a: inner, b: outer)."""
    den = np.subtract(a, b)
    np.maximum(den, 1e-200, out=den)  # a == b only where a <= 1 (set below) or b >= 1 (f <= 0)
    f = np.subtract(1.0, b)
    f *= a
    f /= den
    np.clip(f, 0.0, 1.0, out=f)
    f[a <= 1.0] = 1.0
    return f


def first_hit_depth(cc: float, dot: np.ndarray, nn: np.ndarray) -> np.ndarray:
    """Depth of the forward ray's first point inside the ellipsoid (inf: none; 0: camera inside)."""
    if cc <= 1.0:
        return np.zeros(np.shape(dot))
    disc = dot * dot - nn * (cc - 1.0)
    hit = (dot < 0) & (disc >= 0)
    q = -dot + np.sqrt(np.where(hit, disc, 0.0))  # > 0 on hits: no cancellation
    with np.errstate(divide="ignore"):
        return np.where(hit, (cc - 1.0) / q, np.inf)


def closest_approach_depth(cc: float, dot: np.ndarray, nn: np.ndarray) -> np.ndarray:
    """Depth of the forward-ray point nearest the centre in the ellipsoid metric (mid-chord)."""
    return np.maximum(-dot / nn, 0.0)


def _monomials(camera: Camera, pixels: np.ndarray | None, bbox: BBox | None) -> np.ndarray:
    if pixels is not None:
        if bbox is not None:
            raise ValueError("give either pixels or bbox, not both")
        p = np.asarray(pixels, dtype=float)
        if p.shape[-1:] != (2,):
            raise ValueError(f"pixels must have shape (..., 2), got {p.shape}")
        xn = camera.pixels_to_normalized(p.reshape(-1, 2))
        d = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
        return ray_monomials(d.reshape(*p.shape[:-1], 3))
    if bbox is None:
        return grid_monomials(camera)
    if bbox.empty or bbox.u0 < 0 or bbox.v0 < 0 or bbox.u1 > camera.width or bbox.v1 > camera.height:
        raise ValueError(f"bbox {bbox} is empty or outside the {camera.width}x{camera.height} image")
    return grid_monomials(camera)[bbox.slices]


def projected_density(
    camera: Camera,
    world_T_body: pin.SE3,
    inner: Axes,
    outer: Axes,
    pixels: np.ndarray | None = None,
    *,
    bbox: BBox | None = None,
) -> np.ndarray:
    """Projected generalized density in [0, 1] (definition in the module docstring).

    Evaluated at ``pixels`` (..., 2) -> (...), or on the pixel centres of
    ``bbox`` -> ``bbox.shape`` (i.e. ``full_image[bbox.slices]``), or on the
    whole image -> ``camera.shape``.
    """
    li, lo = inner_outer_arrays(inner, outer)
    rays = BodyRays(camera, world_T_body, _monomials(camera, pixels, bbox))
    a = min_radius_sq(*rays.terms(li))
    b = min_radius_sq(*rays.terms(lo))
    return density_from_radii(np.sqrt(a, out=a), np.sqrt(b, out=b))


def density_region(
    camera: Camera, world_T_body: pin.SE3, inner: Axes, outer: Axes, margin: int = 1
) -> tuple[BBox | None, np.ndarray]:
    """``(bbox, density on bbox)`` for the outer silhouette's box; ``(None, empty)`` if unseen.

    Outside the box the density is exactly 0.
    """
    box = body_bbox(camera, world_T_body, outer, margin)
    if box is None:
        return None, np.zeros((0, 0))
    return box, projected_density(camera, world_T_body, inner, outer, bbox=box)


def body_depth(
    camera: Camera,
    world_T_body: pin.SE3,
    semi_axes: Axes,
    pixels: np.ndarray | None = None,
    *,
    bbox: BBox | None = None,
) -> np.ndarray:
    """Depth (camera z, world units) of the first hit of each pixel's forward ray on the ellipsoid.

    ``inf`` where the ray misses; 0 when the camera centre is inside.  Same
    ``pixels`` / ``bbox`` / whole-image evaluation as :func:`projected_density`.
    """
    L = semi_axes_array(semi_axes)
    rays = BodyRays(camera, world_T_body, _monomials(camera, pixels, bbox))
    return first_hit_depth(*rays.terms(L))
