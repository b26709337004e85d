"""Cameras for the tracker: from a field of view, or calibrated with a chessboard.

:func:`make_camera` builds a :class:`kms2pin.ecm.Camera` from the image size, the
vertical field of view and a pose (default: the thesis scene, :meth:`Camera.default`'s
pose - at the world origin looking along +z with +y up).

:func:`calibrate_chessboard` estimates ``K`` and the lens distortion from
photographs of a planar chessboard (OpenCV: ``findChessboardCorners`` +
``cornerSubPix``, then ``calibrateCamera``).  A calibration knows nothing of the
world frame: the camera gets an identity ``world_T_camera`` (camera frame =
world frame) unless a pose is given.

Lens distortion: :class:`kms2pin.ecm.Camera` applies ``dist`` consistently in
projection, ray back-projection and ray casting, so **the project keeps masks
in the original (distorted) image and puts the coefficients in the camera**;
masks do not need undistorting.  :func:`undistort_mask` exists for other uses
(e.g. overlaying on an ideal pinhole render).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
import pinocchio as pin

from ..ecm.camera import Camera
from ..errors import CameraError, InputDataError
from .io import read_image

DISTORTION_MODELS = ("none", "radial", "standard", "full")
MIN_VIEWS = 3
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)


def make_camera(
    width: int,
    height: int,
    fov_deg: float,
    position: Sequence[float] | None = None,
    look_at: Sequence[float] | None = None,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    name: str = "",
) -> Camera:
    """Camera of ``width`` x ``height`` pixels with vertical field of view ``fov_deg``.

    ``position`` defaults to the world origin and ``look_at`` to ``position + (0, 0, 1)``
    (looking along +z), ``up`` to +y: with neither given this is :meth:`Camera.default`'s pose.
    """
    p = np.zeros(3) if position is None else np.asarray(position, dtype=float)
    t = p + [0.0, 0.0, 1.0] if look_at is None else np.asarray(look_at, dtype=float)
    return Camera.look_at(p, t, up=up, width=width, height=height, fov_deg=fov_deg, name=name)


def with_pose(
    camera: Camera,
    position: Sequence[float] | None = None,
    look_at: Sequence[float] | None = None,
    up: Sequence[float] = (0.0, 1.0, 0.0),
) -> Camera:
    """``camera``'s intrinsics and distortion with the pose of :func:`make_camera`."""
    pose = make_camera(camera.width, camera.height, 40.0, position, look_at, up).world_T_camera
    return Camera(camera.K, pose, camera.width, camera.height, dist=camera.dist, name=camera.name)


def board_points(board: tuple[int, int], square: float) -> np.ndarray:
    """(cols*rows, 3) inner-corner positions on the board plane z = 0, OpenCV's order."""
    cols, rows = board
    g = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * float(square)
    return np.hstack([g, np.zeros((len(g), 1))]).astype(np.float32)


def find_chessboard(image: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners (N, 1, 2) float32 of a ``cols x rows`` board, or None."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(grey, board, flags=flags)
    if not found:
        found, corners = cv2.findChessboardCorners(grey, board, flags=flags | cv2.CALIB_CB_FILTER_QUADS)
    if not found:
        return None
    return cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), _SUBPIX_CRITERIA)


