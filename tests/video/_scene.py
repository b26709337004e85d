"""Synthetic material shared by the video tests."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from kms2pin.video.calibration import board_points
from kms2pin.video.synthetic import chessboard_view

SPECS = Path(__file__).resolve().parents[2] / "specs"
LOWER = SPECS / "lowerbody.kms"


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
