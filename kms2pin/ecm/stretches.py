"""A finished recording's tracks beside (``second_track``): each stretch of frames from the
track that fits it best, changing track where the tracks agree (offline).

Online, a :class:`~kms2pin.ecm.tracker.Tracker` with tracks beside reports on each frame the
track whose pose fits best (:func:`~kms2pin.ecm.secondtrack.better`).  A track that is lost
still fits best on a frame now and then, and each such frame is a jump to the lost pose and
back (on real motion 100-400 mm, docs/design/tracking-history.md).  With the whole recording
at hand the choice is made over the frames instead (:func:`stretches`), as
:func:`~kms2pin.ecm.bothways.choose` makes it between a forward and a backward track: the
most fit gained less :data:`~kms2pin.ecm.bothways.SWITCH` times how far apart the two tracks
are at each change of track (free where they agree within
:data:`~kms2pin.ecm.bothways.TOLERANCE`), a Viterbi pass over all the tracks
(:func:`~kms2pin.ecm.bothways.choose_tracks`).  Then, as ``both_ways`` does with its two
tracks, each part (every joint but the root and those with a branch below them, with the
joints below it) is taken on each frame from the other tracks where that fits better
(:func:`~kms2pin.ecm.bothways.take_parts`), and last each part from the frames beside
(:func:`~kms2pin.ecm.bothways.take_beside`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .bothways import (
    SWEEPS,
    SWITCH,
    TOLERANCE,
    apart_tracks,
    choose_tracks,
    part_scorer,
    parts,
    take_beside,
    take_parts,
)
from .tracker import Tracker

__all__ = ["Stretches", "stretches", "track_poses"]


@dataclass(frozen=True)
class Stretches:
    """The result of :func:`stretches`.

    Attributes:
        q: (frames, nq) the kept pose of each frame.
        track: (frames,) the track kept on each frame (0: the first, k: the k-th beside it).
        fits: (frames, tracks) each track's fit (IoU) on each frame, at the tracker's body sizes.
        fit: (frames,) the fit of :attr:`q`.
        part_names: the joints tried (:func:`~kms2pin.ecm.bothways.parts`), in tree order.
        parts: (frames, len(part_names)) the last track that joint was taken from, with the
            joints below it (:func:`~kms2pin.ecm.bothways.take_parts`), -1 where none (a part
            taken later above it takes it again, from that part's track).
        beside: (frames, len(part_names)) True where that joint and the joints below it were
            then taken from the frames beside (:func:`~kms2pin.ecm.bothways.take_beside`).
    """

    q: np.ndarray
    track: np.ndarray
    fits: np.ndarray
    fit: np.ndarray
    part_names: tuple[str, ...]
    parts: np.ndarray
    beside: np.ndarray


def track_poses(tracker: Tracker) -> np.ndarray:
    """(tracks, nq) each track's own pose after the last frame: ``tracker``'s (the first), then
    each of its tracks beside (:attr:`Tracker.tracks_beside`), as :func:`stretches` takes them."""
    return np.array([tracker.q, *(other.q for other in tracker.tracks_beside)])


def stretches(tracker: Tracker, masks: Sequence, tracks: np.ndarray, *, switch: float = SWITCH,
              tolerance: float = TOLERANCE, sweeps: int = SWEEPS, sources: Sequence[str] | None = None) -> Stretches:
    """Of ``tracks`` (frames, tracks, nq; each track's own poses, :func:`track_poses` after
    each frame, stacked) of ``masks`` (a sequence of frames, each one mask per camera), the pose of
    the track kept on each frame by :func:`~kms2pin.ecm.bothways.choose_tracks` (``switch``
    and ``tolerance`` as there, no margin), then each part taken from the other tracks and
    from the frames beside where that fits better (module docstring; ``sweeps`` as in
    :func:`~kms2pin.ecm.bothways.take_beside`, 0: none).  The fits are taken at
    ``tracker``'s body sizes (the tracker that made the tracks, after its last frame).
    ``sources`` names each frame in error messages (default ``"frame k"``)."""
    tracks = np.asarray(tracks, dtype=float)
    n, robot = len(masks), tracker.robot
    if tracks.ndim != 3 or tracks.shape[0] != n or tracks.shape[2] != robot.nq or not tracks.shape[1]:
        raise ValueError(f"tracks must have shape ({n}, tracks, {robot.nq}) (each track's pose on each frame), "
                         f"not {tracks.shape}")
    names = list(sources) if sources is not None else [f"frame {k}" for k in range(n)]
    fits = np.empty((n, tracks.shape[1]))
    for k in range(n):  # each frame's masks read once for all its tracks
        m = masks[k]
        fits[k] = [tracker.fit(q, m, source=names[k]) for q in tracks[k]]
    kept = choose_tracks(fits, apart_tracks(robot, tracks), switch, tolerance)
    frames = np.arange(n)
    q, fit = tracks[frames, kept], fits[frames, kept]
    scorer = part_scorer(tracker, masks, names)
    taken = np.full((n, len(parts(robot))), -1)
    for t in range(tracks.shape[1]):  # not from a frame's own track: there the trials are q itself, skipped
        q, fit, took = take_parts(robot, scorer, q, np.where((kept == t)[:, None], q, tracks[:, t]), fit)
        taken[took] = t
    q, fit, beside = take_beside(robot, scorer, q, fit, sweeps)
    return Stretches(q, kept, fits, fit, parts(robot), taken, beside)
