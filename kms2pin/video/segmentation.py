"""Figure-ground segmentation by adaptive background subtraction (thesis §2.1.2).

The tracker's input is "a figure-ground segmentation which labels each pixel
as belonging either to the rigid body system or to the background".  This
module produces it from a static-camera video with OpenCV's adaptive
per-pixel background models (``mog2``: Zivkovic's Gaussian mixture, the
default; ``knn``: Zivkovic's K-nearest-neighbour samples), both with shadow
detection on (shadow pixels, value 127, count as background).

Pipeline, per frame:

1. **Learning** from ``learn_frames`` frames (default 30), either spread
   evenly over the whole sequence (``learn_from="spread"``, the default: the
   input is read twice) or the first ones (``"start"``: one pass, for streams).
   Their per-pixel temporal median is a first guess of the empty scene, and
   pixels that differ from it by more than ``bootstrap_diff`` grey levels (the
   moving subject, dilated by 3 pixels) are replaced by the median.  These
   cleaned frames train the model with a high learning rate (``1/(k+1)`` for
   the k-th, i.e. a running average, two passes), so the model learns the real
   noise and flicker of the background but not the subject - provided that
   every pixel shows the background in more than half of the learning frames
   (a subject that stands still there is learnt as background).
2. **Masks for every frame**: with ``"spread"`` every frame is then segmented
   in order, from the first; with ``"start"`` the learning frames are
   segmented again, with the trained model frozen (learning rate 0), before the
   rest - so every frame, including the first, gets a proper mask either way;
   nothing is flagged.
3. **Adaptation**: the frames after the learning frames (every frame with
   ``"spread"``) also update the model, at ``learning_rate``
   (default ``1/history``, history 500 frames: a subject that stands still
   for about ``0.7 * history`` frames fades into the background).
4. **Clean-up** of every mask: shadows dropped; morphological opening
   (elliptical ``open_size`` kernel, default 3x3) removes speckle, closing
   (``close_size``, default 5x5) bridges small gaps; connected components
   smaller than ``min_blob_area`` pixels are removed (default 0.1 % of the
   image, 77 px at 320x240); holes inside the silhouette (background regions
   not connected to the image border) are filled (``fill_holes``).

With ``learn_frames=0`` the model starts empty and learns online (OpenCV's
own schedule) - early masks are then poor.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputDataError

METHODS = ("mog2", "knn")
DEFAULT_METHOD = "mog2"
LEARN_FROM = ("spread", "start")
DEFAULT_THRESHOLD = {"mog2": 16.0, "knn": 400.0}  # OpenCV's own defaults
SHADOW = 127


@dataclass(frozen=True)
class SegmentParams:
    """Parameters of :func:`segment_frames` (see the module docstring)."""

    method: str = DEFAULT_METHOD
    learn_frames: int = 30
    learn_from: str = "spread"  # or "start"
    history: int = 500
    threshold: float | None = None  # MOG2 varThreshold / KNN dist2Threshold
    learning_rate: float | None = None  # None: 1/history
    min_blob_area: int | None = None  # None: 0.1 % of the image
    open_size: int = 3
    close_size: int = 5
    fill_holes: bool = True
    detect_shadows: bool = True
    bootstrap_diff: float = 30.0

    def check(self) -> None:
        if self.method not in METHODS:
            raise InputDataError(f"unknown segmentation method '{self.method}'; choose one of {', '.join(METHODS)}")
        if self.learn_from not in LEARN_FROM:
            raise InputDataError(f"unknown learn_from '{self.learn_from}'; choose one of {', '.join(LEARN_FROM)}")
        if self.learn_frames < 0:
            raise InputDataError(f"learn_frames must be >= 0, got {self.learn_frames}")
        if self.history < 1:
            raise InputDataError(f"history must be >= 1, got {self.history}")
        if self.threshold is not None and not self.threshold > 0:
            raise InputDataError(f"threshold must be > 0, got {self.threshold}")
        if self.learning_rate is not None and not 0 <= self.learning_rate <= 1:
            raise InputDataError(f"learning_rate must be in [0, 1], got {self.learning_rate}")
        if self.min_blob_area is not None and self.min_blob_area < 0:
            raise InputDataError(f"min_blob_area must be >= 0, got {self.min_blob_area}")
        for name in ("open_size", "close_size"):
            if getattr(self, name) < 0:
                raise InputDataError(f"{name} must be >= 0, got {getattr(self, name)}")


def default_min_blob_area(shape: tuple[int, ...]) -> int:
    """0.1 % of the image area (77 px at 320x240, 307 px at 640x480)."""
    return max(1, round(0.001 * shape[0] * shape[1]))


def make_subtractor(params: SegmentParams) -> cv2.BackgroundSubtractor:
    """A fresh OpenCV background model for ``params``."""
    thr = DEFAULT_THRESHOLD[params.method] if params.threshold is None else float(params.threshold)
    if params.method == "mog2":
        return cv2.createBackgroundSubtractorMOG2(
            history=params.history, varThreshold=thr, detectShadows=params.detect_shadows
        )
    return cv2.createBackgroundSubtractorKNN(
        history=params.history, dist2Threshold=thr, detectShadows=params.detect_shadows
    )


def _kernel(size: int) -> np.ndarray | None:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)) if size > 1 else None


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """Fill background regions of a 0/255 mask that do not touch the image border."""
    h, w = mask.shape
    padded = np.zeros((h + 2, w + 2), np.uint8)
    padded[1:-1, 1:-1] = mask
    ff_mask = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(padded, ff_mask, (0, 0), 255)  # everything reachable from outside
    holes = cv2.bitwise_not(padded[1:-1, 1:-1])
    return cv2.bitwise_or(mask, holes)


def remove_small_blobs(mask: np.ndarray, min_area: int) -> np.ndarray:
    """Drop 8-connected components of a 0/255 mask with fewer than ``min_area`` pixels."""
    if min_area <= 1:
        return mask
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return mask
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area
    keep[0] = False
    if keep[1:].all():
        return mask
    return np.where(keep[labels], 255, 0).astype(np.uint8)


def clean_mask(raw: np.ndarray, params: SegmentParams, min_area: int) -> np.ndarray:
    """Post-process a raw subtractor output (0 / 127 shadow / 255) into a 0/255 mask."""
    _, m = cv2.threshold(raw, SHADOW + 1, 255, cv2.THRESH_BINARY)  # shadows (127) -> background
    k = _kernel(params.open_size)
    if k is not None:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, k)
    k = _kernel(params.close_size)
    if k is not None:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    m = remove_small_blobs(m, min_area)
    if params.fill_holes:
        m = fill_holes(m)
    return m


def _as_bgr(frame: np.ndarray, index: int) -> np.ndarray:
    a = np.asarray(frame)
    if a.dtype != np.uint8:
        raise InputDataError(f"frame {index}: expected a uint8 image, got dtype {a.dtype}")
    if a.ndim == 2:
        return cv2.cvtColor(a, cv2.COLOR_GRAY2BGR)
    if a.ndim == 3 and a.shape[2] == 3:
        return a
    if a.ndim == 3 and a.shape[2] == 4:
        return cv2.cvtColor(a, cv2.COLOR_BGRA2BGR)
    if a.ndim == 3 and a.shape[2] == 1:
        return cv2.cvtColor(a[:, :, 0], cv2.COLOR_GRAY2BGR)
    raise InputDataError(f"frame {index}: expected an (H, W) or (H, W, 3) image, got shape {a.shape}")


def bootstrap_frames(frames: list[np.ndarray], diff: float) -> list[np.ndarray]:
    """Learning frames with the moving subject replaced by the temporal median (module docstring)."""
    if len(frames) < 3:
        return frames
    stack = np.stack(frames)
    median = np.median(stack, axis=0).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    out = []
    for f in frames:
        d = cv2.absdiff(f, median).max(axis=2)
        moving = (d > diff).astype(np.uint8)
        moving = cv2.dilate(moving, kernel)
        g = f.copy()
        g[moving > 0] = median[moving > 0]
        out.append(g)
    return out


class Segmenter:
    """Stateful frame-by-frame segmentation (used by :func:`segment_frames`).

    ``learn(frames)`` trains on the learning frames; ``segment(frame, rate)``
    returns one 0/255 mask.
    """

    def __init__(self, params: SegmentParams):
        params.check()
        self.params = params
        self.model = make_subtractor(params)
        self.shape: tuple[int, int] | None = None
        self.min_area: int | None = params.min_blob_area
        self.rate = 1.0 / params.history if params.learning_rate is None else params.learning_rate

    def _check_shape(self, frame: np.ndarray, index: int) -> None:
        if self.shape is None:
            self.shape = frame.shape[:2]
            if self.min_area is None:
                self.min_area = default_min_blob_area(self.shape)
        elif frame.shape[:2] != self.shape:
            raise InputDataError(
                f"frame {index}: {frame.shape[1]}x{frame.shape[0]} pixels, but the first frame is "
                f"{self.shape[1]}x{self.shape[0]}"
            )

    def learn(self, frames: list[np.ndarray], epochs: int = 2) -> None:
        clean = bootstrap_frames(frames, self.params.bootstrap_diff)
        for _ in range(epochs):
            for k, f in enumerate(clean):
                self.model.apply(f, learningRate=1.0 / (k + 1))

    def segment(self, frame: np.ndarray, rate: float | None = None) -> np.ndarray:
        raw = self.model.apply(frame, learningRate=self.rate if rate is None else rate)
        assert self.min_area is not None
        return clean_mask(raw, self.params, self.min_area)


def sample_evenly(frames: Iterable, count: int) -> list[np.ndarray]:
    """About ``count`` (between count and 2 count) frames spread evenly over an iterable
    of unknown length, in bounded memory (keep every s-th frame, doubling s when full)."""
    kept: list[np.ndarray] = []
    stride = 1
    for k, item in enumerate(frames):
        frame = _as_bgr(item[1] if isinstance(item, tuple) else item, k)
        if k % stride == 0:
            kept.append(frame)
            if len(kept) >= 2 * count:
                kept = kept[::2]
                stride *= 2
    return kept


def segment_frames(
    frames: Iterable[np.ndarray | tuple[int, np.ndarray]],
    method: str = DEFAULT_METHOD,
    learn_frames: int = 30,
    learn_from: str = "spread",
    **kwargs,
) -> Iterator[np.ndarray]:
    """Figure-ground masks ``(H, W)`` bool, one per frame, in order.

    ``frames``: BGR (or grey) ``uint8`` images, or ``(index, image)`` pairs as
    from :func:`kms2pin.video.read_frames`.  ``learn_from``: ``"spread"`` (the
    default) trains the background on ``learn_frames`` frames spread evenly over
    the whole sequence, so ``frames`` is read twice and must be re-iterable (a
    list, or a :class:`~kms2pin.video.FrameSource` from :func:`open_frames`);
    ``"start"`` trains on the first ``learn_frames`` frames and then re-segments
    them (one pass, any iterator, e.g. a live stream).  Other keyword arguments
    are the fields of :class:`SegmentParams` (``history``, ``threshold``,
    ``learning_rate``, ``min_blob_area``, ``open_size``, ``close_size``,
    ``fill_holes``, ``detect_shadows``, ``bootstrap_diff``).
    """
    params = SegmentParams(method=method, learn_frames=learn_frames, learn_from=learn_from, **kwargs)
    yield from (m > 0 for m in _segment_u8(frames, params))


def _segment_u8(frames: Iterable, params: SegmentParams) -> Iterator[np.ndarray]:
    seg = Segmenter(params)
    if params.learn_from == "spread" and params.learn_frames > 0:
        if iter(frames) is frames:
            raise InputDataError(
                "learn_from='spread' reads the frames twice: pass a list or open_frames(path), "
                "not a one-shot iterator (or use learn_from='start')"
            )
        sample = sample_evenly(frames, params.learn_frames)
        if sample:
            seg._check_shape(sample[0], 0)
            seg.learn(sample)
        for k, item in enumerate(frames):
            index, frame = item if isinstance(item, tuple) else (k, item)
            frame = _as_bgr(frame, index)
            seg._check_shape(frame, index)
            yield seg.segment(frame)
        return
    buffer: list[np.ndarray] = []
    learning = params.learn_frames > 0
    for k, item in enumerate(frames):
        index, frame = item if isinstance(item, tuple) else (k, item)
        frame = _as_bgr(frame, index)
        seg._check_shape(frame, index)
        if learning:
            buffer.append(frame)
            if len(buffer) < params.learn_frames:
                continue
            seg.learn(buffer)
            for f in buffer:
                yield seg.segment(f, rate=0.0)
            buffer = []
            learning = False
            continue
        yield seg.segment(frame, rate=None if params.learn_frames > 0 else -1.0)
    if learning and buffer:  # fewer frames than learn_frames: learn from them all
        seg.learn(buffer)
        for f in buffer:
            yield seg.segment(f, rate=0.0)
