"""The tracker's image input: one silhouette mask per camera, checked, cleaned and binned.

A :class:`Views` pairs the cameras with their masks for one frame: the E-step, the
silhouette fit and the priors all take one, so that a frame where some cameras see
nothing (:meth:`Views.seeing`) or the masks binned 2x2 (:meth:`Views.binned`) are
just other views.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import InputDataError
from .camera import Camera

__all__ = ["NEARLY_FULL", "Views", "bin_mask", "check_masks", "median_clean", "mask_problem"]

#: a mask with more than this share of its pixels foreground says nothing of the pose (a
#: light switched on, a lens cap taken off, a background model that failed)
NEARLY_FULL = 0.9


def mask_problem(mask: np.ndarray) -> str | None:
    """Why a mask cannot drive the pose: ``"empty mask"``, ``"mask nearly full"`` (more
    than :data:`NEARLY_FULL` of it foreground), or None."""
    n = int(np.count_nonzero(mask))
    if n == 0:
        return "empty mask"
    if n > NEARLY_FULL * mask.size:
        return "mask nearly full"
    return None


def median_clean(mask: np.ndarray) -> np.ndarray:
    """3x3 median filter: removes isolated flipped pixels and 1-pixel specks and
    holes, smooths ragged outlines by a pixel."""
    return cv2.medianBlur(mask.astype(np.uint8), 3).astype(bool)


def bin_mask(mask: np.ndarray, factor: int = 2) -> np.ndarray:
    """The fraction of each ``factor`` x ``factor`` block of ``mask`` that is set
    (float64, the image of :meth:`Camera.binned`; a last partial block is dropped)."""
    f = int(factor)
    h, w = mask.shape[0] // f, mask.shape[1] // f
    if h == 0 or w == 0:
        return np.zeros((h, w))
    m = np.asarray(mask[: h * f, : w * f], dtype=np.float32)
    return cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)


def check_masks(masks, cameras: Sequence[Camera], source: str, clean: bool = False) -> list[np.ndarray]:
    """``masks`` (one (H, W) array per camera, or one array for one camera) as bool
    arrays, each checked against its camera's size (:class:`InputDataError` naming
    ``source`` and the camera) and median-cleaned if ``clean``."""
    if isinstance(masks, np.ndarray) and masks.ndim == 2:
        masks = [masks]
    masks = list(masks)
    if len(masks) != len(cameras):
        raise InputDataError(f"{source}: {len(masks)} masks for {len(cameras)} cameras")
    out = []
    for k, (m, cam) in enumerate(zip(masks, cameras)):
        m = np.asarray(m)
        if m.ndim != 2 or m.shape != cam.shape:
            size = f"{m.shape[1]}x{m.shape[0]}" if m.ndim == 2 else f"of shape {m.shape}"
            raise InputDataError(f"{source}: camera {k} mask is {size} but the camera is {cam.width}x{cam.height}")
        m = m.astype(bool) if m.dtype != bool else m
        if clean and m.any():
            m = median_clean(m)
        out.append(m)
    return out


@dataclass(frozen=True)
class Views:
    """One frame as the cameras see it: ``masks[k]`` is camera ``k``'s (bool, or
    float64 fractions when binned)."""

    cameras: tuple[Camera, ...]
    masks: tuple[np.ndarray, ...]
    #: :meth:`binned`'s result, made once per frame however many parts ask for it
    _binned: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def of(cls, cameras: Sequence[Camera], masks: Sequence[np.ndarray]) -> Views:
        return cls(tuple(cameras), tuple(masks))

    def __len__(self) -> int:
        return len(self.cameras)

    def seeing(self) -> Views:
        """Only the cameras whose mask can drive the pose (:func:`mask_problem`)."""
        seen = [mask_problem(m) is None for m in self.masks]
        return Views(tuple(c for c, s in zip(self.cameras, seen) if s), tuple(m for m, s in zip(self.masks, seen) if s))

    def binned(self, binned_cameras: dict[Camera, Camera]) -> Views | None:
        """The masks binned 2x2 with their binned cameras (``binned_cameras``: camera ->
        :meth:`Camera.binned`), or None if a camera is too small to bin."""
        cached = self._binned.get(id(binned_cameras))
        if cached is not None and cached[0] is binned_cameras:
            return cached[1]
        out = None
        if all(c in binned_cameras for c in self.cameras):
            out = Views(tuple(binned_cameras[c] for c in self.cameras), tuple(bin_mask(m) for m in self.masks))
        self._binned[id(binned_cameras)] = (binned_cameras, out)
        return out
