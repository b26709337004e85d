"""Reference: the thesis's occlusion E-step (§2.1.2), soft assignment of foreground pixels
to bodies front to back.  Not used by the tracker, whose E-step is the union of sharp
silhouettes (:mod:`kms2pin.ecm.estep`); kept as the thesis's formulation to compare with.

For a foreground pixel, let ``f_i`` be body i's projected density
(:mod:`kms2pin.ecm.density`).  Bodies claim the pixel front to back::

    w_i = f_i * prod_{j nearer than i at this pixel} (1 - f_j)

and the responsibilities are ``r_i = w_i / (sum_j w_j + ε)`` for the bodies
and ``ε / (sum_j w_j + ε)`` for the outlier class, ``ε`` being the outlier
density.  Responsibilities ``<= min_weight`` are dropped and the rest
renormalized, so bodies plus outlier sum to exactly 1 on every foreground
pixel.

"Nearer" is decided per pixel from the outer ellipsoid along that pixel's ray
(every pixel with ``f_i > 0`` hits it).  ``occlusion="middle"`` (default) uses
the depth of the ray's closest approach to the centre in the ellipsoid metric
(the middle of the chord through the outer ellipsoid; for ``outer = k*inner``
also the middle of the inner chord).  Unlike the entry depth it does not favour
bodies with wider uncertainty margins, whose outer surfaces stick out further
towards the camera.  ``occlusion="entry"`` uses the outer surface's first hit.

Each body is evaluated only inside its outer silhouette's bounding box (and
the mask's), with NumPy over all pixels at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from kms2pin.ecm._se3 import inner_outer_arrays
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.density import (
    BodyRays,
    closest_approach_depth,
    density_from_radii,
    first_hit_depth,
    grid_monomials,
    min_radius_sq,
)
from kms2pin.ecm.projection import BBox, body_bbox
from kms2pin.errors import InputDataError

BodySpec = tuple[pin.SE3, Sequence[float] | np.ndarray, Sequence[float] | np.ndarray]


@dataclass(frozen=True)
class EStepResult:
    """Soft labels of one frame.

    ``pixels[i]`` (N_i,2) float ``(u, v)`` and ``weights[i]`` (N_i,) are the
    foreground pixels body i received (raster order) and their
    responsibilities; ``outlier`` (H,W) is the outlier responsibility (0 off
    the foreground).
    """

    pixels: tuple[np.ndarray, ...]
    weights: tuple[np.ndarray, ...]
    outlier: np.ndarray

    def weight_image(self, i: int) -> np.ndarray:
        """Body i's responsibilities painted into an (H,W) image (0 elsewhere)."""
        img = np.zeros_like(self.outlier)
        p = self.pixels[i].astype(np.intp)
        img[p[:, 1], p[:, 0]] = self.weights[i]
        return img


