"""Random scenes and pixel helpers shared by the ECM tests."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy import ndimage

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.projection import Visibility, ellipsoid_visibility

DIST = np.array([-0.12, 0.03, 0.001, -0.0015, 0.0])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random 3x3 rotation."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return pin.Quaternion(q[0], q[1], q[2], q[3]).toRotationMatrix()


def random_camera(rng: np.random.Generator, kind: int, dist: np.ndarray | None = None) -> Camera:
    """Default camera (kind 0), a look_at camera (1) or one with a random non-square K (2)."""
    if kind == 0 and dist is None:
        return Camera.default()
    pos = rng.uniform(-6, 6, size=3)
    target = rng.uniform(-1, 1, size=3)
    cam = Camera.look_at(pos, target, up=rng.normal(size=3), fov_deg=rng.uniform(30, 70))
    K = cam.K.copy()
    if kind == 2:
        K = np.array(
            [
                [rng.uniform(200, 400), 0.0, rng.uniform(140, 180)],
                [0.0, rng.uniform(200, 400), rng.uniform(100, 140)],
                [0.0, 0.0, 1.0],
            ]
        )
    return Camera(K, cam.world_T_camera, cam.width, cam.height, dist=dist)


def random_body_in_view(
    rng: np.random.Generator,
    camera: Camera,
    scale: float = 1.0,
    depth: tuple[float, float] = (2.0, 12.0),
) -> tuple[pin.SE3, np.ndarray]:
    """A random ellipsoid entirely in front of the camera, centred on a random pixel."""
    while True:
        axes = rng.uniform(0.1, 1.2, size=3) * scale
        px = np.array([[rng.uniform(20, camera.width - 20), rng.uniform(20, camera.height - 20)]])
        d, c = camera.rays(px)
        z = rng.uniform(*depth)
        centre = c + d[0] * z / (d[0] @ camera.world_T_camera.rotation[:, 2])
        pose = pin.SE3(random_rotation(rng), centre)
        if ellipsoid_visibility(camera, pose, axes) is Visibility.FRONT:
            return pose, axes


def pixel_grid(camera: Camera) -> np.ndarray:
    """(H,W,2) pixel-centre coordinates (u, v)."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    return np.stack([u, v], axis=-1).astype(float)


def boundary_pixels(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 3x3 neighbourhood (inside the image) holds both values."""
    m = mask.astype(np.uint8)
    hi = ndimage.maximum_filter(m, size=3, mode="nearest")
    lo = ndimage.minimum_filter(m, size=3, mode="nearest")
    return hi != lo
