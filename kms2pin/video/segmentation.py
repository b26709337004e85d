"""Figure-ground segmentation by adaptive background subtraction (thesis §2.1.2).

The tracker's input is "a figure-ground segmentation which labels each pixel as
belonging either to the rigid body system or to the background".  This module makes
it from a static-camera video with OpenCV's adaptive per-pixel background models
(``mog2``, the default, or ``knn``), per frame:

1. **learning** from ``learn_frames`` frames (spread over the video, or the first
   ones), cleaned of the moving subject with their per-pixel temporal mode
   (:func:`temporal_mode`);
2. **gain**: a frame whose per-channel gain against the background is more than
   ``GAIN_DEADBAND`` from 1 is divided by it (:func:`channel_gains`: automatic
   exposure, white balance);
3. **adaptation** of the models at ``learning_rate``;
4. **edge refinement** on luminance (lossy codecs bleed colour a pixel into the
   background);
5. **clean-up**: shadows dropped (a pixel keeping at least ``shadow_threshold`` of
   the background's brightness), opening, closing, small blobs removed, holes filled;
6. **a check** for regions foreground in 90 % of the frames
   (:class:`StaticForegroundWarning`).

Each step's reasons and measurements: docs/design/segmentation.md.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..errors import InputDataError


class StaticForegroundWarning(UserWarning):
    """Part of the image is foreground in nearly every frame: the background model did
    not learn it (module docstring, step 6)."""


#: share of the frames in which a pixel must be foreground to count as static foreground
STATIC_SHARE = 0.9
#: fewest frames for the static-foreground check
STATIC_MIN_FRAMES = 20

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
    close_size: int = 3
    fill_holes: bool = True
    detect_shadows: bool = True
    shadow_threshold: float = 0.5  # a shadow keeps at least this fraction of the background's brightness
    bootstrap_diff: float = 30.0
    mode_tolerance: float = 20.0  # grey levels: learning frames that agree on the background (temporal_mode)
    refine_edges: bool = True
    edge_contrast: float = 4.0  # grey levels
    compensate_gain: bool = True  # divide each frame by its per-channel gain against the background

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
        if not 0.0 < self.shadow_threshold < 1.0:
            raise InputDataError(f"shadow_threshold must be between 0 and 1, got {self.shadow_threshold}")
        if not self.mode_tolerance >= 0:
            raise InputDataError(f"mode_tolerance must be >= 0, got {self.mode_tolerance}")
        if not self.edge_contrast >= 0:
            raise InputDataError(f"edge_contrast must be >= 0, got {self.edge_contrast}")


def default_min_blob_area(shape: tuple[int, ...]) -> int:
    """0.1 % of the image area (77 px at 320x240, 307 px at 640x480)."""
    return max(1, round(0.001 * shape[0] * shape[1]))


def make_subtractor(params: SegmentParams) -> cv2.BackgroundSubtractor:
    """A fresh OpenCV background model for ``params``."""
    thr = DEFAULT_THRESHOLD[params.method] if params.threshold is None else float(params.threshold)
    if params.method == "mog2":
        model = cv2.createBackgroundSubtractorMOG2(
            history=params.history, varThreshold=thr, detectShadows=params.detect_shadows
        )
    else:
        model = cv2.createBackgroundSubtractorKNN(
            history=params.history, dist2Threshold=thr, detectShadows=params.detect_shadows
        )
    model.setShadowThreshold(float(params.shadow_threshold))
    return model


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
    # Grana's block-based labelling: the same components, about 3x faster than the default here
    n, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_GRANA)
    small = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] < min_area) + 1
    if small.size == 0:
        return mask
    if small.size > 64:  # speckle everywhere: one pass over the image
        keep = stats[:, cv2.CC_STAT_AREA] >= min_area
        keep[0] = False
        return np.where(keep[labels], 255, 0).astype(np.uint8)
    out = mask.copy()
    for i in small:  # erase each small blob inside its bounding box
        x, y, w, h = stats[i, :4]
        box = out[y : y + h, x : x + w]
        box[labels[y : y + h, x : x + w] == i] = 0
    return out


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


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def luminance_gain(luma: np.ndarray, bg_luma: np.ndarray, background: np.ndarray, step: int = 4) -> float:
    """Global lighting gain of a frame: mean luminance over mean background luminance,
    both over the ``background`` pixels (a uint8 mask, non-zero = background) of every
    ``step``-th row."""
    m = background[::step]
    b = cv2.mean(bg_luma[::step], m)[0]
    return cv2.mean(luma[::step], m)[0] / b if b > 1.0 else 1.0


def refine_edges(raw: np.ndarray, luma: np.ndarray, bg_luma: np.ndarray, gain: float,
                 min_contrast: float) -> np.ndarray:
    """Raw mask (0 / 127 / 255) with the rim pixels that luminance puts in the background
    set to 0 (module docstring, step 4).  ``luma``: the frame's (H, W) uint8 luminance;
    ``bg_luma``: (H, W) float32 background luminance."""
    fg = cv2.threshold(raw, SHADOW, 1, cv2.THRESH_BINARY)[1]
    x, y, w, h = cv2.boundingRect(fg)
    if w == 0:
        return raw
    H, W = fg.shape
    x0, y0, x1, y1 = max(x - 3, 0), max(y - 3, 0), min(x + w + 3, W), min(y + h + 3, H)
    f = fg[y0:y1, x0:x1]
    inner = cv2.erode(f, _CROSS)
    rv, ru = np.nonzero(f > inner)  # the rim
    if rv.size == 0:
        return raw
    lum = luma[y0:y1, x0:x1]
    den = cv2.boxFilter(inner, cv2.CV_8U, (5, 5), normalize=False)[rv, ru].astype(np.float32)
    inside_sum = cv2.boxFilter(cv2.bitwise_and(lum, lum, mask=inner), cv2.CV_16U, (5, 5), normalize=False)
    y_fg = inside_sum[rv, ru] / np.maximum(den, 1.0)
    y_bg = gain * bg_luma[y0 + rv, x0 + ru]
    y = lum[rv, ru].astype(np.float32)
    drop = (np.abs(y - y_bg) < np.abs(y - y_fg)) & (np.abs(y_fg - y_bg) >= min_contrast) & (den > 0)
    if not drop.any():
        return raw
    out = raw.copy()
    out[y0 + rv[drop], x0 + ru[drop]] = 0
    return out


#: the gain is measured on every s-th pixel of every s-th row (:func:`gain_step`): s is
#: _GAIN_STEP up to 640x480, and larger above so that about _GAIN_PIXELS pixels count
_GAIN_STEP = 4
_GAIN_PIXELS = 20000
#: a frame is divided by its gains only when one is further than this from 1: the
#: background models learn smaller changes (flicker) as part of each pixel's variance
GAIN_DEADBAND = 0.1


def gain_step(shape: tuple[int, ...]) -> int:
    """The stride of the pixels the gain is measured on, for an image of ``shape``: 4 up to
    640x480 (and a little above), then growing so that about 20000 pixels count (10 at
    1920x1080): the median's cost grows with the pixels, its precision hardly."""
    return max(_GAIN_STEP, round(math.sqrt(shape[0] * shape[1] / _GAIN_PIXELS)))


