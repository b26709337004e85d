"""A finished recording tracked both ways: forwards, then backwards from the last pose,
keeping on each frame the pose that fits the masks better (offline).

A track loses a limb for a stretch of frames (the arms, above all, in front of the
trunk) and finds it again later.  Tracked backwards from the end, the same stretch is
entered from its other side, where the limb was found, and it is often lost elsewhere
or not at all.  :func:`both_ways` runs a second :class:`~kms2pin.ecm.tracker.Tracker`
(the same model, cameras and options) over the frames in reverse order, started at the
forward track's last pose, and keeps the backward pose on a frame where its silhouette
fit (IoU) beats the forward pose's by :data:`MARGIN`; both fits are measured at the
backward tracker's body sizes after its pass, so the two are scored alike.  It costs a
second track, and uses the frames after each frame, so it is for a finished recording.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .options import Preset, TrackerOptions
from .tracker import Tracker
from .trajectory import FrameResult

__all__ = ["MARGIN", "BothWays", "both_ways"]

#: the IoU by which the backward pose must fit better to be kept (docs/design/tracking-history.md)
MARGIN = 0.005


@dataclass(frozen=True)
class BothWays:
    """The result of :func:`both_ways`.

    Attributes:
        q: (frames, nq) the kept pose of each frame.
        backward: (frames,) True where the backward track's pose was kept.
        fit_forward, fit_backward: (frames,) each track's fit (IoU), at the backward
            tracker's body sizes.
        results: the backward track's :class:`FrameResult` per frame, in frame order.
    """

    q: np.ndarray
    backward: np.ndarray
    fit_forward: np.ndarray
    fit_backward: np.ndarray
    results: list[FrameResult]

    @property
    def fit(self) -> np.ndarray:
        """(frames,) the kept pose's fit."""
        return np.where(self.backward, self.fit_backward, self.fit_forward)


def both_ways(robot, cameras: Sequence[Camera], masks: Sequence, forward_q: np.ndarray,
              options: TrackerOptions | Preset | None = None, *, margin: float = MARGIN,
              sources: Sequence[str] | None = None, progress: Callable | None = None, **overrides) -> BothWays:
    """Track ``masks`` (a sequence of frames, each one mask per camera) backwards from
    the last pose of ``forward_q`` (frames, nq), the forward track of the same frames,
    with a :class:`~kms2pin.ecm.tracker.Tracker` of ``robot``, ``cameras`` and
    ``options`` / ``overrides`` (those of the forward track), and keep per frame the
    better-fitting pose (module docstring).  ``sources`` names each frame in error
    messages (default ``"frame k"``); ``progress`` wraps the frames' iteration (a tqdm)."""
    forward_q = np.asarray(forward_q, dtype=float)
    n = len(masks)
    if forward_q.shape != (n, robot.nq):
        raise ValueError(f"forward_q must have shape ({n}, {robot.nq}) (one pose per frame), not {forward_q.shape}")
    names = list(sources) if sources is not None else [f"frame {k}" for k in range(n)]
    tracker = Tracker(robot, cameras, options, q0=forward_q[-1], **overrides)
    order = range(n - 1, -1, -1)
    results: list[FrameResult | None] = [None] * n
    for k in progress(order) if progress is not None else order:
        results[k] = tracker.step(masks[k], source=names[k])
    fit_f, fit_b = np.empty(n), np.empty(n)
    for k in range(n):  # both fits at the sizes the backward pass ended with, each frame's masks read once
        m = masks[k]
        fit_f[k] = tracker.fit(forward_q[k], m, source=names[k])
        fit_b[k] = tracker.fit(results[k].q, m, source=names[k])
    back = fit_b > fit_f + margin
    q = np.where(back[:, None], np.array([r.q for r in results]), forward_q)
    return BothWays(q, back, fit_f, fit_b, results)
