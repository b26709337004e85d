"""The second track (the option ``second_track``): the frames tracked twice, each frame's better pose.

A track through real silhouettes is chaotic: two tracks that differ in a detail lose the
subject at different frames, and on a lost frame the true pose fits the masks clearly
better than the lost one (docs/design/tracking-history.md).  So a
:class:`~kms2pin.ecm.tracker.Tracker` with ``second_track`` runs a second tracker on the
same frames, with some options changed, each track going on from its own poses, and
reports on each frame the pose of the two that fits better (IoU at the first tracker's
body sizes).  Twice the time.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from .masks import Views, check_masks
from .trajectory import FrameResult

if TYPE_CHECKING:
    from .tracker import Tracker

__all__ = ["FLAG", "better"]

#: how a frame taken from the second track is flagged
FLAG = "from the second track"
#: the start of a frame's flag that its fit is below the tracker's ``poor_fit``
POOR = "poor fit"


def better(tracker: Tracker, res: FrameResult, second: FrameResult, masks, source: str) -> FrameResult:
    """Of ``tracker``'s frame ``res`` and its second track's ``second`` on ``masks``, the
    one whose pose fits better at ``tracker``'s body sizes over the cameras that see
    something (ties, and a frame with no mask to fit: ``res``), with that fit and both
    tracks' timings; the second's flagged :data:`FLAG`, its ``poor fit`` judged again by
    that fit and ``tracker``'s threshold (its other flags its own)."""
    timings = {k: res.timings.get(k, 0.0) + second.timings.get(k, 0.0) for k in res.timings}
    views = Views.of(tracker.cameras, check_masks(masks, tracker.cameras, source, tracker.options.silhouette.clean))
    views = views.seeing()
    if not res.iterations or not len(views):
        return dataclasses.replace(res, timings=timings)
    mine, theirs = tracker.ecm.fit(res.q, views), tracker.ecm.fit(second.q, views)
    if not theirs > mine:
        return dataclasses.replace(res, fit=mine, timings=timings)
    flags = tuple(f for f in second.flags if not f.startswith(POOR))
    if theirs < tracker.options.silhouette.poor_fit:
        flags += (f"{POOR} ({theirs:.2f})",)
    return dataclasses.replace(second, fit=theirs, flags=(*flags, FLAG), timings=timings)
