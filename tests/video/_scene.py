"""Synthetic material shared by the video tests: walks of the lowerbody model,
colour videos of them over a textured static scene, chessboard photographs."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pinocchio as pin

from kms2pin.ecm.motions import FPS, make_motion
from kms2pin.ecm.raycast import render_labels
from kms2pin.video.calibration import board_points
from kms2pin.video.synthetic import chessboard_view, textured_background

SPECS = Path(__file__).resolve().parents[2] / "specs"
LOWER = SPECS / "lowerbody.kms"
# saturated BGR body colours: none is a darker copy of a greyish background colour
# (MOG2's shadow detection would drop such a body: a light-red foot was lost that way)
PALETTE = np.array(
    [[40, 40, 200], [200, 60, 40], [40, 170, 40], [30, 140, 230], [180, 40, 170],
     [200, 180, 30], [90, 30, 140], [30, 200, 200], [220, 40, 120]], float)


def out_and_back_walk(robot, out: int, turn: int, back: int, x0: float = -2.5, speed: float = 0.15) -> np.ndarray:
    """A 30 fps walk along world -x from ``x0`` for ``out`` frames at ``speed`` units per frame,
    a half turn on the spot over ``turn`` frames, and ``back`` frames walking back along +x
    (the subject faces the way it walks).  With :func:`exit_cameras` the subject leaves
    both images on the way out and comes back into them."""
    n = out + turn + back
    q = make_motion(robot, "walk", n).copy()
    k = np.arange(n)
    far = x0 - speed * (out - 1)
    x = np.where(k < out, x0 - speed * k, np.where(k < out + turn, far, far + speed * (k - out - turn + 1)))
    u = np.clip((k - out + 1) / (turn + 1), 0.0, 1.0)
    yaw = np.pi / 2 - np.pi * u  # facing -x, turning round to face +x (the specs face -z at rest)
    rest = pin.XYZQUATToSE3(robot.q_rest[:7])
    for f in range(n):
        R = pin.exp3(np.array([0.0, yaw[f], 0.0])) @ rest.rotation
        p = rest.translation + [x[f], 0.02 * robot.height * np.cos(2 * np.pi * f / FPS / 0.6), 0.0]
        q[f, :7] = pin.SE3ToXYZQUAT(pin.SE3(R, p))
    return q


def exit_cameras():
    """The default front camera and a raised one 48° to its left, both aimed at the
    rest pose: a subject walking along world -x leaves the front image at x ≈ -4.5
    and the other at x ≈ -5 (the lowerbody model)."""
    from kms2pin.ecm.camera import Camera

    return [Camera.default(), Camera.look_at(position=[-6, 3, 2], target=[0, 0, 8])]


def label_renders(robot, q, camera) -> list[tuple[np.ndarray, np.ndarray]]:
    """(body label or -1, depth) images of the inner ellipsoids, one pair per configuration."""
    return [render_labels(camera, [(P, robot.inner(b)) for P, b in zip(robot.body_poses(qf), robot.bodies)])
            for qf in q]


def render_video(robot, q, camera, seed, background=None, palette=PALETTE, renders=None):
    """BGR frames (a static background, by default textured; global flicker of +-5 %;
    Gaussian noise of 3 grey levels) with the model's inner ellipsoids in ``palette``
    colours, shaded with depth, and the true masks.  ``renders``: :func:`label_renders`
    of ``q`` if already made."""
    rng = np.random.default_rng(seed)
    bg = textured_background(camera.height, camera.width, rng) if background is None else background
    renders = label_renders(robot, q, camera) if renders is None else renders
    fin = np.concatenate([d[np.isfinite(d)] for _, d in renders])
    near, far = (float(fin.min()), float(fin.max())) if fin.size else (0.0, 1.0)
    frames, masks = [], []
    for lab, dep in renders:
        fg = lab >= 0
        img = np.array(bg, dtype=np.float32)
        s = 1.0 - 0.45 * np.clip((dep[fg] - near) / max(far - near, 1e-9), 0.0, 1.0)
        img[fg] = palette[lab[fg] % len(palette)] * s[:, None]
        img *= rng.uniform(0.95, 1.05)
        img += rng.normal(0.0, 3.0, size=img.shape).astype(np.float32)
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
        masks.append(fg)
    return frames, masks


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def read_masks(folder: Path, n: int) -> list[np.ndarray]:
    return [cv2.imread(str(folder / f"frame_{i:05d}.png"), cv2.IMREAD_GRAYSCALE) > 0 for i in range(n)]


def chessboard_poses(rng, K, dist, size, board=(9, 6), square=0.03, count=15):
    """``count`` random board poses whose whole board (with margin) is inside the image."""
    cols, rows = board
    centre = np.array([(cols - 1) / 2 * square, (rows - 1) / 2 * square, 0.0])
    margin = np.array([[-2, -2, 0], [cols + 1, -2, 0], [cols + 1, rows + 1, 0], [-2, rows + 1, 0]], float) * square
    out = []
    while len(out) < count:
        angles = np.radians([rng.uniform(-35, 35), rng.uniform(-35, 35), rng.uniform(-20, 20)])
        R = cv2.Rodrigues(np.array([angles[0], 0, 0]))[0] @ cv2.Rodrigues(np.array([0, angles[1], 0]))[0]
        R = R @ cv2.Rodrigues(np.array([0, 0, angles[2]]))[0]
        t = -R @ centre + np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), rng.uniform(0.55, 0.9)])
        rvec = cv2.Rodrigues(R)[0].ravel()
        px, _ = cv2.projectPoints(np.vstack([margin, board_points(board, square)]), rvec, t, K,
                                  dist if dist is not None else np.zeros(5))
        px = px.reshape(-1, 2)
        if px.min() > 5 and px[:, 0].max() < size[0] - 5 and px[:, 1].max() < size[1] - 5:
            out.append((rvec, t))
    return out


def chessboard_images(rng, K, dist, size, board=(9, 6), square=0.03, count=15):
    return [chessboard_view(K, dist, r, t, size, board, square) for r, t in
            chessboard_poses(rng, K, dist, size, board, square, count)]


def pale_walk(robot, camera, frames: int = 60, stride: int = 4, seed: int = 3):
    """The walk (every ``stride``-th frame, crossing the image) before a white wall
    (grey level 215, smooth texture of 8), with the pelvis and trunk in light grey
    (170, shaded with depth down to 94): a darker copy of the wall, i.e. what shadow
    detection takes for a shadow.  Returns (BGR frames, true masks, true masks of the
    light bodies, configurations)."""
    q = make_motion(robot, "walk", frames * stride)[::stride]
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.normal(size=(camera.height, camera.width, 3)).astype(np.float32), (0, 0), 6)
    wall = 215.0 + 8.0 * texture / texture.std()
    palette = PALETTE.copy()
    light = [robot.bodies.index("pelvis"), robot.bodies.index("trunk")]
    palette[light] = 170.0
    renders = label_renders(robot, q, camera)
    images, masks = render_video(robot, q, camera, seed=seed, background=wall, palette=palette, renders=renders)
    return images, masks, [np.isin(lab, light) for lab, _ in renders], q


def cast_shadow(frames, masks, darkness: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The frames with the subject's shadow on the floor, and the shadows' masks: its
    silhouette (``masks``) squashed to a third of its height below its lowest pixel
    and sheared, the background there darkened to ``darkness`` of its brightness
    (colour kept)."""
    out, shadows = [], []
    for frame, m in zip(frames, masks):
        img = frame.astype(np.float32)
        rows = np.flatnonzero(m.any(axis=1))
        if rows.size:
            foot = float(rows[-1])
            warp = np.float32([[1, 0.8, -0.8 * foot], [0, 1 / 3, foot * 2 / 3]])
            shadow = (cv2.warpAffine(m.astype(np.uint8), warp, (m.shape[1], m.shape[0])) > 0) & ~m
            img[shadow] *= darkness
        else:
            shadow = np.zeros_like(m)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
        shadows.append(shadow)
    return out, shadows
