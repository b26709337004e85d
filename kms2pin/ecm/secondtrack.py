"""The second track (the option ``second_track``): the frames tracked twice, each frame's better pose.

A track through real silhouettes is chaotic: two tracks that differ in a detail lose the
subject at different frames, and on a lost frame the true pose fits the masks clearly
better than the lost one (docs/design/tracking-history.md).  So a
:class:`~kms2pin.ecm.tracker.Tracker` with ``second_track`` runs a second tracker on the
same frames, with some options changed (or several, each with its own changes), each
track going on from its own poses, and reports on each frame the pose that fits best
(IoU at the first tracker's body sizes), then each part of it (:mod:`~kms2pin.ecm.parts`:
a limb below a hip, a knee, a shoulder, an elbow, ...) taken from the other tracks where
that fits better: one track may hold an arm that the best-fitting one lost.  Each track
beside costs about one more track's time; the choice with the parts a few milliseconds a frame.
"""

from __future__ import annotations

import dataclasses
import re
import weakref
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .masks import Views, check_masks
from .parts import Parts
from .silhouette import IncrementalFit
from .trajectory import POOR_FIT, FrameResult, poor_fit_flag

if TYPE_CHECKING:
    from .tracker import Tracker

__all__ = ["FLAG", "better", "flag", "is_part_flag", "is_track_flag", "part_flag", "track_name"]

#: how a frame taken from the second track is flagged (a third: :func:`flag`)
FLAG = "from the second track"
#: each robot's parts (:func:`_parts`)
_PARTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_ORDINALS = ("first", "second", "third", "fourth", "fifth")
#: the flags better adds (flag, part_flag)
_TRACK_FLAG = re.compile(r"(?:'.+' taken )?from (?:the (?:" + "|".join(_ORDINALS) + r") track|track \d+)")


def track_name(t: int) -> str:
    """Track ``t``'s name in flags and notes: ``"the first track"`` (0, the tracker's own),
    ``"the second track"`` (1, the first beside it), ..."""
    return f"the {_ORDINALS[t]} track" if t < len(_ORDINALS) else f"track {t + 1}"


def part_flag(joint: str, t: int) -> str:
    """The flag of a part (``joint`` and the joints below it) taken from track ``t``
    (0: the first): ``"'<joint>' taken from the <n-th> track"``."""
    return f"'{joint}' taken from {track_name(t)}"


def is_track_flag(text: str) -> bool:
    """Whether ``text`` is a flag :func:`better` adds: :func:`flag` or :func:`part_flag`."""
    return bool(_TRACK_FLAG.fullmatch(text))


def is_part_flag(text: str) -> bool:
    """Whether ``text`` is a :func:`part_flag`."""
    return text.startswith("'") and is_track_flag(text)


def flag(k: int) -> str:
    """The flag of a frame taken from track ``k`` beside the first (0: the second track)."""
    return f"from {track_name(k + 1)}"


def _parts(robot) -> Parts:
    """The parts :func:`better` takes from the other tracks, worked out once a robot."""
    taker = _PARTS.get(robot)
    if taker is None:
        taker = _PARTS[robot] = Parts(robot, branches=False)
    return taker


def better(tracker: Tracker, res: FrameResult, others: Sequence[FrameResult], masks, source: str) -> FrameResult:
    """Of ``tracker``'s frame ``res`` and its tracks beside's frames ``others`` on
    ``masks``, the one whose pose fits best at ``tracker``'s body sizes over the cameras
    that see something (ties go to the earlier track; a frame with no mask to fit:
    ``res``), with each part then taken from the other tracks in track order where that
    fits better (:func:`~kms2pin.ecm.parts.take_parts`'s parts: not one with a branch
    below it), with that fit and every track's timings summed.  One from beside is
    flagged :func:`flag`, a part taken ``'<joint>' taken from the <n-th> track``; its
    ``poor fit`` judged again by that fit and ``tracker``'s threshold (its other flags its own)."""
    timings = {k: res.timings.get(k, 0.0) + sum(o.timings.get(k, 0.0) for o in others) for k in res.timings}
    views = Views.of(tracker.cameras, check_masks(masks, tracker.cameras, source, tracker.options.silhouette.clean))
    views = views.seeing()
    if not res.iterations or not len(views):
        return dataclasses.replace(res, timings=timings)
    tracks = [res, *others]
    best, fit = 0, tracker.ecm.fit(res.q, views)
    for k, other in enumerate(others, 1):
        theirs = tracker.ecm.fit(other.q, views)
        if theirs > fit:
            best, fit = k, theirs
    chosen = tracks[best]
    taker = _parts(tracker.robot)
    score = IncrementalFit(tracker.robot, views.cameras, views.masks, tracker.ecm.sizes.inner)
    pm = tracker.robot.model
    q, took = chosen.q, {}  # the parts in the pose, by joint: the track each came from (the last taken)
    for t, other in enumerate(tracks):
        if t == best or not other.iterations:
            continue
        taken = np.zeros(len(taker.names), dtype=bool)
        q, fit = taker.take(score, q, other.q, fit, taken)
        for h in (h for h, x in zip(taker.names, taken) if x):
            below = pm.subtrees[pm.getJointId(h)]  # a part taken replaces those taken at or below it
            took = {j: u for j, u in took.items() if pm.getJointId(j) not in below}
            took[h] = t
    flags = tuple(f for f in chosen.flags if not f.startswith(POOR_FIT))
    if fit < tracker.options.silhouette.poor_fit:
        flags += (poor_fit_flag(fit),)
    flags += (flag(best - 1),) if best else ()
    if took:
        chosen = dataclasses.replace(chosen, q=q, body_poses=tracker.robot.maximal_coordinates(q))
    return dataclasses.replace(chosen, fit=fit, flags=(*flags, *(part_flag(h, t) for h, t in took.items())),
                               timings=timings)
