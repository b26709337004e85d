"""A finished recording tracked both ways: forwards, then backwards from the last pose,
keeping on each frame the pose that fits the masks better (offline).

A track loses a limb for a stretch of frames (the arms, above all, in front of the
trunk) and finds it again later.  Tracked backwards from the end, the same stretch is
entered from its other side, where the limb was found, and it is often lost elsewhere
or not at all.  :func:`both_ways` runs a second :class:`~kms2pin.ecm.tracker.Tracker`
(the same model, cameras and options) over the frames in reverse order, started at the
forward track's last pose, and keeps the backward poses where their silhouette fit
(IoU) beats the forward poses' by :data:`MARGIN` a frame; both fits are measured at the
backward tracker's body sizes after its pass, so the two are scored alike.

A pose that fits well is not always right: a track lost for a stretch may fit better
than the held one on a few of its frames.  Taken frame by frame, those frames would
make the result jump from one track to the other and back.  So the choice is made over
the whole sequence (:func:`choose`): each change from one track to the other costs
:data:`SWITCH` times how far apart the two tracks' poses are where the change is made,
and the choice of the most fit gained less those costs is kept (a Viterbi pass over the
two tracks).  A stretch one track lost is taken from the other where that fits better
over the stretch, entered and left where the two agree; where they agree within
:data:`TOLERANCE` a change costs nothing.  Then each part, every joint but the root from
the top down (a ball joint, a hip or a shoulder, pointed as the other track points it; a
hinge, a knee or an elbow, at the other track's angle), is taken with the joints below it
from the track not kept on each frame where that fits better (:func:`take_parts`; not a
part with a branch below it, :func:`branching`): a whole pose's choice turns on the trunk
and the legs, and leaves an arm (or a foot) that the other track held better.  Last, each
part is tried on each frame from the frames beside it (:func:`take_beside`): a limb held
on a few frames spreads to the frames on either side where the masks bear it out.  It
costs a second track, and uses the frames after each frame, so it is for a finished
recording.  :func:`beside` takes the frames beside on one track alone, without the
backward pass (seconds to tens of seconds for a few hundred frames, not a second track).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..robot import Robot
from .camera import Camera
from .options import Preset, TrackerOptions
from .parts import Parts, branching, hinges, parts, take_parts
from .tracker import Tracker
from .trajectory import FrameResult

__all__ = ["MARGIN", "SWEEPS", "SWITCH", "TOLERANCE", "Beside", "BothWays", "apart", "apart_tracks", "beside", "both_ways", "branching",
           "choose", "choose_tracks", "hinges", "part_scorer", "parts", "take_beside", "take_parts"]

#: the IoU by which the backward pose must fit better, a frame, to be kept (docs/design/tracking-history.md)
MARGIN = 0.005
#: the IoU a change from one track to the other costs per model height that the two
#: tracks' body centres lie apart, on average, where it is made (docs/design/tracking-history.md)
SWITCH = 1.0
#: how far apart (model heights, as :func:`apart`) the two tracks may be where a change from
#: one to the other costs nothing (docs/design/tracking-history.md)
TOLERANCE = 0.01
#: how many passes :func:`take_beside` makes over the frames (docs/design/tracking-history.md)
SWEEPS = 2


@dataclass(frozen=True)
class BothWays:
    """The result of :func:`both_ways`.

    Attributes:
        q: (frames, nq) the kept pose of each frame.
        backward: (frames,) True where the backward track's pose was kept (before the
            parts: :attr:`parts`).
        fit_forward, fit_backward: (frames,) each track's fit (IoU), at the backward
            tracker's body sizes.
        apart: (frames,) how far apart the two tracks' poses are (:func:`apart`, model heights).
        results: the backward track's :class:`FrameResult` per frame, in frame order.
        fit: (frames,) the fit of :attr:`q`.
        part_names: the joints :func:`take_parts` tries (:func:`parts`), in tree order.
        parts: (frames, len(part_names)) True where that joint and the joints below it
            were taken from the track not kept (:func:`take_parts`).
        beside: (frames, len(part_names)) True where that joint and the joints below it
            were then taken from the frames beside (:func:`take_beside`).
    """

    q: np.ndarray
    backward: np.ndarray
    fit_forward: np.ndarray
    fit_backward: np.ndarray
    apart: np.ndarray
    results: list[FrameResult]
    fit: np.ndarray
    part_names: tuple[str, ...]
    parts: np.ndarray
    beside: np.ndarray


@dataclass(frozen=True)
class Beside:
    """The result of :func:`beside`.

    Attributes:
        q: (frames, nq) each frame's pose, its parts taken from the frames beside it.
        fit: (frames,) the fit (IoU) of :attr:`q`, at the tracker's body sizes.
        part_names: the joints tried (:func:`parts`), in tree order.
        taken: (frames, len(part_names)) True where that joint and the joints below it
            were taken from the frames beside.
    """

    q: np.ndarray
    fit: np.ndarray
    part_names: tuple[str, ...]
    taken: np.ndarray


def apart(robot: Robot, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """(frames,) the mean distance between the body centres of ``robot`` at ``qa`` and at
    ``qb`` (each (frames, nq)), frame by frame, in model heights."""
    return apart_tracks(robot, np.stack([qa, qb], axis=1))[:, 0, 1]


def apart_tracks(robot: Robot, tracks: np.ndarray) -> np.ndarray:
    """(frames, tracks, tracks) :func:`apart` for each two of ``tracks`` (frames, tracks, nq;
    several tracks of the same frames), frame by frame, in model heights."""
    centres = np.array([[robot.body_pose_arrays(x)[1] for x in frame] for frame in tracks])  # frames, tracks, bodies, 3
    return np.linalg.norm(centres[:, :, None] - centres[:, None], axis=-1).mean(axis=-1) / robot.height


def choose(fit_forward: np.ndarray, fit_backward: np.ndarray, apart: np.ndarray, margin: float = MARGIN,
           switch: float = SWITCH, tolerance: float = TOLERANCE) -> np.ndarray:
    """(frames,) True where the backward pose is kept: the choice that maximises the fit
    the backward poses gain over the forward ones (``fit_backward - fit_forward - margin``
    summed over the frames that take them) less ``switch`` times ``max(min(apart[k],
    apart[k + 1]) - tolerance, 0)`` for each change of track between frames k and k + 1
    (``apart``: how far apart the two tracks' poses are, model heights; the change is made
    where they agree more, and is free where they agree within ``tolerance``).  A Viterbi
    pass over the two tracks (:func:`choose_tracks`), the forward one kept on a tie; with
    ``switch`` 0 it is the frame-by-frame choice ``fit_backward > fit_forward + margin``."""
    fits = np.stack([np.asarray(fit_forward, dtype=float), np.asarray(fit_backward, dtype=float)], axis=1)
    far = np.asarray(apart, dtype=float)
    pair = np.zeros((len(far), 2, 2))
    pair[:, 0, 1] = pair[:, 1, 0] = far
    return choose_tracks(fits, pair, switch, tolerance, margins=(0.0, margin)) == 1


def choose_tracks(fits: np.ndarray, apart: np.ndarray, switch: float = SWITCH, tolerance: float = TOLERANCE,
                  margins: Sequence[float] | None = None) -> np.ndarray:
    """(frames,) the track kept on each frame, of T tracks of the same frames: the choice
    that maximises the fit kept (``fits`` (frames, T), each track's fit on each frame, less
    ``margins[t]`` (T,; default 0) on the frames taking track t) less ``switch`` times
    ``max(min(apart[k, i, j], apart[k + 1, i, j]) - tolerance, 0)`` for each change from
    track i to track j between frames k and k + 1 (``apart`` (frames, T, T): how far apart
    the tracks' poses are, model heights, :func:`apart`).  A Viterbi pass over the tracks;
    on a tie the last frame takes the first of the tracks tied, and each frame before it,
    going back, the track held where holding it ties.  With ``switch`` 0 it is each frame's
    best track (the first on a tie).  The fits are taken relative to track 0's, so that two
    tracks are scored with :func:`choose`'s arithmetic exactly."""
    fits = np.asarray(fits, dtype=float)
    n, t = fits.shape
    margin = np.zeros(t) if margins is None else np.asarray(margins, dtype=float)
    far = np.asarray(apart, dtype=float)
    if margin.shape != (t,) or far.shape != (n, t, t):
        raise ValueError(f"for {t} tracks of {n} frames: margins ({t},) and apart ({n}, {t}, {t}), not "
                         f"{margin.shape} and {far.shape}")
    if not (np.isfinite(fits).all() and np.isfinite(margin).all() and np.isfinite(far).all()):
        raise ValueError("the fits, margins and distances must be finite")
    if switch < 0 or tolerance < 0:
        raise ValueError(f"switch and tolerance must be 0 or more, not {switch} and {tolerance}")
    gain = fits - fits[:, :1] - margin  # (frames, T): each track's gain over the first, the least cost less it
    if n == 0:
        return np.zeros(0, dtype=int)
    if switch == 0.0:
        return np.argmax(gain, axis=1)  # the first on a tie
    step = switch * np.maximum(np.minimum(far[:-1], far[1:]) - tolerance, 0.0)  # (frames - 1, i, j)
    step[:, np.arange(t), np.arange(t)] = 0.0  # holding a track costs nothing
    cost = -gain[0].copy()  # (T,): the least cost of the frames so far ending on each track
    came = np.zeros((n, t), dtype=int)  # the track the best way to (frame, track) came from
    for k in range(1, n):
        total = cost[:, None] + step[k - 1]  # from track i (rows) to track j (columns)
        best = np.argmin(total, axis=0)  # the first on a tie
        held = total[np.arange(t), np.arange(t)] <= total[best, np.arange(t)]  # the track held on a tie
        came[k] = np.where(held, np.arange(t), best)
        cost = total[came[k], np.arange(t)] - gain[k]
    kept = np.zeros(n, dtype=int)
    s = int(np.argmin(cost))
    for k in range(n - 1, -1, -1):
        kept[k] = s
        s = came[k, s]
    return kept


def take_beside(robot: Robot, scorer: Callable[[int], Callable[[np.ndarray], float]], q: np.ndarray,
                fit_q: np.ndarray, sweeps: int = SWEEPS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each of :func:`parts` taken on frame k, as :func:`take_parts` takes it, from the
    frames beside it where that fits better: from the pose halfway between frames k - 1 and
    k + 1 (``pin.interpolate``), then from frame k - 1, k + 1, k - 2 and k + 2 as they stand.
    ``sweeps`` passes over the frames, forwards then backwards in turn, each frame on the
    frames before it as the pass left them, so that a limb a track held on a few frames
    spreads to the frames on either side where the masks bear it out.  ``scorer`` as in
    :func:`take_parts` (asked once a frame and pass).  Returns (q, its fit, (frames, parts)
    True where a part was taken)."""
    if sweeps < 0:
        raise ValueError(f"sweeps must be 0 or more, not {sweeps}")
    tried = Parts(robot)
    q, fit_q = np.array(q, dtype=float), np.array(fit_q, dtype=float)
    n = len(q)
    if fit_q.shape != (n,):
        raise ValueError(f"fit_q must have one fit per frame of q ({n}), not shape {fit_q.shape}")
    taken = np.zeros((n, len(tried.names)), dtype=bool)
    for sweep in range(sweeps):
        for k in (range(n) if sweep % 2 == 0 else range(n - 1, -1, -1)):
            score = scorer(k)
            for other in _beside(robot, q, k):
                q[k], fit_q[k] = tried.take(score, q[k], other, fit_q[k], taken[k])
    return q, fit_q, taken


def part_scorer(tracker: Tracker, masks: Sequence, names: Sequence[str]) -> Callable[[int], Callable[[np.ndarray], float]]:
    """The scorer :func:`take_parts` and :func:`take_beside` ask once a frame: the fit at
    ``tracker``'s sizes on frame k's masks (read and checked once for all its trials),
    counted from the moved bodies alone (:meth:`Tracker.part_fit`)."""
    def scorer(k: int) -> Callable[[np.ndarray], float]:
        return tracker.part_fit(masks[k], source=names[k])

    return scorer


def beside(tracker: Tracker, masks: Sequence, q: np.ndarray, *, sweeps: int = SWEEPS,
           sources: Sequence[str] | None = None) -> Beside:
    """One finished track ``q`` (frames, nq) of ``masks`` (a sequence of frames, each one
    mask per camera) with its parts (:func:`parts`) taken from the frames beside
    (:func:`take_beside`), without a backward pass: the fits at ``tracker``'s body sizes
    (the tracker that made the track, after its last frame).  ``sources`` names each frame
    in error messages (default ``"frame k"``)."""
    q = np.asarray(q, dtype=float)
    n, robot = len(masks), tracker.robot
    if q.shape != (n, robot.nq):
        raise ValueError(f"q must have shape ({n}, {robot.nq}) (one pose per frame), not {q.shape}")
    names = list(sources) if sources is not None else [f"frame {k}" for k in range(n)]
    fit = np.array([tracker.fit(q[k], masks[k], source=names[k]) for k in range(n)])

    q, fit, taken = take_beside(robot, part_scorer(tracker, masks, names), q, fit, sweeps)
    return Beside(q, fit, parts(robot), taken)


def _beside(robot: Robot, q: np.ndarray, k: int):
    """The poses :func:`take_beside` tries on frame k, those of frames outside left out."""
    n = len(q)
    if 0 < k < n - 1:
        yield pin.interpolate(robot.model, q[k - 1], q[k + 1], 0.5)
    for j in (k - 1, k + 1, k - 2, k + 2):
        if 0 <= j < n:
            yield q[j].copy()  # q[k] is written as the frame's parts are taken


def both_ways(robot: Robot, cameras: Sequence[Camera], masks: Sequence, forward_q: np.ndarray,
              options: TrackerOptions | Preset | None = None, *, margin: float = MARGIN, switch: float = SWITCH,
              tolerance: float = TOLERANCE, sweeps: int = SWEEPS, sources: Sequence[str] | None = None,
              progress: Callable | None = None, jobs: int = 1, **overrides) -> BothWays:
    """Track ``masks`` (a sequence of frames, each one mask per camera) backwards from
    the last pose of ``forward_q`` (frames, nq), the forward track of the same frames,
    with a :class:`~kms2pin.ecm.tracker.Tracker` of ``robot``, ``cameras`` and
    ``options`` / ``overrides`` (those of the forward track), and keep per frame the
    better-fitting poses, then the better-fitting parts (:func:`parts`), from the other track and then
    from the frames beside (module docstring; ``margin``, ``switch`` and ``tolerance`` as in
    :func:`choose`; :func:`take_parts`; ``sweeps`` as in :func:`take_beside`, 0: none).
    ``sources`` names each frame in error messages (default ``"frame k"``); ``progress``
    wraps the frames' iteration (a tqdm); ``jobs`` as :class:`~kms2pin.ecm.tracker.Tracker` takes it."""
    forward_q = np.asarray(forward_q, dtype=float)
    n = len(masks)
    if forward_q.shape != (n, robot.nq):
        raise ValueError(f"forward_q must have shape ({n}, {robot.nq}) (one pose per frame), not {forward_q.shape}")
    names = list(sources) if sources is not None else [f"frame {k}" for k in range(n)]
    order = range(n - 1, -1, -1)
    results: list[FrameResult | None] = [None] * n
    with Tracker(robot, cameras, options, q0=forward_q[-1], jobs=jobs, **overrides) as tracker:
        for k in progress(order) if progress is not None else order:
            results[k] = tracker.step(masks[k], source=names[k])
    fit_f, fit_b = np.empty(n), np.empty(n)
    for k in range(n):  # both fits at the sizes the backward pass ended with, each frame's masks read once
        m = masks[k]
        fit_f[k] = tracker.fit(forward_q[k], m, source=names[k])
        fit_b[k] = tracker.fit(results[k].q, m, source=names[k])
    backward_q = np.array([r.q for r in results])
    far = apart(robot, forward_q, backward_q)
    back = choose(fit_f, fit_b, far, margin, switch, tolerance)
    q = np.where(back[:, None], backward_q, forward_q)
    other = np.where(back[:, None], forward_q, backward_q)

    scorer = part_scorer(tracker, masks, names)
    q, fit_q, taken = take_parts(robot, scorer, q, other, np.where(back, fit_b, fit_f))
    q, fit_q, beside = take_beside(robot, scorer, q, fit_q, sweeps)
    return BothWays(q, back, fit_f, fit_b, far, results, fit_q, parts(robot), taken, beside)
