"""The tracker's E-step (thesis §2.1.2): the union of the bodies' sharp silhouettes.

In every camera each body's sharp silhouette ``s_j = σ(h_j)`` (:mod:`kms2pin.ecm.mstep`)
is evaluated at the current, kinematically valid pose, and every body learns how much
of each pixel the *others* explain, ``o_i = 1 - Π_{j≠i} (1 - s_j)`` (soft labels;
occlusion needs no depth order, a silhouette being the union of the bodies' images).
The union is accumulated as ``Σ_j log(1 - s_j)`` in a per-camera scratch image that is
re-zeroed over the bodies' boxes only.  With an outlier class (``outlier > 0``) each
pixel also gets its inlier responsibility ``p / (p + outlier)``, ``p`` its probability
under a union whose edge is at least ``outlier_px`` wide.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ..native import kernels
from .camera import Camera
from .mstep import SLACK_PX, BodyImage, BodyView, PackedViews, _frozen, body_box_arrays, body_images, world_rays
from .projection import BBox

__all__ = ["UnionEStep"]


class UnionEStep:
    """The E-step with its buffers: one scratch union image per camera and size.

    Args:
        max_pixels: pixels per body and camera above which a body's view is subsampled
            (every ``stride``-th row and column) for the M-step.
        outlier, outlier_px: the outlier class (0: off) and its least edge width (pixels).
        fused: do a camera in one kernel call (``estep_camera``) when it can (the same
            views as body by body).
        pack: let :meth:`packed` leave the views packed for the M-step's one kernel call
            (False: it returns None, and every iteration makes the views per body).

    :attr:`fused_cameras` counts the cameras the last call did in one kernel call.
    """

    def __init__(self, max_pixels: int, outlier: float = 0.0, outlier_px: float = 3.0, fused: bool = True,
                 pack: bool = True):
        self.max_pixels = int(max_pixels)
        self.outlier, self.outlier_px = float(outlier), float(outlier_px)
        self.fused, self.pack = bool(fused), bool(pack)
        self.fused_cameras = 0
        self._scratch: dict[tuple, np.ndarray] = {}

    def __call__(
        self, poses: Sequence[pin.SE3], Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray,
        cameras: Sequence[Camera], masks: Sequence[np.ndarray], delta_px: float,
    ) -> list[list[BodyView]]:
        """Every body's :class:`BodyView` per camera seeing it, the bodies at ``poses``
        (rotations ``Rs`` (n, 3, 3), centres ``ts`` (n, 3), world) with inner semi-axes
        ``inner`` (n, 3); ``masks`` bool or float64 fractions (binned), ``delta_px`` the
        edge width in pixels."""
        n = len(poses)
        As = (Rs / inner[:, None, :] ** 2) @ Rs.transpose(0, 2, 1)
        views: list[list[BodyView]] = [[] for _ in range(n)]
        self.fused_cameras = 0
        for c, (cam, mask) in enumerate(zip(cameras, masks)):
            log_free = self._zeroed(c, cam.shape)  # Σ_j log(1 - s_j)
            if self.fused and self.outlier <= 0 and cam.dist is None:
                fused = self._camera_fused(cam, mask, Rs, ts, As, inner, log_free, delta_px)
                if fused is not None:  # _camera below in one kernel call
                    self.fused_cameras += 1
                    for i, v in enumerate(fused):
                        if v is not None:
                            views[i].append(v)
                    self._scratch[c, cam.shape] = log_free
                    continue
            for i, v in enumerate(self._camera(cam, mask, poses, Rs, ts, As, inner, log_free, delta_px)):
                if v is not None:
                    views[i].append(v)
            self._scratch[c, cam.shape] = log_free
        return views

    def packed(self, Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray, cameras: Sequence[Camera],
               masks: Sequence[np.ndarray], delta_px: float) -> PackedViews | None:
        """The E-step of :meth:`__call__` with every camera in one kernel call, its views
        left packed for :func:`~kms2pin.ecm.mstep.fit_packed`; None where a camera needs
        the per-body path (an outlier class, a distorted camera, a body straddling a
        camera plane, a view above ``max_pixels``) or ``pack`` is off."""
        if not (self.fused and self.pack) or self.outlier > 0 or any(cam.dist is not None for cam in cameras):
            return None
        n = len(Rs)
        boxed = [_boxes(cam, Rs, ts, inner, delta_px) for cam in cameras]
        if any(b is None or (n and b[3].max() > self.max_pixels) for b in boxed):
            return None
        As = ((Rs / inner[:, None, :] ** 2) @ Rs.transpose(0, 2, 1)).reshape(n, 9)
        packs, inv, seen_all = [], np.zeros((len(cameras), n)), np.zeros((len(cameras), n))
        for c, (cam, mask, box) in enumerate(zip(cameras, masks, boxed)):
            log_free = self._zeroed(c, cam.shape)
            offset, dirs, sp, o, y, inv_c = _estep_camera(cam, mask, As, ts, box, log_free)
            self._scratch[c, cam.shape] = log_free
            packs.append((dirs, y, o, offset, cam.centre))
            seen = box[0]
            inv[c] = np.where(seen, inv_c, 0.0)  # the M-step's 1/(2δ), as BodyView's
            seen_all[c] = seen
        return PackedViews(packs, inv, seen_all)

    def _camera(self, cam, mask, poses, Rs, ts, As, inner, log_free, delta_px) -> list[BodyView | None]:
        """One camera's views, body by body."""
        n = len(poses)
        images: list = [None] * n
        log_free_o = np.zeros(cam.shape) if self.outlier > 0 else None
        widen = delta_px / max(delta_px, self.outlier_px)  # h at the outlier edge width
        # the union needs every pixel: the E-step works at full resolution
        body_imgs = body_images(cam, poses, inner, delta_px, max_pixels=10**9, arrays=(Rs, ts))
        es = cam.centre - ts
        for i, img in enumerate(body_imgs):
            if img is None:
                continue
            img.s = np.empty(len(img.dirs))  # softplus(h) = -log(1 - s)
            b = img.box
            kernels.estep_body(
                img.dirs, As[i], es[i], 1.0 / (2.0 * img.delta), log_free, b.v0, b.u0, b.v1 - b.v0, b.u1 - b.u0,
                img.s, log_free_o, widen,
            )
            images[i] = img
        weight = None
        if log_free_o is not None:
            # outlier class: p(y | model) of the union (edge >= outlier_px wide) against a
            # constant outlier density; inlier responsibility = p / (p + ε)
            miss = np.exp(log_free_o)  # 1 - M
            p_in = mask * (1.0 - miss) + (1.0 - mask) * miss  # mask: 0/1 or a fraction
            weight = p_in / (p_in + self.outlier)
        out: list[BodyView | None] = [None] * n
        for i, img in enumerate(images):
            if img is None:
                continue
            b = img.box
            o, y = np.empty(len(img.s)), np.empty(len(img.s))  # y: 0/1, or a binned fraction
            kernels.estep_view(log_free, mask, b.v0, b.u0, b.v1 - b.v0, b.u1 - b.u0, img.s, o, y)
            wt = None if weight is None else weight[img.slices].ravel()
            out[i] = self._subsampled(img, y, o, wt)
        for img in body_imgs:  # zeroed again for the next E-step
            if img is not None:
                log_free[img.slices] = 0.0
        return out

    def _camera_fused(self, cam: Camera, mask, Rs, ts, As, inner, log_free, delta_px: float) -> list | None:
        """One camera's E-step in one kernel call (``estep_camera``): every
        body's :class:`BodyView` (None: out of view), the same as the per-body kernels
        give; None when a body needs :func:`kms2pin.ecm.mstep.body_image`'s per-body
        path (straddling the camera plane or degenerate)."""
        n = len(Rs)
        box = _boxes(cam, Rs, ts, inner, delta_px)
        if box is None:
            return None
        seen, boxes, delta, _ = box
        offset, dirs, sp, o, y, _ = _estep_camera(cam, mask, As.reshape(n, 9), ts, box, log_free)
        out: list = [None] * n
        ib, off, dl = boxes.astype(int).tolist(), offset.astype(int).tolist(), delta.tolist()
        for i in np.flatnonzero(seen).tolist():
            a, b = off[i], off[i + 1]
            u0, v0, u1, v1 = ib[i]
            img = BodyImage(cam, _frozen(BBox, u0=u0, v0=v0, u1=u1, v1=v1), 1, dirs[a:b], dl[i], sp[a:b])
            out[i] = self._subsampled(img, y[a:b], o[a:b], None)
        return out

    def _zeroed(self, c: int, shape: tuple[int, int]) -> np.ndarray:
        """Camera ``c``'s scratch image of ``shape`` for the union, all zeros: the last
        E-step's, which re-zeroed it over the bodies' boxes only (a fresh 320x240 array
        a camera and iteration costs more than the boxes' pixels).  It is taken out
        until then, so an E-step that raised leaves none behind."""
        buf = self._scratch.pop((c, shape), None)
        return buf if buf is not None else np.zeros(shape)

    def scratch_images(self) -> list[np.ndarray]:
        """The scratch images kept for the next E-step (each all zeros between E-steps)."""
        return list(self._scratch.values())

    def _subsampled(self, img, y: np.ndarray, o: np.ndarray, weight: np.ndarray | None) -> BodyView:
        """The M-step's view of a full-resolution body image: every ``stride``-th row and
        column when the box holds more than ``max_pixels`` pixels."""
        if len(y) <= self.max_pixels:  # the usual case, once per body, camera and iteration
            return _frozen(BodyView, image=img, y=y, o=o, weight=weight)
        rows, cols = img.shape
        stride = max(1, int(np.ceil(np.sqrt(rows * cols / self.max_pixels))))
        if stride == 1:
            return _frozen(BodyView, image=img, y=y, o=o, weight=weight)
        b = img.box
        rays = world_rays(img.camera)[b.v0 : b.v1 : stride, b.u0 : b.u1 : stride].reshape(-1, 3)
        sub = BodyImage(img.camera, b, stride, rays, img.delta)

        def pick(a):
            return np.ascontiguousarray(a.reshape(rows, cols)[::stride, ::stride]).ravel()

        return BodyView(sub, pick(y), pick(o), None if weight is None else pick(weight))


