"""The tracking overlay: masks with the model's projected ellipses, one tile per camera."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from ..ecm.camera import Camera
from ..ecm.projection import ProjectionError, ellipse_parameters, ellipsoid_conic
from ..robot import Robot

__all__ = ["overlay_image"]

#: BGR colours of the outer and inner ellipses
OUTER, INNER = (0, 200, 255), (0, 255, 0)


def overlay_image(robot: Robot, cameras: Sequence[Camera], masks: Sequence[np.ndarray], q: np.ndarray,
                  scales: np.ndarray | None = None) -> np.ndarray:
    """(H, W * cameras, 3) BGR uint8: each camera's mask in grey with the projected outer
    (orange) and inner (green) ellipses of ``robot`` at ``q``, the body sizes times
    ``scales`` (n_bodies, 3; the tracker's measured sizes), side by side."""
    poses = robot.body_poses(q)
    scales = np.ones((len(robot.bodies), 3)) if scales is None else scales
    tiles = []
    for cam, m in zip(cameras, masks):
        img = cv2.cvtColor(m.astype(np.uint8) * 160, cv2.COLOR_GRAY2BGR)
        for P, b, f in zip(poses, robot.bodies, scales):
            for axes, colour in ((robot.outer(b) * f, OUTER), (robot.inner(b) * f, INNER)):
                try:
                    e = ellipse_parameters(ellipsoid_conic(cam, P, axes))
                except (ProjectionError, np.linalg.LinAlgError):
                    continue
                if not np.all(np.isfinite(e.centre)) or np.max(e.semi_axes) > 1e4:
                    continue
                cv2.ellipse(img, (tuple(map(float, e.centre)), tuple(map(float, 2 * e.semi_axes)), e.angle_deg),
                            colour, 1, cv2.LINE_AA)
        tiles.append(img)
    h = max(t.shape[0] for t in tiles)
    tiles = [cv2.copyMakeBorder(t, 0, h - t.shape[0], 0, 0, cv2.BORDER_CONSTANT) for t in tiles]
    return np.hstack(tiles)
