"""Synthetic test material: a colour video of a model walking over a static scene,
and chessboard photographs taken with a known camera.

Used by the tests and by ``benchmarks/video.py``; the ground truth is exact
(ray casting of the inner ellipsoids, :func:`kms2pin.ecm.raycast.render_labels`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import pinocchio as pin

from ..ecm.camera import Camera
from ..ecm.raycast import render_labels
from ..robot import Robot

# BGR body colours: saturated, so that they are not mistaken for (grey) shadows
PALETTE = np.array(
    [[40, 40, 200], [200, 60, 40], [40, 170, 40], [30, 140, 230], [180, 40, 170],
     [200, 180, 30], [90, 30, 140], [30, 200, 200], [120, 120, 230], [230, 120, 120]],
    dtype=float,
)


def textured_background(height: int, width: int, rng: np.random.Generator, shapes: int = 6) -> np.ndarray:
    """A static BGR scene: smoothed colour noise (two scales) plus a few flat shapes."""
    img = np.full((height, width, 3), 120.0)
    for sigma, amp in ((max(width, height) / 12.0, 45.0), (2.0, 12.0)):
        n = rng.normal(size=(height, width, 3)).astype(np.float32)
        n = cv2.GaussianBlur(n, (0, 0), sigma)
        n /= n.std() + 1e-9
        img += amp * n
    for _ in range(shapes):
        colour = rng.uniform(30, 220, size=3).tolist()
        if rng.random() < 0.5:
            p = (int(rng.uniform(0, width)), int(rng.uniform(0, height)))
            q = (p[0] + int(rng.uniform(10, width / 4)), p[1] + int(rng.uniform(10, height / 4)))
            cv2.rectangle(img, p, q, colour, -1)
        else:
            c = (int(rng.uniform(0, width)), int(rng.uniform(0, height)))
            cv2.circle(img, c, int(rng.uniform(5, min(width, height) / 8)), colour, -1)
    return np.clip(img, 0, 255).astype(np.float32)


def shade_bodies(labels: np.ndarray, depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """(H,W,3) float BGR of the rendered bodies: palette colour x depth shading (1 near .. 0.55 far)."""
    fg = labels >= 0
    out = np.zeros(labels.shape + (3,), np.float32)
    s = 1.0 - 0.45 * np.clip((depth[fg] - near) / max(far - near, 1e-9), 0.0, 1.0)
    out[fg] = PALETTE[labels[fg] % len(PALETTE)] * s[:, None]
    return out


@dataclass
class SyntheticVideo:
    frames: list[np.ndarray]  # BGR uint8
    masks: list[np.ndarray]  # true silhouettes, bool
    camera: Camera


def diagonal_walk(robot: Robot, frames: int, stride: int = 2, length: float = 3.0) -> np.ndarray:
    """Configurations (frames, nq) of a free-root model walking ``length`` units along
    world (1, 0, -1)/√2 through its rest position, turning to face that way over the
    first half second: the ``walk`` motion's joint angles (every ``stride``-th frame of
    30 fps) and a vertical bob of 2 % of the height.

    Diagonal so that the subject crosses the images of both a front camera and a side
    camera (at x = 8 looking along -x): background subtraction needs every pixel to show
    the background in most frames, and a subject walking straight at a camera covers
    the same pixels throughout.
    """
    from ..ecm.motions import FPS, make_motion

    q = make_motion(robot, "walk", frames * stride)[::stride].copy()
    t = np.arange(frames) * stride / FPS
    ramp = np.clip(t / 0.5, 0, 1)
    s = length * (t / max(t[-1], 1e-9) - 0.5)
    d = np.array([1.0, 0.0, -1.0]) / np.sqrt(2)
    rest = pin.XYZQUATToSE3(robot.q_rest[:7])
    for f in range(frames):
        R = pin.exp3(np.array([0.0, -np.pi / 4 * ramp[f], 0.0])) @ rest.rotation
        p = rest.translation + s[f] * d + [0.0, 0.02 * robot.height * np.cos(2 * np.pi * t[f] / 0.6), 0.0]
        q[f, :7] = pin.SE3ToXYZQUAT(pin.SE3(R, p))
    return q


def walking_video(
    robot: Robot,
    camera: Camera,
    frames: int = 60,
    seed: int = 0,
    flicker: float = 0.05,
    noise_sigma: float = 3.0,
    motion: str = "walk",
    render_scale: int = 1,
    stride: int = 4,
    q: np.ndarray | None = None,
) -> SyntheticVideo:
    """The model's inner ellipsoids moving over a textured static background.

    Per frame the whole image gets a global gain drawn uniformly in
    ``1 +- flicker`` and Gaussian sensor noise of ``noise_sigma`` grey levels.
    ``render_scale`` > 1 ray-casts at 1/render_scale of the resolution and
    enlarges (nearest) - faster, for benchmarks.  ``stride``: keep every
    ``stride``-th frame of the 30 fps motion (4: 60 frames span the 8 s
    there-and-back walk, so the subject crosses the image).  ``q``: the
    configurations (frames, nq) to render instead of ``motion`` (e.g.
    :func:`diagonal_walk`).
    """
    from ..ecm.motions import make_motion

    rng = np.random.default_rng(seed)
    if q is None:
        q = make_motion(robot, motion, frames * stride, rng=np.random.default_rng(seed))[::stride]
    else:
        q = np.asarray(q, dtype=float).reshape(-1, robot.nq)
        frames = len(q)
    bg = textured_background(camera.height, camera.width, rng)
    rcam = camera
    if render_scale > 1:
        s = render_scale
        K = camera.K.copy()
        K[:2] /= s
        K[0, 2] = (camera.K[0, 2] + 0.5) / s - 0.5
        K[1, 2] = (camera.K[1, 2] + 0.5) / s - 0.5
        rcam = Camera(K, camera.world_T_camera, camera.width // s, camera.height // s, dist=camera.dist)
    renders = []
    for f in range(frames):
        poses = robot.body_poses(q[f])
        bodies = [(P, robot.inner(b)) for P, b in zip(poses, robot.bodies)]
        lab, dep = render_labels(rcam, bodies)
        if render_scale > 1:
            lab = cv2.resize(lab, (camera.width, camera.height), interpolation=cv2.INTER_NEAREST)
            dep = cv2.resize(dep, (camera.width, camera.height), interpolation=cv2.INTER_NEAREST)
        renders.append((lab, dep))
    fin = np.concatenate([d[np.isfinite(d)] for _, d in renders] or [np.zeros(1)])
    near, far = (float(fin.min()), float(fin.max())) if fin.size else (0.0, 1.0)
    out, masks = [], []
    for lab, dep in renders:
        fg = lab >= 0
        img = bg.copy()
        img[fg] = shade_bodies(lab, dep, near, far)[fg]
        img *= rng.uniform(1 - flicker, 1 + flicker)
        img += rng.normal(0.0, noise_sigma, size=img.shape).astype(np.float32)
        out.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
        masks.append(fg)
    return SyntheticVideo(out, masks, camera)


def write_video(path: str | os.PathLike, frames: Sequence[np.ndarray], fps: float = 30.0) -> None:
    """Write BGR frames with cv2.VideoWriter: ``.avi`` as MJPG, anything else as ``mp4v``."""
    h, w = frames[0].shape[:2]
    fourcc = cv2.VideoWriter_fourcc(*("MJPG" if str(path).lower().endswith(".avi") else "mp4v"))
    vw = cv2.VideoWriter(str(path), fourcc, fps, (w, h))
    if not vw.isOpened():
        raise RuntimeError(f"{path}: cv2.VideoWriter cannot write this format")
    for f in frames:
        vw.write(f)
    vw.release()


def chessboard_view(
    camera_K: np.ndarray,
    dist: np.ndarray | None,
    rvec: np.ndarray,
    tvec: np.ndarray,
    size: tuple[int, int],
    board: tuple[int, int] = (9, 6),
    square: float = 0.03,
    supersample: int = 4,
) -> np.ndarray:
    """A grey photograph of a chessboard with ``board`` inner corners at pose (rvec, tvec).

    The board has ``(cols+1) x (rows+1)`` squares, the top-left one black, with a
    one-square white margin; each square is projected with ``cv2.projectPoints``
    (through ``dist``) and filled with ``cv2.fillConvexPoly``, drawn at
    ``supersample`` x resolution and averaged down (anti-aliased edges).
    """
    cols, rows = board
    w, h = size
    s = supersample
    img = np.full((h * s, w * s), 90, np.uint8)  # grey surroundings
    # subdivide edges so that distorted squares stay accurate
    def poly(x0, y0, x1, y1, n=4):
        t = np.linspace(0, 1, n, endpoint=False)
        pts = np.concatenate([
            np.stack([x0 + (x1 - x0) * t, np.full(n, y0)], 1),
            np.stack([np.full(n, x1), y0 + (y1 - y0) * t], 1),
            np.stack([x1 - (x1 - x0) * t, np.full(n, y1)], 1),
            np.stack([np.full(n, x0), y1 - (y1 - y0) * t], 1),
        ])
        obj = np.hstack([pts * square, np.zeros((len(pts), 1))])
        px, _ = cv2.projectPoints(obj, rvec, tvec, camera_K, dist if dist is not None else np.zeros(5))
        # pixel centres at integer coordinates: pixel (u, v) covers [u-0.5, u+0.5]
        return np.rint(((px.reshape(-1, 2) + 0.5) * s - 0.5) * 16).astype(np.int32)

    cv2.fillConvexPoly(img, poly(-2, -2, cols + 1, rows + 1), 255, cv2.LINE_8, 4)  # white board with margin
    for i in range(cols + 1):
        for j in range(rows + 1):
            if (i + j) % 2 == 0:
                cv2.fillConvexPoly(img, poly(i - 1, j - 1, i, j), 20, cv2.LINE_8, 4)
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