def e_step(
    mask: np.ndarray,
    camera: Camera,
    bodies: Sequence[BodySpec],
    outlier: float = 0.05,
    *,
    min_weight: float = 1e-3,
    occlusion: str = "middle",
    source: str = "mask",
) -> EStepResult:
    """Assign the foreground of ``mask`` (H,W bool) to ``bodies`` ``(world_T_body, inner, outer)``.

    ``outlier`` is the outlier class's constant density (> 0); ``source``
    names the mask (file and frame) in error messages.
    """
    if not outlier > 0:
        raise ValueError(f"outlier density must be > 0, got {outlier}")
    if occlusion not in ("middle", "entry"):
        raise ValueError(f"occlusion must be 'middle' or 'entry', got {occlusion!r}")
    fg = _check_mask(mask, camera, source)
    H, W = camera.shape
    n = len(bodies)
    rows = np.flatnonzero(fg.any(axis=1))
    cols = np.flatnonzero(fg.any(axis=0))
    if len(rows) == 0:
        empty = tuple(np.zeros((0, 2)) for _ in range(n))
        return EStepResult(empty, tuple(np.zeros(0) for _ in range(n)), np.zeros((H, W)))
    fg_box = BBox(int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)

    mono = grid_monomials(camera)
    idx_parts, body_parts, f_parts, depth_parts = [], [], [], []
    for i, (pose, inner, outer) in enumerate(bodies):
        li, lo = inner_outer_arrays(inner, outer)
        box = body_bbox(camera, pose, lo)
        box = box.intersect(fg_box) if box is not None else None
        if box is None:
            continue
        rays = BodyRays(camera, pose, mono[box.slices])
        out_terms = rays.terms(lo)
        a = min_radius_sq(*rays.terms(li))
        b = min_radius_sq(*out_terms)
        f = density_from_radii(np.sqrt(a, out=a), np.sqrt(b, out=b))
        sel = fg[box.slices] & (f > 0)
        r, c = np.nonzero(sel)
        if len(r) == 0:
            continue
        depth_fn = closest_approach_depth if occlusion == "middle" else first_hit_depth
        depth = depth_fn(out_terms[0], out_terms[1][sel], out_terms[2][sel])
        idx_parts.append((r + box.v0) * W + (c + box.u0))
        body_parts.append(np.full(len(r), i, dtype=np.intp))
        f_parts.append(f[sel])
        depth_parts.append(depth)

    outlier_map = np.zeros((H, W))
    if not idx_parts:
        outlier_map[fg] = 1.0
        empty = tuple(np.zeros((0, 2)) for _ in range(n))
        return EStepResult(empty, tuple(np.zeros(0) for _ in range(n)), outlier_map)

    idx = np.concatenate(idx_parts)
    body = np.concatenate(body_parts)
    f = np.concatenate(f_parts)
    depth = np.concatenate(depth_parts)

    order = np.lexsort((body, depth, idx))  # by pixel, then front to back (ties: body order)
    idx, body, f = idx[order], body[order], f[order]
    run, first = runs(idx)  # entry -> claimed pixel; first entry of each claimed pixel
    claimed = idx[first]  # flat index of each claimed pixel
    w = f * transmittance(run, first, 1.0 - f)

    total = np.add.reduceat(w, first)
    keep = w > min_weight * (total[run] + outlier)
    idx, body, w, run = idx[keep], body[keep], w[keep], run[keep]
    total = np.bincount(run, weights=w, minlength=len(first)) + outlier
    resp = w / total[run]
    outlier_map[fg] = 1.0  # foreground no body claims
    outlier_map.reshape(-1)[claimed] = outlier / total

    by_body = np.argsort(body, kind="stable")
    counts = np.bincount(body, minlength=n)
    splits = np.cumsum(counts)[:-1]
    idx_b = np.split(idx[by_body], splits)
    resp_b = np.split(resp[by_body], splits)
    pixels = tuple(np.stack([k % W, k // W], axis=1).astype(float) for k in idx_b)
    return EStepResult(pixels, tuple(resp_b), outlier_map)


def runs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For sorted ``keys``: the run number of each entry and the first entry of each run."""
    start = np.ones(len(keys), dtype=bool)
    start[1:] = keys[1:] != keys[:-1]
    return np.cumsum(start) - 1, np.flatnonzero(start)


def transmittance(run: np.ndarray, first: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """Exclusive running product of ``factor`` within each run (see :func:`runs`)."""
    zero = factor <= 0.0
    logf = np.log(np.where(zero, 1.0, factor))
    cum_log = np.cumsum(logf) - logf  # exclusive
    cum_zero = np.cumsum(zero) - zero
    cum_log -= cum_log[first][run]
    cum_zero -= cum_zero[first][run]
    return np.where(cum_zero > 0, 0.0, np.exp(cum_log))


def _check_mask(mask: np.ndarray, camera: Camera, source: str) -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim != 2:
        raise InputDataError(f"{source}: a mask must be a 2-D image, got shape {m.shape}")
    if m.shape != camera.shape:
        cam = f" '{camera.name}'" if camera.name else ""
        raise InputDataError(
            f"{source}: mask is {m.shape[1]}x{m.shape[0]} but camera{cam} is {camera.width}x{camera.height}"
        )
    if m.dtype == bool:
        return m
    if m.dtype.kind in "iuf" and np.all((m == 0) | (m == 1)):
        return m.astype(bool)
    raise InputDataError(f"{source}: mask must be boolean (or 0/1), got dtype {m.dtype}")
