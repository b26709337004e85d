"""The silhouette fit: how well a pose's inner ellipsoids cover the masks.

One measure serves the tracker (:attr:`FrameResult.fit`, the running fit, the
hypotheses and the limb search), the automatic initialization and re-acquisition:
the intersection over union of the model's silhouette (the pixels whose ray passes
through some inner ellipsoid, at the pixel centre) with the masks, pooled over the
cameras.  Two empty sets agree: an empty union is a fit of 1.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import pinocchio as pin

from ..native import kernels
from ..robot import Robot
from .camera import Camera
from .mstep import body_box_arrays, body_images, closest_approach, pose_arrays, world_rays
from .projection import BBox, body_bbox

__all__ = ["IncrementalFit", "PoseCache", "body_coverage", "body_silhouettes", "group_counts", "model_silhouette", "silhouette_counts", "silhouette_iou", "visible_bodies"]


class _Poses(Sequence):
    """The bodies' poses (world) as a sequence of ``pin.SE3`` made when first read from
    rotations ``Rs`` (n, 3, 3) and centres ``ts`` (n, 3): the packed iteration reads
    only the arrays."""

    def __init__(self, Rs: np.ndarray, ts: np.ndarray):
        self._Rs, self._ts = Rs, ts
        self._made: list[pin.SE3 | None] = [None] * len(Rs)

    def __len__(self) -> int:
        return len(self._made)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        P = self._made[i]
        if P is None:
            P = self._made[i] = pin.SE3(self._Rs[i], self._ts[i])
        return P


class PoseCache:
    """The body poses at a configuration and their arrays, kept for the
    last configuration asked for: an iteration's outline test, the next iteration's
    E-step and the frame's fit all want the same ones."""

    def __init__(self, robot: Robot):
        self.robot = robot
        self._last: tuple | None = None

    def __call__(self, q: np.ndarray) -> tuple[Sequence[pin.SE3], np.ndarray, np.ndarray]:
        """(poses, rotations (n, 3, 3), centres (n, 3)) of the bodies at ``q`` (world); the
        arrays are :meth:`Robot.body_pose_arrays`, the poses made from them when read."""
        key = np.asarray(q, dtype=float).tobytes()
        if self._last is None or self._last[0] != key:
            Rs, ts = self.robot.body_pose_arrays(q)
            self._last = (key, _Poses(Rs, ts), Rs, ts)
        return self._last[1:]


def body_silhouettes(camera: Camera, poses: Sequence[pin.SE3], inner: np.ndarray,
                     arrays: tuple[np.ndarray, np.ndarray] | None = None) -> Iterator[tuple[int, BBox, np.ndarray]]:
    """Per body in view: (its index, its image box, the box's pixels (bool) whose centre's
    ray meets its inner ellipsoid); bodies at ``poses``, semi-axes ``inner`` (n, 3);
    ``arrays``: their :func:`pose_arrays`."""
    images = body_images(camera, poses, inner, 0.5, slack_px=0.0, max_pixels=10**9, arrays=arrays)
    for i, (P, li, img) in enumerate(zip(poses, inner, images)):
        if img is not None:  # stride 1: every pixel of the box
            a2, _ = closest_approach(img, P.rotation, P.translation, li, False)
            yield i, img.box, (a2 <= 1.0).reshape(img.shape)


def _union_args(camera: Camera, Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray) -> tuple | None:
    """The ``silhouette_union`` kernel's metrics (n, 9), camera centres relative to the
    bodies (n, 3) and boxes (n, 4: u0, v0, u1, v1; empty: out of view), the boxes of
    :func:`body_silhouettes`, of the bodies at rotations ``Rs`` (n, 3, 3) and centres
    ``ts`` (n, 3); None when one needs :func:`body_images`' per-body path (a distorted
    camera, a body straddling the camera plane)."""
    if camera.dist is not None:
        return None
    status, boxes, _ = body_box_arrays(camera, Rs, ts, inner, 0.5, 0.0)
    if (status == 1).any():
        return None
    boxes[status != 2] = 0.0
    As = (Rs / inner[:, None, :] ** 2) @ Rs.transpose(0, 2, 1)
    return As.reshape(-1, 9), camera.centre - ts, boxes


