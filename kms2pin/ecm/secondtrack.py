"""The second track (the option ``second_track``): the frames tracked twice, each frame's better pose.

A track through real silhouettes is chaotic: two tracks that differ in a detail lose the
subject at different frames, and on a lost frame the true pose fits the masks clearly
better than the lost one (docs/design/tracking-history.md).  So a
:class:`~kms2pin.ecm.tracker.Tracker` with ``second_track`` runs a second tracker on the
same frames, with some options changed (or several, each with its own changes), each
track going on from its own poses, and reports on each frame the pose that fits best
(IoU at the first tracker's body sizes).  Each track beside costs about one more track's
time.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

from .masks import Views, check_masks
from .trajectory import POOR_FIT, FrameResult, poor_fit_flag

if TYPE_CHECKING:
    from .tracker import Tracker

__all__ = ["FLAG", "better", "flag", "track_name"]

#: how a frame taken from the second track is flagged (a third: :func:`flag`)
FLAG = "from the second track"
_ORDINALS = ("first", "second", "third", "fourth", "fifth")


def track_name(t: int) -> str:
    """Track ``t``'s name in flags and notes: ``"the first track"`` (0, the tracker's own),
    ``"the second track"`` (1, the first beside it), ..."""
    return f"the {_ORDINALS[t]} track" if t < len(_ORDINALS) else f"track {t + 1}"


def flag(k: int) -> str:
    """The flag of a frame taken from track ``k`` beside the first (0: the second track)."""
    return f"from {track_name(k + 1)}"


def better(tracker: Tracker, res: FrameResult, others: Sequence[FrameResult], masks, source: str) -> FrameResult:
    """Of ``tracker``'s frame ``res`` and its tracks beside's frames ``others`` on
    ``masks``, the one whose pose fits best at ``tracker``'s body sizes over the cameras
    that see something (ties go to the earlier track; a frame with no mask to fit:
    ``res``), with that fit and every track's timings summed; one from beside flagged
    :func:`flag`, its ``poor fit`` judged again by that fit and ``tracker``'s threshold
    (its other flags its own)."""
    timings = {k: res.timings.get(k, 0.0) + sum(o.timings.get(k, 0.0) for o in others) for k in res.timings}
    views = Views.of(tracker.cameras, check_masks(masks, tracker.cameras, source, tracker.options.silhouette.clean))
    views = views.seeing()
    if not res.iterations or not len(views):
        return dataclasses.replace(res, timings=timings)
    best, fit = -1, tracker.ecm.fit(res.q, views)
    for k, other in enumerate(others):
        theirs = tracker.ecm.fit(other.q, views)
        if theirs > fit:
            best, fit = k, theirs
    if best < 0:
        return dataclasses.replace(res, fit=fit, timings=timings)
    chosen = others[best]
    flags = tuple(f for f in chosen.flags if not f.startswith(POOR_FIT))
    if fit < tracker.options.silhouette.poor_fit:
        flags += (poor_fit_flag(fit),)
    return dataclasses.replace(chosen, fit=fit, flags=(*flags, flag(best)), timings=timings)
