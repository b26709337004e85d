"""Finding the subject again after it has left the view of every camera.

While every mask is empty the tracker keeps the last pose (flag ``"empty
mask"``).  The subject usually comes back elsewhere, facing another way, and
first only in part (cut by the image border), so tracking on from the kept
pose locks onto a wrong pose.  :class:`Reacquisition` watches the tracked
frames.  After an empty frame it is *searching*:

- frames whose silhouettes come within ``margin`` pixels of the image border
  (the subject is still coming in) are tracked as they are, for at most
  ``wait`` frames;
- on the other frames, a fit (IoU of the model's silhouettes with the masks)
  of at least ``good`` times the *reference fit* (the median fit of the
  recent frames tracked before the subject left, or the initial pose's) ends
  the search once ``searches`` searches have been tried; otherwise a fresh
  :func:`~kms2pin.ecm.initialization.initial_pose_details` search starts from the last
  well-tracked pose's joint angles (a frame is well tracked if its fit is good
  and no silhouette comes near the border: a silhouette cut by the border can
  be fitted well by a wrong pose); its pose, refined by ECM on the frame
  (:meth:`~kms2pin.ecm.tracker.Tracker.refine`), replaces the tracked one if it
  fits better, and the tracker restarts from it (flag ``"reinitialized"``).
  So searches go on for the first ``searches`` frames the subject is back wholly
  in view even if the tracked pose fits (unless one wins): a wrong pose (turned round, walking
  backwards with the knees bent backwards) can fit the silhouettes well too,
  and a search from one frame can miss the pose that the next one finds.

After ``max_attempts`` searches without a good fit it gives up (a note says so).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np

from ..robot import Robot
from .camera import Camera
from .tracker import FrameResult, Tracker


def touches_border(mask: np.ndarray, margin: int = 1) -> bool:
    """Whether a mask has a pixel in the outermost ``margin`` rows or columns of the image."""
    m = np.asarray(mask, dtype=bool)
    k = max(int(margin), 1)
    return bool(m[:k].any() or m[-k:].any() or m[:, :k].any() or m[:, -k:].any())


class Reacquisition:
    """Re-initialization of a :class:`~kms2pin.ecm.tracker.Tracker` after the subject
    returns (module docstring).  Call :meth:`update` once per tracked frame.

    Args:
        robot: the tracked model (free root).
        cameras: the tracker's cameras.
        q0: the initial configuration (the first "last well-tracked pose").
        reference_fit: the initial pose's fit (IoU), the first reference.
        good: a fit of ``good`` x the reference fit ends a search.
        wait: frames after the return during which a subject at the border is not searched for.
        margin: pixels from the image border that count as "at the border".
        max_attempts: searches after one return before giving up.
        searches: searches tried after a return even when the tracked pose fits.
        memory: how many recent good fits make the reference (their median).
    """

    def __init__(
        self,
        robot: Robot,
        cameras: Sequence[Camera],
        q0: np.ndarray,
        reference_fit: float | None = None,
        good: float = 0.9,
        wait: int = 15,
        margin: int = 4,
        max_attempts: int = 10,
        searches: int = 3,
        memory: int = 10,
    ):
        self.robot = robot
        self.cameras = list(cameras)
        self.good = good
        self.wait = wait
        self.margin = margin
        self.max_attempts = max_attempts
        self.searches = searches
        self._fits: deque[float] = deque([reference_fit] if reference_fit else [], maxlen=memory)
        self.last_good_q = np.array(q0, dtype=float)
        self.searching = False
        self.attempts = 0
        self.frames_back = 0

    @property
    def reference_fit(self) -> float:
        """Median fit of the recent well-tracked frames (0.8 before any)."""
        return float(np.median(self._fits)) if self._fits else 0.8

    def _good(self, result: FrameResult) -> None:
        self._fits.append(result.fit)
        self.last_good_q = result.q.copy()
        self.searching = False

    def update(
        self, tracker: Tracker, result: FrameResult, masks: Sequence[np.ndarray], source: str
    ) -> tuple[Tracker, FrameResult, str | None]:
        """The tracker to go on with, this frame's result and a note for the user (or None)."""
        if "empty mask" in result.flags:
            if not self.searching:
                self.searching, self.attempts, self.frames_back = True, 0, 0
            return tracker, result, None
        target = self.good * self.reference_fit
        inside = not any(touches_border(m, self.margin) for m in masks)
        if not self.searching:
            if inside and result.fit >= target:
                self._good(result)
            return tracker, result, None
        self.frames_back += 1
        fits = inside and result.fit >= target
        if fits and self.attempts >= self.searches:
            # it fits, and searches have been tried since the subject came back
            self._good(result)
            return tracker, result, None
        if not inside and self.frames_back <= self.wait:
            return tracker, result, None
        if self.attempts >= self.max_attempts:
            self.searching = False
            return tracker, result, (
                f"the subject came back but no pose fits it well (fit {result.fit:.2f} after "
                f"{self.attempts} searches); tracking on from the current pose"
            )
        from .initialization import initial_pose_details

        self.attempts += 1
        found = initial_pose_details(self.robot, self.cameras, masks, q_start=self.last_good_q)
        # the search's pose refined by ECM, against the tracked one
        q_found, fit_found = tracker.refine(found.q, masks, source)
        if fit_found <= result.fit:
            if fits and self.attempts >= self.searches:
                self._good(result)
            return tracker, result, None
        # the same subject, tracked the same way: its options, the body sizes measured at
        # the start and its upright axis are kept
        tracker.restart(q_found)
        r = tracker.step(masks, source=source)
        result = FrameResult(r.q, r.body_poses, r.iterations, r.fit, r.converged, r.flags + ("reinitialized",),
                             r.timings)
        if inside and result.fit >= target:
            self._good(result)
        return tracker, result, f"subject back in view; pose found again (fit {result.fit:.2f})"