@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate_chessboard`."""

    camera: Camera
    rms: float  # RMS reprojection error over all used corners, pixels
    used: list[str]  # names of the images where the board was found
    rejected: list[str]  # names of the images where it was not
    per_view_rms: list[float] = field(default_factory=list)


def _calib_flags(distortion: str) -> int:
    if distortion == "none":
        return cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    if distortion == "radial":
        return cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
    if distortion == "standard":
        return cv2.CALIB_FIX_K3
    if distortion == "full":
        return 0
    raise CameraError(f"unknown distortion model '{distortion}'; choose one of {', '.join(DISTORTION_MODELS)}")


def calibrate_chessboard(
    images: Sequence[str | os.PathLike | np.ndarray],
    board: tuple[int, int] = (9, 6),
    square: float = 0.025,
    distortion: str = "standard",
    name: str = "",
) -> CalibrationResult:
    """Calibrate from views of a chessboard with ``board = (cols, rows)`` inner corners.

    ``images`` are paths or BGR/grey arrays (all of one size); ``square`` is the
    side of one square in world units (metres).  ``distortion``: ``none`` (ideal
    pinhole, no ``dist``), ``radial`` (k1, k2), ``standard`` (k1, k2, p1, p2; the
    default) or ``full`` (k1, k2, p1, p2, k3).  Needs the board in at least 3 images.
    """
    cols, rows = board
    if cols < 2 or rows < 2 or cols == rows:
        raise CameraError(
            f"chessboard {cols}x{rows}: need at least 2x2 inner corners and cols != rows "
            "(a square board's orientation is ambiguous)"
        )
    if not square > 0:
        raise CameraError(f"chessboard square size must be > 0, got {square}")
    flags = _calib_flags(distortion)
    obj = board_points(board, square)
    size: tuple[int, int] | None = None
    first = ""
    img_pts, used, rejected = [], [], []
    for i, item in enumerate(images):
        label = os.fspath(item) if not isinstance(item, np.ndarray) else f"image {i}"
        img = read_image(item) if not isinstance(item, np.ndarray) else item
        if img.dtype != np.uint8:
            raise InputDataError(f"{label}: expected an 8-bit image, got {img.dtype}")
        wh = (img.shape[1], img.shape[0])
        if size is None:
            size, first = wh, label
        elif wh != size:
            raise InputDataError(
                f"{label}: {wh[0]}x{wh[1]} pixels, but {first} is {size[0]}x{size[1]}; "
                "calibration images must all have one size"
            )
        corners = find_chessboard(img, board)
        if corners is None:
            rejected.append(label)
        else:
            img_pts.append(corners)
            used.append(label)
    if size is None:
        raise CameraError("calibration: no images given")
    if len(used) < MIN_VIEWS:
        raise CameraError(
            f"calibration: the {cols}x{rows} chessboard was found in {len(used)} of {len(used) + len(rejected)} "
            f"images; at least {MIN_VIEWS} are needed (--board counts inner corners: a board of "
            f"{cols + 1}x{rows + 1} squares has {cols}x{rows})"
        )
    w, h = size
    K0 = np.array([[max(w, h), 0, (w - 1) / 2], [0, max(w, h), (h - 1) / 2], [0, 0, 1]], float)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
        [obj] * len(img_pts), img_pts, size, K0, np.zeros(5), flags=flags
    )
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CameraError(f"calibration failed (K = {K.tolist()}); use more, and more varied, views")
    per_view = []
    for r, t, pts in zip(rvecs, tvecs, img_pts):
        proj, _ = cv2.projectPoints(obj, r, t, K, dist)
        per_view.append(float(np.sqrt(np.mean(np.sum((proj - pts) ** 2, axis=2)))))
    d = dist.ravel()[:5].astype(float)
    d_out = None if distortion == "none" else d.tolist()
    K = np.array(K, float)
    K[0, 1] = K[1, 0] = 0.0
    cam = Camera(K, pin.SE3.Identity(), w, h, dist=d_out, name=name)
    return CalibrationResult(cam, float(rms), used, rejected, per_view)


def undistort_mask(mask: np.ndarray, camera: Camera) -> tuple[np.ndarray, Camera]:
    """Resample a mask seen by ``camera`` to its ideal pinhole (same K, no ``dist``).

    Nearest-neighbour, so the result stays binary (same dtype).  Returns the mask
    and the pinhole camera it belongs to.  Not needed by the tracker (see the
    module docstring).
    """
    m = np.asarray(mask)
    if m.shape[:2] != camera.shape:
        raise InputDataError(
            f"mask is {m.shape[1]}x{m.shape[0]} pixels but camera '{camera.name}' is {camera.width}x{camera.height}"
        )
    ideal = Camera(camera.K, camera.world_T_camera, camera.width, camera.height, name=camera.name)
    if camera.dist is None:
        return m.copy(), ideal
    src = m.astype(np.uint8) if m.dtype == bool else m
    # for each ideal pixel, where it is seen in the distorted image
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(float)
    px = camera.distort_pixels(np.stack([u.ravel(), v.ravel()], axis=1)).astype(np.float32)
    mx = px[:, 0].reshape(camera.shape)
    my = px[:, 1].reshape(camera.shape)
    out = cv2.remap(src, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return (out > 0 if m.dtype == bool else out), ideal
