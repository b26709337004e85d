"""The tracking overlay (overlay.mp4's frames): the ellipses drawn are the bodies' outlines."""

from __future__ import annotations

import cv2
import numpy as np

from kms2pin.ecm import Camera
from kms2pin.viewer.overlay import INNER, OUTER, overlay_image

from ._util import load


def _outline(cam: Camera, pose, semi: np.ndarray) -> np.ndarray:
    """The convex hull (pixels) of 20 000 points of the ellipsoid's surface projected by the
    pinhole camera: its outline, with no conic algebra."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=(20000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    world = (pose.rotation @ (u * semi).T).T + pose.translation
    return cv2.convexHull(cam.project(world).astype(np.float32)).reshape(-1, 2)


def _near(points: np.ndarray, pixels: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point lies within ``tol`` pixels of a pixel centre of ``pixels`` (N, 2: x, y)."""
    d = np.linalg.norm(points[:, None, :] - pixels[None, :, :], axis=2)
    return d.min(axis=1) <= tol


def test_the_drawn_ellipses_are_the_bodies_projected_outlines():
    """On an empty mask, the green (inner) and orange (outer) pixels of one camera's tile lie on
    the convex hulls of the bodies' projected surface points, and every body's outline is
    drawn: most of its hull within a pixel and a half of a pixel of its colour (a body's
    line can be drawn over by a body drawn after it)."""
    robot = load("lowerbody", root="free")
    cam = Camera.look_at(position=[6.0, 1.0, 8.0], target=robot.q_rest[:3], width=320, height=240)
    img = overlay_image(robot, [cam], [np.zeros(cam.shape, bool)], robot.q_rest)
    assert img.shape == (240, 320, 3)
    poses = robot.body_poses(robot.q_rest)
    g, r = img[..., 1].astype(int), img[..., 2].astype(int)
    # the anti-aliased lines on black (BGR): green (0, 255, 0) keeps red at 0, orange (0, 200, 255) has it highest
    green, orange = (r < 40) & (g > 110), (r > 110) & (r > g)
    assert INNER == (0, 255, 0) and OUTER == (0, 200, 255)
    for where, axes in ((green, robot.inner), (orange, robot.outer)):
        drawn = np.argwhere(where)[:, ::-1].astype(float)  # (x, y), the line's core
        assert len(drawn) > 100
        hulls = [_outline(cam, P, axes(b)) for P, b in zip(poses, robot.bodies)]
        on_some = np.zeros(len(drawn), bool)
        for hull in hulls:
            dense = np.concatenate([np.linspace(a, b, 12, endpoint=False) for a, b in zip(hull, np.roll(hull, -1, 0))])
            assert _near(dense, drawn, 1.5).mean() > 0.7, "a body's outline is not drawn"
            on_some |= _near(drawn, dense, 1.5)
        assert on_some.mean() > 0.98, "pixels of the colour off every body's outline"