def _boxes(cam: Camera, Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray, delta_px: float) -> tuple | None:
    """The bodies' boxes in an undistorted camera (:func:`body_box_arrays`) as the
    ``estep_camera`` kernel takes them: (in view (n,), boxes (n, 4) with those out of view
    emptied, edge widths (n,), pixel counts (n,)); None when a body needs the per-body
    path (straddling the camera plane or degenerate)."""
    status, boxes, delta = body_box_arrays(cam, Rs, ts, inner, delta_px, SLACK_PX)
    if (status == 1).any():
        return None
    seen = status == 2
    boxes[~seen] = 0.0
    return seen, boxes, delta, (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])


def _estep_camera(cam: Camera, mask: np.ndarray, As: np.ndarray, ts: np.ndarray, box: tuple,
                  log_free: np.ndarray) -> tuple[np.ndarray, ...]:
    """One camera's E-step in one ``estep_camera`` call over the :func:`_boxes` ``box``
    (metrics ``As`` (n, 9), centres ``ts``), ``log_free`` its zeroed union image (zeroed
    again after): (offsets (n + 1,), then each body's pixels one after the other: rays
    (N, 3), ``softplus(h)``, ``o``, ``y``; then the bodies' ``1/(2δ)`` (n,), 1 out of view)."""
    seen, boxes, delta, counts = box
    offset = np.zeros(len(ts) + 1)
    np.cumsum(counts, out=offset[1:])
    N = int(offset[-1])
    dirs, sp, o, y = np.empty((N, 3)), np.empty(N), np.empty(N), np.empty(N)
    inv = np.where(seen, 0.5 / np.where(seen, delta, 1.0), 1.0)
    kernels.estep_camera(world_rays(cam), As, cam.centre - ts, inv, boxes, offset, np.ascontiguousarray(mask), log_free,
                         dirs, sp, o, y)
    return offset, dirs, sp, o, y, inv