def channel_gains(frame: np.ndarray, reference: np.ndarray, exclude: np.ndarray | None = None,
                  lit: np.ndarray | None = None) -> np.ndarray:
    """Per-channel gain of ``frame`` against ``reference`` (both ``(h, w, 3)``): the median
    over pixels of their ratio, left out where the reference is dark (< 16), the frame
    saturated (> 250) or ``exclude`` (the subject) is set.  The median ignores the subject
    as long as it covers less than half of the pixels.  Ones when fewer than 64 pixels count.
    ``lit``: ``reference >= 16``, from a caller that measures many frames against one reference."""
    f = frame.astype(np.float32)
    ok = (reference >= 16.0 if lit is None else lit) & (f <= 250.0)
    if exclude is not None:
        ok &= ~exclude[:, :, None]
    gains = np.ones(3)
    for c in range(3):
        sel = ok[:, :, c]
        if np.count_nonzero(sel) >= 64:
            gains[c] = float(np.median(f[:, :, c][sel] / reference[:, :, c][sel]))
    return gains


def apply_gains(frame: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """``frame`` divided by its per-channel ``gains`` (saturating ``uint8``)."""
    return cv2.multiply(frame, (1.0 / gains[0], 1.0 / gains[1], 1.0 / gains[2], 0.0))


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


#: most learning frames the temporal mode compares (evenly spread over them): 60 take
#: 0.9 s at 640x480 and 5.6 s at 1920x1080
_MODE_FRAMES = 60


def temporal_mode(frames: Sequence[np.ndarray], tolerance: float) -> np.ndarray:
    """Per pixel, the mean of the largest group of frames that agree: the frame whose
    value the most frames are within ``tolerance`` grey levels of, in every channel
    (the first on a tie), and those frames.  ``frames``: (H, W, 3) ``uint8`` images of
    one size.  The mean, not that one frame's value, averages out the sensor noise and
    the lighting's flicker as the median did.

    Unlike the median it finds the background where the background shows in fewer
    than half of the frames, as long as no one colour of the subject shows there in
    more (module docstring).  Cost: a comparison per pair of frames, by bands of rows
    (about 16 MB of counts at a time, whatever the image size)."""
    n = len(frames)
    h, w = frames[0].shape[:2]
    lo, hi = (0, 0, 0), (float(tolerance),) * 3

    def near(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return cv2.inRange(cv2.absdiff(a, b), lo, hi) > 0  # every channel within the tolerance

    out = np.empty(frames[0].shape, np.uint8)
    rows = max(1, (1 << 22) // max(1, n * w))
    for r0 in range(0, h, rows):
        band = [np.ascontiguousarray(f[r0 : r0 + rows]) for f in frames]
        counts = np.zeros((n,) + band[0].shape[:2], np.int32)
        for i in range(n):
            for j in range(i + 1, n):
                both = near(band[i], band[j])
                counts[i] += both
                counts[j] += both
        centre = np.take_along_axis(np.stack(band), counts.argmax(axis=0)[None, :, :, None], axis=0)[0]
        total = np.zeros(centre.shape, np.float64)
        members = np.zeros(centre.shape[:2], np.int32)
        for f in band:
            m = near(f, centre)
            total[m] += f[m]
            members += m
        out[r0 : r0 + rows] = np.rint(total / members[:, :, None])  # the centre frame is a member
    return out


def bootstrap_frames(frames: list[np.ndarray], diff: float, tolerance: float = 20.0) -> list[np.ndarray]:
    """Learning frames with the moving subject replaced by the temporal mode
    (:func:`temporal_mode`, module docstring)."""
    if len(frames) < 3:
        return frames
    step = -(-len(frames) // _MODE_FRAMES)  # the mode's cost grows as the square of its frames
    mode = temporal_mode(frames[::step], tolerance)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    out = []
    for f in frames:
        d = cv2.absdiff(f, mode).max(axis=2)
        moving = (d > diff).astype(np.uint8)
        moving = cv2.dilate(moving, kernel)
        g = f.copy()
        g[moving > 0] = mode[moving > 0]
        out.append(g)
    return out


class Segmenter:
    """Stateful frame-by-frame segmentation (used by :func:`segment_frames`).

    ``masks(frames)`` gives the 0/255 mask of every frame in order, learning first
    (module docstring); after it ``static_foreground()`` checks them (step 6).  Frame
    by frame: ``learn(frames)`` trains on the learning frames; ``segment(frame, rate)``
    returns one 0/255 mask.  ``bg_luma`` is the (H, W) float32 luminance background of
    the edge refinement.
    """

    def __init__(self, params: SegmentParams):
        params.check()
        self.params = params
        self.model = make_subtractor(params)
        self.shape: tuple[int, int] | None = None
        self.min_area: int | None = params.min_blob_area
        self.rate = 1.0 / params.history if params.learning_rate is None else params.learning_rate
        self.bg_luma: np.ndarray | None = None
        self.frames_seen = 0
        self.reference: np.ndarray | None = None  # subsampled background, for the gain
        self.lit: np.ndarray | None = None  # reference >= 16 (channel_gains)
        self.subject: np.ndarray | None = None  # subsampled last raw mask's foreground
        self.foreground_sum: np.ndarray | None = None  # per pixel, the sum of the masks: 255 per foreground frame

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

    @staticmethod
    def _sub(a: np.ndarray) -> np.ndarray:
        step = gain_step(a.shape)
        return a[::step, ::step]

    @staticmethod
    def _compensated(frame: np.ndarray, gains: np.ndarray) -> np.ndarray:
        return apply_gains(frame, gains) if np.abs(gains - 1.0).max() > GAIN_DEADBAND else frame

    def _gains(self, frame: np.ndarray) -> np.ndarray:
        """``frame``'s per-channel gains against the learnt background (``reference`` set)."""
        assert self.reference is not None
        return channel_gains(self._sub(frame), self.reference, self.subject, self.lit)

    def learn(self, frames: list[np.ndarray], epochs: int = 2) -> None:
        if self.params.compensate_gain and frames:
            ref = self._sub(frames[len(frames) // 2]).astype(np.float32)
            frames = [self._compensated(f, channel_gains(self._sub(f), ref)) for f in frames]
        clean = bootstrap_frames(frames, self.params.bootstrap_diff, self.params.mode_tolerance)
        for _ in range(epochs):
            for k, f in enumerate(clean):
                self.model.apply(f, learningRate=1.0 / (k + 1))
        if self.params.compensate_gain and clean:
            self.reference = np.mean([self._sub(f) for f in clean], axis=0, dtype=np.float32)
            self.lit = self.reference >= 16.0
        if self.params.refine_edges and clean:
            acc = np.zeros(clean[0].shape[:2], np.float32)
            for f in clean:
                acc += cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
            self.bg_luma = acc / len(clean)

    def segment(self, frame: np.ndarray, rate: float | None = None) -> np.ndarray:
        rate = self.rate if rate is None else rate
        if self.reference is not None:
            frame = self._compensated(frame, self._gains(frame))
        raw = self.model.apply(frame, learningRate=rate)
        if self.reference is not None:
            self.subject = self._sub(raw) > 0
        self.frames_seen += 1
        if self.params.refine_edges:
            luma = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            if self.bg_luma is None:  # learning online only: start from this frame
                self.bg_luma = luma.astype(np.float32)
            else:
                background = cv2.compare(raw, 0, cv2.CMP_EQ)
                gain = luminance_gain(luma, self.bg_luma, background)
                raw = refine_edges(raw, luma, self.bg_luma, gain, self.params.edge_contrast)
            luma_rate = max(1.0 / self.frames_seen, 1.0 / self.params.history) if rate < 0 else rate
            if luma_rate > 0:
                cv2.accumulateWeighted(luma, self.bg_luma, luma_rate, mask=cv2.compare(raw, 0, cv2.CMP_EQ))
        assert self.min_area is not None
        mask = clean_mask(raw, self.params, self.min_area)
        if self.foreground_sum is None:
            self.foreground_sum = np.zeros(mask.shape, np.uint32)
        self.foreground_sum += mask  # 0/255: no boolean mask per frame (uint32: 16 million frames)
        return mask

    def masks(self, frames: Iterable) -> Iterator[np.ndarray]:
        """The 0/255 mask of every frame of ``frames`` (images or ``(index, image)`` pairs),
        in order, learning as ``params.learn_from`` says (:func:`segment_frames`)."""
        params = self.params
        if params.learn_from == "spread" and params.learn_frames > 0:
            if iter(frames) is frames:
                raise InputDataError(
                    "learn_from='spread' reads the frames twice: pass a list or open_frames(path), "
                    "not a one-shot iterator (or use learn_from='start')"
                )
            sample = sample_evenly(frames, params.learn_frames)
            if sample:
                self._check_shape(sample[0], 0)
                self.learn(sample)
            for k, item in enumerate(frames):
                index, frame = item if isinstance(item, tuple) else (k, item)
                frame = _as_bgr(frame, index)
                self._check_shape(frame, index)
                yield self.segment(frame)
            return
        buffer: list[np.ndarray] = []
        learning = params.learn_frames > 0
        for k, item in enumerate(frames):
            index, frame = item if isinstance(item, tuple) else (k, item)
            frame = _as_bgr(frame, index)
            self._check_shape(frame, index)
            if learning:
                buffer.append(frame)
                if len(buffer) < params.learn_frames:
                    continue
                self.learn(buffer)
                for f in buffer:
                    yield self.segment(f, rate=0.0)
                buffer = []
                learning = False
                continue
            yield self.segment(frame, rate=None if params.learn_frames > 0 else -1.0)
        if learning and buffer:  # fewer frames than learn_frames: learn from them all
            self.learn(buffer)
            for f in buffer:
                yield self.segment(f, rate=0.0)

    def static_foreground(self) -> str | None:
        """The message of a :class:`StaticForegroundWarning`, or None (module docstring, step 6)."""
        total, n = self.foreground_sum, self.frames_seen
        if total is None or n < STATIC_MIN_FRAMES:
            return None
        count = total // 255
        static = (count >= STATIC_SHARE * n).astype(np.uint8)
        stats = cv2.connectedComponentsWithStats(static, 8, cv2.CV_32S)[2]
        big = [i for i in np.argsort(-stats[1:, cv2.CC_STAT_AREA]) + 1
               if stats[i, cv2.CC_STAT_AREA] >= max(self.min_area or 1, 1)]
        if not big:
            return None
        where = "; ".join(f"{area} pixels around x={x + w // 2}, y={y + h // 2} ({w}x{h})"
                          for x, y, w, h, area in stats[big[:3]])
        more = f" and {len(big) - 3} more region(s)" if len(big) > 3 else ""
        return (f"{where}{more}: foreground in {STATIC_SHARE:.0%} or more of the {n} frames. The background "
                "model did not learn that part of the scene (the subject stood there in the learning frames, "
                "the camera moved, or the scene changed; unless the subject stands there throughout). "
                "Check the masks there")


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
    **kwargs: Any,
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
    ``fill_holes``, ``detect_shadows``, ``shadow_threshold``, ``bootstrap_diff``, ``mode_tolerance``,
    ``refine_edges``, ``edge_contrast``, ``compensate_gain``).  Warns
    (:class:`StaticForegroundWarning`) of a part of the scene the model never learnt.
    """
    seg = Segmenter(SegmentParams(method=method, learn_frames=learn_frames, learn_from=learn_from, **kwargs))
    yield from (m > 0 for m in seg.masks(frames))
    message = seg.static_foreground()
    if message:
        warnings.warn(StaticForegroundWarning(message), stacklevel=2)
