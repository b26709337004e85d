"""Synthetic silhouettes for ECM tests and benchmarks (``kms2pin synth``).

Masks are the inner ellipsoids rendered by exact ray casting
(:func:`kms2pin.ecm.raycast.render_mask`), or with ``shape="capsule"`` a capsule in
place of each (:meth:`~kms2pin.ecm.raycast.Capsule.of_ellipsoid`: along the longest
semi-axis a, end to end 2a, radius the mean of the other two), a subject whose outline
the tracking model does not have exactly.  Optional corruption, all driven by
one ``noise`` level ``L`` (e.g. ``0.05`` = "5 % noise"), applied in this order:

- **ragged boundaries**: every pixel within 1 pixel of the outline is flipped
  with probability ``4 L`` (capped at 0.5);
- **holes**: ``round(100 L)`` background discs, radius 1-3 pixels, punched inside
  the silhouette;
- **false blobs**: ``round(40 L)`` foreground discs, radius 1-4 pixels, placed
  anywhere in the image;
- **flipped pixels**: every pixel flipped independently with probability ``L / 10``
  (salt-and-pepper).

``size_mismatch`` ``m`` renders each body with its semi-axes scaled by a factor
drawn uniformly in ``[1 - m, 1 + m]`` per body and axis (fixed over the whole
sequence), so the tracking model is off by up to ``m`` (e.g. 0.1 = 10 %).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import cv2
import numpy as np

from ..errors import OptionError
from ..robot import Robot
from .camera import Camera
from .raycast import Body, Capsule, render_mask

SHAPES = ("ellipsoid", "capsule")


def body_scales(robot: Robot, size_mismatch: float, rng: np.random.Generator) -> np.ndarray:
    """(n_bodies, 3) semi-axis factors for ``size_mismatch`` (module docstring)."""
    n = len(robot.bodies)
    if size_mismatch <= 0:
        return np.ones((n, 3))
    return rng.uniform(1.0 - size_mismatch, 1.0 + size_mismatch, (n, 3))


def render(robot: Robot, q: np.ndarray, cameras: Sequence[Camera], scales: np.ndarray | None = None,
           shape: str = "ellipsoid") -> list[np.ndarray]:
    """Clean (H, W) bool silhouettes at ``q``, one per camera, of the inner ellipsoids (their
    semi-axes times ``scales``), or of capsules in their place (``shape="capsule"``)."""
    if shape not in SHAPES:
        raise OptionError(f"shape must be one of {', '.join(SHAPES)}, not {shape!r}")
    poses = robot.body_poses(q)
    n = len(robot.bodies)
    scales = np.ones((n, 3)) if scales is None else scales
    bodies: list[Body] = [(P, robot.inner(b) * s) for P, b, s in zip(poses, robot.bodies, scales)]
    if shape == "capsule":
        bodies = [Capsule.of_ellipsoid(P, axes) for P, axes in bodies]
    return [render_mask(c, bodies) for c in cameras]


def _discs(shape, centres, radii) -> np.ndarray:
    img = np.zeros(shape, dtype=np.uint8)
    for (v, u), r in zip(centres, radii):
        cv2.circle(img, (int(u), int(v)), int(r), 1, -1)
    return img.astype(bool)


def corrupt(mask: np.ndarray, noise: float, rng: np.random.Generator) -> np.ndarray:
    """Apply the corruption of the module docstring at level ``noise`` to a mask."""
    m = np.array(mask, dtype=bool)
    if noise <= 0:
        return m
    u8 = m.astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    edge = cv2.dilate(u8, kernel).astype(bool) & ~cv2.erode(u8, kernel).astype(bool)
    flip = edge & (rng.random(m.shape) < min(4.0 * noise, 0.5))
    m ^= flip
    inside = np.argwhere(mask)
    n_holes = int(round(100 * noise))
    if n_holes and len(inside):
        pick = inside[rng.integers(0, len(inside), n_holes)]
        m &= ~_discs(m.shape, pick, rng.integers(1, 4, n_holes))
    n_blobs = int(round(40 * noise))
    if n_blobs:
        pos = np.stack([rng.integers(0, m.shape[0], n_blobs), rng.integers(0, m.shape[1], n_blobs)], axis=1)
        m |= _discs(m.shape, pos, rng.integers(1, 5, n_blobs))
    m ^= rng.random(m.shape) < noise / 10.0
    return m


def synthesize(
    robot: Robot,
    motion: np.ndarray,
    cameras: Camera | Sequence[Camera],
    *,
    noise: float = 0.0,
    size_mismatch: float = 0.0,
    rng: np.random.Generator | None = None,
    shape: str = "ellipsoid",
) -> Iterator[tuple[int, list[np.ndarray]]]:
    """Yield ``(frame, masks)`` for every configuration of ``motion`` (T, nq), one
    mask per camera (a single :class:`Camera` counts as a list of one); ``shape`` as in
    :func:`render`."""
    cameras = [cameras] if isinstance(cameras, Camera) else cameras
    rng = np.random.default_rng() if rng is None else rng
    scales = body_scales(robot, size_mismatch, rng)
    for f, q in enumerate(motion):
        masks = render(robot, q, cameras, scales, shape)
        yield f, [corrupt(m, noise, rng) for m in masks]