def model_silhouette(camera: Camera, poses: Sequence[pin.SE3], inner: np.ndarray,
                     arrays: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(H, W) bool: the pixels of ``camera`` whose centre's ray meets an inner ellipsoid
    (:func:`body_silhouettes`)."""
    model = np.zeros(camera.shape, dtype=bool)
    if len(poses):
        Rs, ts = pose_arrays(poses) if arrays is None else arrays
        args = _union_args(camera, Rs, ts, np.asarray(inner, dtype=float).reshape(len(poses), 3))
        if args is not None:
            kernels.silhouette_union(world_rays(camera), *args, model)
            return model
    for _, b, sil in body_silhouettes(camera, poses, inner, arrays):
        model[b.v0 : b.v1, b.u0 : b.u1] |= sil
    return model


def group_counts(camera: Camera, Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray, on: np.ndarray,
                 off: np.ndarray) -> np.ndarray:
    """(K, 2) int: :func:`silhouette_counts` of K groups of m bodies at rotations ``Rs``
    (K, m, 3, 3) and centres ``ts`` (K, m, 3), semi-axes ``inner`` (m, 3)."""
    K, m = ts.shape[:2]
    inners = np.tile(np.asarray(inner, dtype=float).reshape(m, 3), (K, 1))
    args = _union_args(camera, Rs.reshape(K * m, 3, 3), ts.reshape(K * m, 3), inners)
    if args is None:
        return np.array([_counts_per_body(camera, [pin.SE3(R, t) for R, t in zip(Rs[k], ts[k])], inner, on, off,
                                          (Rs[k], ts[k])) for k in range(K)], dtype=int).reshape(K, 2)
    counts = np.empty((K, 2))
    kernels.silhouette_counts(world_rays(camera), *args, np.arange(0, K * m + 1, m, dtype=float), on, off, counts)
    return counts.astype(int)


def silhouette_counts(camera: Camera, poses: Sequence[pin.SE3], inner: np.ndarray, on: np.ndarray,
                      off: np.ndarray, arrays: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[int, int]:
    """How many pixels of the bodies' silhouette (as :func:`model_silhouette`) fall where
    ``on`` and where ``off`` (bool images) hold, counted within the bodies' image boxes
    only."""
    if not len(poses):
        return 0, 0
    Rs, ts = pose_arrays(poses) if arrays is None else arrays
    on_, off_ = group_counts(camera, Rs[None], ts[None], inner, on, off)[0].tolist()
    return on_, off_


def _counts_per_body(camera: Camera, poses: Sequence[pin.SE3], inner: np.ndarray, on: np.ndarray, off: np.ndarray,
                     arrays: tuple[np.ndarray, np.ndarray]) -> tuple[int, int]:
    """:func:`silhouette_counts` by :func:`body_silhouettes` (any camera, any body)."""
    parts = list(body_silhouettes(camera, poses, inner, arrays))
    if not parts:
        return 0, 0
    v0, v1 = min(b.v0 for _, b, _ in parts), max(b.v1 for _, b, _ in parts)
    u0, u1 = min(b.u0 for _, b, _ in parts), max(b.u1 for _, b, _ in parts)
    union = np.zeros((v1 - v0, u1 - u0), dtype=bool)
    for _, b, sil in parts:
        union[b.v0 - v0 : b.v1 - v0, b.u0 - u0 : b.u1 - u0] |= sil
    return int(np.count_nonzero(union & on[v0:v1, u0:u1])), int(np.count_nonzero(union & off[v0:v1, u0:u1]))


def body_coverage(camera: Camera, poses: Sequence[pin.SE3], inner: np.ndarray, mask: np.ndarray,
                  arrays: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(n, 2) per body: the pixels of its own silhouette in ``camera`` (as in
    :func:`model_silhouette`) and how many of them ``mask`` (bool) holds."""
    out = np.zeros((len(poses), 2), dtype=int)
    for i, b, sil in body_silhouettes(camera, poses, inner, arrays):
        out[i] = np.count_nonzero(sil), np.count_nonzero(sil & mask[b.v0 : b.v1, b.u0 : b.u1])
    return out


def silhouette_iou(poses: Sequence[pin.SE3], inner: np.ndarray, cameras: Sequence[Camera],
                   masks: Sequence[np.ndarray], arrays: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """The intersection over union of the bodies' silhouettes with ``masks`` (bool, one
    per camera), pooled over the cameras (1 for an empty union)."""
    arrays = pose_arrays(poses) if arrays is None else arrays
    inter = union = 0
    for cam, mask in zip(cameras, masks):
        model = model_silhouette(cam, poses, inner, arrays)
        inter += int(np.count_nonzero(model & mask))
        union += int(np.count_nonzero(model | mask))
    return inter / union if union else 1.0


def visible_bodies(poses: Sequence[pin.SE3], inner: np.ndarray, cameras: Sequence[Camera]) -> list[int]:
    """Indices of the bodies whose inner silhouette falls in at least one camera."""
    return [i for i, P in enumerate(poses) if any(body_bbox(c, P, inner[i], 0) is not None for c in cameras)]


class IncrementalFit:
    """:func:`silhouette_iou` of ``robot``'s poses against one frame's ``masks`` (bool, one
    per camera), the bodies' semi-axes ``inner``, for trials that each differ from a
    *base* pose (:meth:`rebase`) in a few bodies (a limb's part taken from elsewhere):
    the same counts to the pixel, from the moved bodies alone.

    The base is kept per camera as a count image (how many bodies' silhouettes cover
    each pixel, ``silhouette_add``); a trial's counts are the base's with the moved
    bodies' pixels at the base taken out and theirs at the trial painted in, over the box
    that holds both (``silhouette_swap``).  A body has moved when its rotation or centre
    differs at all.  A camera with lens distortion, a body across a camera's plane, or
    more than 255 bodies on a pixel: :func:`silhouette_iou` itself.
    """

    def __init__(self, robot: Robot, cameras: Sequence[Camera], masks: Sequence[np.ndarray], inner: np.ndarray):
        self.robot, self.cameras = robot, list(cameras)
        self.masks = [np.ascontiguousarray(m, dtype=bool) for m in masks]
        self.inner = np.array(inner, dtype=float).reshape(-1, 3)  # a copy: the tracker's sizes change in place
        self._key: bytes | None = None

    def _full(self, Rs: np.ndarray, ts: np.ndarray) -> float:
        return silhouette_iou(_Poses(Rs, ts), self.inner, self.cameras, self.masks, (Rs, ts))

    def rebase(self, q: np.ndarray) -> float:
        """Make ``q`` the pose the trials are counted from; returns its fit."""
        q = np.asarray(q, dtype=float)
        key = q.tobytes()
        if key == self._key:
            return self._fit
        Rs, ts = self.robot.body_pose_arrays(q)
        cams: list[tuple] | None = []  # per camera: the kernels' arguments, the count image
        inter = union = 0
        for cam, mask in zip(self.cameras, self.masks):
            args = _union_args(cam, Rs, ts, self.inner)
            counts = np.zeros(cam.shape, dtype=np.uint8)
            try:
                if args is not None:
                    kernels.silhouette_add(world_rays(cam), *args, counts)
            except ValueError:  # more than 255 bodies on a pixel
                args = None
            if args is None:
                cams = None
                break
            cams.append((args, counts))
            covered = counts != 0
            inter += int(np.count_nonzero(covered & mask))
            union += int(np.count_nonzero(covered | mask))
        fit = self._full(Rs, ts) if cams is None else (inter / union if union else 1.0)
        # the new base is set whole, last: a base half made is never used
        self._Rs, self._ts, self._cams, self._inter, self._union, self._fit = Rs, ts, cams, inter, union, fit
        self._key = key
        return fit

    def __call__(self, q: np.ndarray) -> float:
        """The fit at ``q`` (:func:`silhouette_iou`), counted from the base (:meth:`rebase`
        first)."""
        if self._key is None:
            raise RuntimeError("IncrementalFit: call rebase() before scoring a trial")
        Rs, ts = self.robot.body_pose_arrays(np.asarray(q, dtype=float))
        if self._cams is None:
            return self._full(Rs, ts)
        moved = np.flatnonzero((Rs != self._Rs).any(axis=(1, 2)) | (ts != self._ts).any(axis=1))
        if not len(moved):
            return self._fit
        inter, union = self._inter, self._union
        for cam, mask, (args, counts) in zip(self.cameras, self.masks, self._cams):
            new = _union_args(cam, Rs[moved], ts[moved], self.inner[moved])
            if new is None:
                return self._full(Rs, ts)
            old = (args[0][moved], args[1][moved], args[2][moved])
            d_inter, d_union = kernels.silhouette_swap(world_rays(cam), *old, *new, counts, mask)
            inter += d_inter
            union += d_union
        return inter / union if union else 1.0
