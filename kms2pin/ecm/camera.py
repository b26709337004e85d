"""Pinhole cameras in the OpenCV convention, with JSON I/O.

Frames: the camera frame has x right, y down, z forward (optical axis);
``world_T_camera`` places it in the world.  Pixels are ``(u, v)`` = (column,
row) with the centre of pixel ``[row, col]`` at integer coordinates
``(col, row)``, as in OpenCV.  Lengths are in world units (metres in the
thesis models); ``K`` is in pixels.

A JSON camera file holds one object (or, for :meth:`Camera.list_from_json`, a
list of them)::

    {"name": "left", "width": 320, "height": 240,
     "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
     "world_T_camera": {"rotation": [[...], [...], [...]], "translation": [x, y, z]},
     "dist": [k1, k2, p1, p2, k3]}

``name`` and ``dist`` are optional.  The accepted ranges (anything else is a
:class:`~kms2pin.errors.CameraError` naming the file and the field): ``width`` and
``height`` whole numbers in [1, 8192] (:data:`~kms2pin.userfile.MAX_IMAGE_SIDE`);
focal lengths ``fx``, ``fy`` in [1e-3, 1e6] pixels and the principal point within
+-1e6 pixels; the translation within +-1e6 world units (the spec's lengths'
range); distortion coefficients within +-1e6.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pinocchio as pin

from kms2pin.errors import CameraError, did_you_mean
from kms2pin.jsonfile import read_json
from kms2pin.lang.symbols import MAX_LENGTH
from kms2pin.robot import rotation_error
from kms2pin.userfile import MAX_IMAGE_SIDE

ROTATION_TOL = 1e-6
MAX_COORDINATE = MAX_LENGTH  # 1e6: |translation| (the spec's lengths' range), |cx|, |cy|, |dist|, fx, fy at most
MIN_FOCAL = 1e-3  # fx, fy at least this (pixels)
DIST_LENGTHS = (4, 5, 8, 12, 14)
FIELDS = ("name", "width", "height", "K", "world_T_camera", "dist")
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)


class Camera:
    """A calibrated pinhole camera (OpenCV convention, see the module docstring).

    ``K`` is the 3x3 intrinsic matrix (pixels), ``world_T_camera`` the camera
    frame in the world, ``width``/``height`` the image size in pixels and
    ``dist`` optional OpenCV distortion coefficients ``(k1, k2, p1, p2[, k3...])``.
    Instances are immutable.
    """

    def __init__(
        self,
        K: np.ndarray | Sequence[Sequence[float]],
        world_T_camera: pin.SE3 | np.ndarray,
        width: int,
        height: int,
        dist: Sequence[float] | np.ndarray | None = None,
        name: str = "",
    ):
        where = f"camera '{name}'" if name else "camera"
        if isinstance(world_T_camera, pin.SE3):
            R = np.array(world_T_camera.rotation, dtype=float)
            t = np.array(world_T_camera.translation, dtype=float)
        else:
            m = _matrix(world_T_camera, (4, 4), where, "world_T_camera", "a pin.SE3 or a 4x4 matrix")
            R, t = m[:3, :3], m[:3, 3]
        self._K = _check_K(_matrix(K, (3, 3), where, "K", "a 3x3 matrix of numbers"), where)
        self._R = _check_rotation(R, where, "world_T_camera.rotation")
        self._t = _check_translation(_matrix(t, (3,), where, "world_T_camera.translation", "a list of 3 numbers"),
                                     where)
        self._width = _check_size(width, where, "width")
        self._height = _check_size(height, where, "height")
        self._dist = None if dist is None else _check_dist(dist, where)
        if not isinstance(name, str):
            raise CameraError(f"{where}: field 'name' must be a string")
        self._name = name
        for a in (self._K, self._R, self._t) + ((self._dist,) if self._dist is not None else ()):
            a.flags.writeable = False

    # ----------------------------------------------------------------- basics
    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix in pixels (read-only)."""
        return self._K

    @property
    def world_T_camera(self) -> pin.SE3:
        """The camera frame in the world (a fresh copy)."""
        return pin.SE3(self._R.copy(), self._t.copy())

    @property
    def world_R_camera(self) -> np.ndarray:
        """3x3 rotation of the camera frame in the world (read-only; columns = camera x, y, z)."""
        return self._R

    @property
    def camera_T_world(self) -> pin.SE3:
        """The world frame in camera coordinates (a fresh copy)."""
        return pin.SE3(self._R.T.copy(), -self._R.T @ self._t)

    @property
    def width(self) -> int:
        return self._width

    @property
    def height(self) -> int:
        return self._height

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)`` as for a NumPy image."""
        return (self._height, self._width)

    @property
    def dist(self) -> np.ndarray | None:
        """OpenCV distortion coefficients, or None for an ideal pinhole."""
        return self._dist

    @property
    def name(self) -> str:
        return self._name

    @property
    def centre(self) -> np.ndarray:
        """Camera centre (optical centre) in world coordinates (read-only)."""
        return self._t

    @cached_property
    def P(self) -> np.ndarray:
        """3x4 projection matrix ``K [R^T | -R^T t]`` (world -> undistorted pixels; read-only)."""
        Rcw = self._R.T
        P = self._K @ np.hstack([Rcw, (-Rcw @ self._t)[:, None]])
        P.flags.writeable = False
        return P

    def __repr__(self) -> str:
        fx, fy = self._K[0, 0], self._K[1, 1]
        d = "" if self._dist is None else f", dist={self._dist.tolist()}"
        return (
            f"Camera(name={self._name!r}, {self._width}x{self._height}, fx={fx:.6g}, fy={fy:.6g}, "
            f"centre={self._t.tolist()}{d})"
        )

    def binned(self, factor: int = 2) -> Camera:
        """This camera for its image binned ``factor`` x ``factor`` (each new pixel the
        block of ``factor**2`` pixels starting at ``factor * (row, col)``; a last partial
        row or column of blocks is dropped).  Pixel ``(u', v')``'s centre is the block's,
        ``factor * u' + (factor - 1) / 2`` in this camera, so
        ``K' = diag(1/f, 1/f, 1) K`` with the principal point moved by ``-(f - 1) / 2``
        before the scaling; the distortion (in normalized coordinates) is kept."""
        f = int(factor)
        if f < 1 or self._width < f or self._height < f:
            raise CameraError(f"camera: cannot bin a {self._width}x{self._height} image by {factor}")
        if f == 1:
            return self
        K = self._K.copy()
        K[:2, 2] -= (f - 1) / 2.0
        K[:2] /= f
        K.flags.writeable = False
        # made from this checked camera, not checked again: its focal lengths may fall below a
        # file's least (MIN_FOCAL), and an error then would name no file
        out = object.__new__(Camera)
        out.__dict__.update(self.__dict__, _K=K, _width=self._width // f, _height=self._height // f)
        for cached in ("P", "ray_grid"):
            out.__dict__.pop(cached, None)
        return out

    # ------------------------------------------------------------- projection
    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """World points (N,3) -> camera-frame points (N,3)."""
        p = np.asarray(points_world, dtype=float).reshape(-1, 3)
        return (p - self._t) @ self._R

    def depth(self, points_world: np.ndarray) -> np.ndarray:
        """Camera-frame z (distance along the optical axis) of world points (N,3) -> (N,)."""
        return self.to_camera(points_world)[:, 2]

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixels (N,2) of world points (N,3), distorted when ``dist`` is set.

        Points at or behind the camera plane (depth <= 0) give NaN.
        """
        pc = self.to_camera(points_world)
        z = pc[:, 2]
        front = z > 0
        if self._dist is None and front.all():  # the same arithmetic as below, fewer copies
            return (pc[:, :2] / z[:, None]) @ self._K[:2, :2].T + self._K[:2, 2]
        out = np.full((len(pc), 2), np.nan)
        if not np.any(front):
            return out
        xn = pc[front, :2] / z[front, None]
        out[front] = self.normalized_to_pixels(xn)
        return out

    def normalized_to_pixels(self, xn: np.ndarray) -> np.ndarray:
        """Undistorted normalized image coordinates (N,2) -> pixels (N,2), applying ``dist``."""
        xn = np.asarray(xn, dtype=float).reshape(-1, 2)
        if self._dist is None:
            return xn @ self._K[:2, :2].T + self._K[:2, 2]
        obj = np.hstack([xn, np.ones((len(xn), 1))])
        px, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self._K, self._dist)
        return px.reshape(-1, 2)

    def pixels_to_normalized(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (N,2) -> undistorted normalized image coordinates (N,2) (inverse of the above)."""
        px = np.asarray(pixels, dtype=float).reshape(-1, 2)
        if self._dist is None:
            Kinv = np.linalg.inv(self._K)
            return px @ Kinv[:2, :2].T + Kinv[:2, 2]
        und = cv2.undistortPoints(px.reshape(-1, 1, 2), self._K, self._dist, criteria=_UNDISTORT_CRITERIA)
        return und.reshape(-1, 2)

    def undistort_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (N,2) -> ideal pinhole pixels (N,2), where conics from ``P`` apply."""
        xn = self.pixels_to_normalized(pixels)
        return xn @ self._K[:2, :2].T + self._K[:2, 2]

    def distort_pixels(self, ideal_pixels: np.ndarray) -> np.ndarray:
        """Ideal pinhole pixels (N,2) -> observed (distorted) pixels (N,2)."""
        px = np.asarray(ideal_pixels, dtype=float).reshape(-1, 2)
        if self._dist is None:
            return px.copy()
        Kinv = np.linalg.inv(self._K)
        return self.normalized_to_pixels(px @ Kinv[:2, :2].T + Kinv[:2, 2])

    def rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels (N,2) to unit world ray directions (N,3) and the centre (3,).

        Pixels are observed ones: with ``dist`` set they are undistorted first, so
        that ``project(centre + s * d)`` returns the pixel for every ``s > 0``.
        """
        xn = self.pixels_to_normalized(pixels)
        d = np.hstack([xn, np.ones((len(xn), 1))])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d @ self._R.T, self._t.copy()

    @cached_property
    def ray_grid(self) -> np.ndarray:
        """(H,W,3) camera-frame ray directions ``(x, y, 1)`` through every pixel centre.

        The third component is 1, so a point ``s * ray`` has depth ``s``.
        Undistorted when ``dist`` is set; computed once and cached (read-only).
        """
        v, u = np.mgrid[0 : self._height, 0 : self._width].astype(float)
        xn = self.pixels_to_normalized(np.stack([u.ravel(), v.ravel()], axis=1))
        grid = np.empty((self._height, self._width, 3))
        grid[..., :2] = xn.reshape(self._height, self._width, 2)
        grid[..., 2] = 1.0
        grid.flags.writeable = False
        return grid

    # ----------------------------------------------------------- constructors
    @classmethod
    def default(cls, width: int = 320, height: int = 240, fov_deg: float = 40.0) -> Camera:
        """Camera at the world origin looking along world +z with world +y up.

        ``world_R_camera = diag(-1, -1, 1)``; vertical field of view ``fov_deg``
        (over the full image height), square pixels, principal point at the
        image centre ``((width-1)/2, (height-1)/2)``.
        """
        K = _intrinsics(width, height, fov_deg)
        return cls(K, pin.SE3(np.diag([-1.0, -1.0, 1.0]), np.zeros(3)), width, height, name="default")

    @classmethod
    def look_at(
        cls,
        position: Sequence[float],
        target: Sequence[float],
        up: Sequence[float] = (0.0, 1.0, 0.0),
        width: int = 320,
        height: int = 240,
        fov_deg: float = 40.0,
        name: str = "",
    ) -> Camera:
        """Camera at ``position`` (world) with its optical axis towards ``target``.

        ``up`` (world) appears upwards in the image (towards smaller v); the
        intrinsics are as in :meth:`default`.
        """
        p = np.asarray(position, dtype=float)
        z = np.asarray(target, dtype=float) - p
        up_v = np.asarray(up, dtype=float)
        if np.linalg.norm(z) == 0:
            raise CameraError("look_at: position and target coincide")
        z /= np.linalg.norm(z)
        x = np.cross(z, up_v)
        if np.linalg.norm(x) < 1e-9 * max(np.linalg.norm(up_v), 1e-300):
            raise CameraError(f"look_at: up {up_v.tolist()} is parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z], axis=1)
        return cls(_intrinsics(width, height, fov_deg), pin.SE3(R, p), width, height, name=name)

    # -------------------------------------------------------------------- I/O
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the fields of the module docstring)."""
        d: dict[str, Any] = {}
        if self._name:
            d["name"] = self._name
        d["width"] = self._width
        d["height"] = self._height
        d["K"] = self._K.tolist()
        d["world_T_camera"] = {"rotation": self._R.tolist(), "translation": self._t.tolist()}
        if self._dist is not None:
            d["dist"] = self._dist.tolist()
        return d

    @classmethod
    def from_dict(cls, data: Any, source: str = "<dict>") -> Camera:
        """Build a camera from a dict; any problem is a CameraError naming ``source`` and field."""
        return _parse_camera(data, source)

    def to_json(self, path: str | Path) -> None:
        """Write this camera to ``path`` as one JSON object."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @staticmethod
    def list_to_json(cameras: Sequence[Camera], path: str | Path) -> None:
        """Write several cameras to ``path`` as a JSON list."""
        Path(path).write_text(json.dumps([c.to_dict() for c in cameras], indent=2) + "\n")

    @classmethod
    def from_json(cls, path: str | Path) -> Camera:
        """Read one camera (a JSON object) from ``path``."""
        data = read_json(path, CameraError, cannot_read="cannot read camera file")
        if isinstance(data, list):
            n = len(data)
            raise CameraError(f"{path}: holds a list of {n} camera{'' if n == 1 else 's'}, not a single camera")
        return _parse_camera(data, str(path))

    @classmethod
    def list_from_json(cls, path: str | Path) -> list[Camera]:
        """Read a JSON list of cameras (or a single camera object) from ``path``."""
        data = read_json(path, CameraError, cannot_read="cannot read camera file")
        if not isinstance(data, list):
            return [_parse_camera(data, str(path))]
        if not data:
            raise CameraError(f"{path}: the list of cameras is empty")
        return [_parse_camera(item, f"{path}[{i}]") for i, item in enumerate(data)]


# ---------------------------------------------------------------- validation
def _intrinsics(width: int, height: int, fov_deg: float) -> np.ndarray:
    if not (0 < fov_deg < 180):
        raise CameraError(f"camera: field of view must be in (0, 180) degrees, got {fov_deg}")
    f = (height / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _matrix(value: Any, shape: tuple[int, ...], where: str, field: str, expect: str) -> np.ndarray:
    """Convert ``value`` to a finite float array of ``shape`` or raise CameraError."""
    if isinstance(value, np.ndarray):
        ok = value.shape == shape and value.dtype.kind in "iuf"
        arr = value.astype(float) if ok else None
    else:
        arr = _nested_numbers(value, shape)
        ok = arr is not None
    if not ok or arr is None:
        raise CameraError(f"{where}: field '{field}' must be {expect}")
    if not np.all(np.isfinite(arr)):
        raise CameraError(f"{where}: field '{field}' must contain finite numbers")
    return arr


def _nested_numbers(value: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    if len(shape) == 1:
        if not isinstance(value, (list, tuple)) or len(value) != shape[0]:
            return None
        if not all(_is_number(x) for x in value):
            return None
        return np.array(value, dtype=float)
    if not isinstance(value, (list, tuple)) or len(value) != shape[0]:
        return None
    rows = [_nested_numbers(r, shape[1:]) for r in value]
    if any(r is None for r in rows):
        return None
    return np.stack(rows)  # type: ignore[arg-type]


def _within(values: np.ndarray, bound: float, where: str, field: str, unit: str) -> np.ndarray:
    if np.max(np.abs(values)) > bound:
        raise CameraError(f"{where}: field '{field}' must be within +-{bound:g}{unit}, got {values.tolist()}")
    return values


def _check_translation(t: np.ndarray, where: str) -> np.ndarray:
    return _within(t, MAX_COORDINATE, where, "world_T_camera.translation", " (world units)")


def _check_K(K: np.ndarray, where: str) -> np.ndarray:
    if (
        np.max(np.abs(K[2] - [0.0, 0.0, 1.0])) > 1e-12
        or abs(K[1, 0]) > 1e-12
        or abs(K[0, 1]) > 1e-12
        or K[0, 0] <= 0
        or K[1, 1] <= 0
    ):
        raise CameraError(
            f"{where}: field 'K' must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] "
            f"with positive focal lengths fx, fy (no skew: OpenCV ignores it), got {K.tolist()}"
        )
    if not (MIN_FOCAL <= K[0, 0] <= MAX_COORDINATE and MIN_FOCAL <= K[1, 1] <= MAX_COORDINATE):
        raise CameraError(f"{where}: field 'K': focal lengths fx, fy must be in [{MIN_FOCAL:g}, {MAX_COORDINATE:g}] "
                          f"pixels, got {K[0, 0]:g}, {K[1, 1]:g}")
    _within(K[:2, 2], MAX_COORDINATE, where, "K", " pixels for the principal point cx, cy")
    return K


def _check_rotation(R: np.ndarray, where: str, field: str) -> np.ndarray:
    R = _matrix(R, (3, 3), where, field, "a 3x3 matrix of numbers")
    err, det = rotation_error(R)
    if err > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise CameraError(
            f"{where}: field '{field}' is not a rotation matrix "
            f"(max |R R^T - I| = {err:.3g}, det = {det:.6g}; tolerance {ROTATION_TOL:g})"
        )
    return R


def _check_size(value: Any, where: str, field: str) -> int:
    if isinstance(value, (np.integer,)):
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
        raise CameraError(f"{where}: field '{field}' must be a positive integer, got {value!r}")
    if value > MAX_IMAGE_SIDE:
        raise CameraError(f"{where}: field '{field}' is {value} pixels; images of at most {MAX_IMAGE_SIDE} "
                          "pixels a side are supported")
    return value


def _check_dist(value: Any, where: str) -> np.ndarray:
    expect = "a list of 4, 5, 8, 12 or 14 numbers (k1, k2, p1, p2[, k3, ...])"
    if isinstance(value, np.ndarray):
        arr = value.astype(float).ravel() if value.dtype.kind in "iuf" else None
    else:
        ok = isinstance(value, (list, tuple)) and all(_is_number(x) for x in value)
        arr = np.array(value, dtype=float) if ok else None
    if arr is None or len(arr) not in DIST_LENGTHS:
        raise CameraError(f"{where}: field 'dist' must be {expect}")
    if not np.all(np.isfinite(arr)):
        raise CameraError(f"{where}: field 'dist' must contain finite numbers")
    return _within(arr, MAX_COORDINATE, where, "dist", "")


def _parse_camera(data: Any, where: str) -> Camera:
    if not isinstance(data, dict):
        raise CameraError(f"{where}: a camera must be a JSON object, got {type(data).__name__}")
    for key in data:
        if key not in FIELDS:
            raise CameraError(f"{where}: unknown field '{key}'{did_you_mean(str(key), FIELDS)}")
    for key in ("width", "height", "K", "world_T_camera"):
        if key not in data:
            raise CameraError(f"{where}: missing field '{key}'")
    name = data.get("name", "")
    if not isinstance(name, str):
        raise CameraError(f"{where}: field 'name' must be a string")
    if name:
        where = f"{where} (camera '{name}')"
    width = _check_size(data["width"], where, "width")
    height = _check_size(data["height"], where, "height")
    K = _check_K(_matrix(data["K"], (3, 3), where, "K", "a 3x3 matrix of numbers"), where)
    pose = data["world_T_camera"]
    if not isinstance(pose, dict):
        raise CameraError(f"{where}: field 'world_T_camera' must be an object with 'rotation' and 'translation'")
    for key in pose:
        if key not in ("rotation", "translation"):
            hint = did_you_mean(str(key), ("rotation", "translation"))
            raise CameraError(f"{where}: unknown field 'world_T_camera.{key}'{hint}")
    for key in ("rotation", "translation"):
        if key not in pose:
            raise CameraError(f"{where}: missing field 'world_T_camera.{key}'")
    R = _check_rotation(pose["rotation"], where, "world_T_camera.rotation")
    t = _check_translation(_matrix(pose["translation"], (3,), where, "world_T_camera.translation",
                                  "a list of 3 numbers"), where)
    dist = data.get("dist")
    if dist is not None:
        dist = _check_dist(dist, where)
    return Camera(K, pin.SE3(R, t), width, height, dist=dist, name=name)
