"""A finished track refit over time: each frame's ECM held towards the frames beside it (offline).

A frame's silhouettes fix some coordinates firmly and others hardly at all: an arm three
or four pixels wide, an elbow nearly straight, a limb in front of the trunk.  Tracked
frame by frame, those coordinates wander from frame to frame within what the masks
allow.  Low-pass filtering (:mod:`~kms2pin.ecm.smoothing`) smooths them without the
masks, so it also cuts real fast motion.  :func:`temporal` keeps the masks and adds time.
Each frame ``t`` is refit by the frame's ECM (:meth:`~kms2pin.ecm.tracker.Tracker.refine`)
with one more spring in the static update (§2.3.3, eq. 2.28, a spring like eq. 2.33's on
every coordinate; :class:`~kms2pin.ecm.priors.RestPrior`):

    E_t(q) = E_masks,t(q) + ½ k |q ⊖ g_t|²,   g_t = halfway from q_t to m_t,
    m_t = the midpoint of q_{t-1} and q_{t+1}

so the target ``g_t`` weighs the frame before, the frame itself and the frame after 1/4,
1/2 and 1/4 (:func:`targets`).  ``⊖`` is ``pin.difference`` and each "halfway"
``pin.interpolate`` (a free root moves along SE(3)'s screw).  The first and last frames
take the midpoint of themselves and their one neighbour (:func:`midpoints`).  The frame's
own pose in its target keeps a stiff spring from swinging a frame-to-frame jitter between
the odd and the even frames from sweep to sweep, as the neighbours' midpoint alone does
(a Jacobi sweep's highest mode; docs/design/tracking-history.md).  The stiffness is the
same for every coordinate: ``weight`` times the mean stiffness of the frame's data
springs.  So a coordinate the masks fix firmly hardly moves, and one they hardly fix
follows its neighbours.  A sweep refits every frame from the last sweep's poses and
targets (a Jacobi sweep: the order of the frames does not matter, so the frames can be
refit in several processes at once, ``jobs``).  Each frame's ECM runs from each of
``starts``, any of its own pose, its target and the midpoint of the frames beside (by
default :data:`STARTS`, the first two); the end that fits the masks best is kept (a tie
to the earlier in that order).  A frame whose own pose sits in a wrong basin
(an arm a few pixels off, bent the wrong way) is refit from where the frames beside put
it too.  The first sweeps run coarse to fine in time (``spans``, by default
:data:`SPANS`): their frames beside are ``h`` frames away, not one (m_t the midpoint of
q_{t-h} and q_{t+h}; near the ends ``h`` shrinks to the frames there are), so a pull
spreads about h² times as far in a sweep, as a multigrid's coarse levels do, and the
sweeps at ``h`` = 1 after them hold each frame to the frames next to it.  Every
``sizes_every`` sweeps (:data:`SIZES_EVERY`) the body sizes are measured again at the
refit's poses, on every second frame its masks can drive, from the evidence of those
frames alone (:meth:`~kms2pin.ecm.tracker.Tracker.measure_sizes`): the online track
measured them at its own, worse poses, and an ellipsoid sized there fits the true pose
less well.  Before each sweep of ``searches`` (:data:`SEARCHES`) every frame's limbs are
searched again from its pose, on its masks alone, by the tracker's reach search
(:meth:`~kms2pin.ecm.tracker.Tracker.reach_limbs`; nothing without ``reach_search``): an
arm held in a wrong basin by the frames beside, which ECM does not leave, is re-aimed at
the masks, and the sweeps after it carry the move to the frames around.  Repeated sweeps
spread the pull over longer stretches, like a smoothness prior over the recording.  The
track should already hold the subject (:mod:`~kms2pin.ecm.stretches`,
:mod:`~kms2pin.ecm.bothways`): a stretch lost throughout is not found again.  It uses the
frames after each frame, so it is for a finished recording.  Measured on real motion:
docs/tracking.md, "Real motion".
"""

from __future__ import annotations

import multiprocessing as mp
import signal
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .priors import RestPrior
from .tracker import Tracker
from .workers import FORK

__all__ = ["SEARCHES", "SIZES_EVERY", "SPANS", "START_NAMES", "STARTS", "SWEEPS", "WEIGHT", "Temporal", "midpoints",
           "processes", "span", "targets", "temporal"]

#: the spring towards the frames beside, in the frame's mean data stiffness
#: (docs/design/tracking-history.md)
WEIGHT = 0.01
#: how many sweeps over the frames (docs/design/tracking-history.md)
SWEEPS = 20
#: the distance (frames) to the frames beside in each of the first sweeps' targets, 1 in the
#: sweeps after them: coarse to fine in time (docs/design/tracking-history.md)
SPANS = (4, 4, 4, 4, 2, 2, 2, 2)
#: the sweeps (counted from 0) before which every frame's limbs are searched again by the
#: reach search (docs/design/tracking-history.md)
SEARCHES = (4, 8)
#: where each frame's ECM may start: its own pose (the last sweep's), its target
#: (:func:`targets`), the midpoint of the frames beside it (:func:`midpoints`)
START_NAMES = ("pose", "target", "neighbours")
#: where each frame's ECM starts by default (docs/design/tracking-history.md)
STARTS = ("pose", "target")
#: the body sizes measured again at the refit's poses before every this many sweeps
#: after the first ones (0: the track's sizes throughout; docs/design/tracking-history.md)
SIZES_EVERY = 2


@dataclass(frozen=True)
class Temporal:
    """The refit track: ``q`` (frames, nq), each frame's silhouette fit ``fit`` (IoU) and
    the body sizes it was fit at, ``scales`` (n_bodies, 3, relative to the spec's; the
    tracker's own unless re-measured, ``sizes_every``)."""

    q: np.ndarray
    fit: np.ndarray
    scales: np.ndarray


def midpoints(model: pin.Model, q: np.ndarray, h: int = 1) -> np.ndarray:
    """(frames, nq): each frame's midpoint of the frames ``h`` before and after it (``h``
    shrunk to the frames there are near the ends, to 1 at least: the first and last frames
    take themselves and their neighbour)."""
    n = len(q)
    out = []
    for t in range(n):
        k = max(1, min(int(h), t, n - 1 - t))
        out.append(pin.interpolate(model, q[max(t - k, 0)], q[min(t + k, n - 1)], 0.5))
    return np.array(out)


def targets(model: pin.Model, q: np.ndarray, h: int = 1) -> np.ndarray:
    """(frames, nq): each frame's target, halfway from its pose to :func:`midpoints`' (with
    ``h`` = 1 the weights 1/4, 1/2, 1/4 of the frame before, the frame and the frame after)."""
    if len(q) < 2:
        return np.array(q, dtype=float)
    return np.array([pin.interpolate(model, x, m, 0.5) for x, m in zip(q, midpoints(model, q, h))])


def span(spans: Sequence[int], k: int) -> int:
    """The distance to the frames beside in sweep ``k`` (counted from 0) of ``spans``: its
    ``k``-th, 1 past its end."""
    return int(spans[k]) if k < len(spans) else 1


def temporal(tracker: Tracker, masks: Sequence, q: np.ndarray, *, weight: float = WEIGHT, sweeps: int = SWEEPS,
             starts: Sequence[str] = STARTS, sizes_every: int = SIZES_EVERY, searches: Sequence[int] = SEARCHES,
             spans: Sequence[int] = SPANS, sources: Sequence[str] | None = None,
             progress: Callable | None = None, jobs: int = 1) -> Temporal:
    """The track ``q`` (frames, nq) of ``masks`` (a sequence of frames, each one mask per
    camera) refit over time (module docstring) by ``tracker`` (the one that made the
    track, at the body sizes it ended with): ``sweeps`` sweeps, the spring ``weight``,
    each frame's ECM from each of ``starts`` (names in :data:`START_NAMES`), the best fit
    kept, the body sizes measured again every ``sizes_every`` sweeps (0: never; the
    tracker's own are left as they were), every frame's limbs searched again before each
    sweep of ``searches`` (counted from 0; sweeps past the last are ignored), the frames
    beside ``spans[k]`` frames away in sweep ``k`` (1 past its end; empty: 1 throughout).
    ``jobs`` processes refit a sweep's frames at once (forked, Linux only; the same results as
    one).  ``sources`` names each frame in error messages (default ``"frame k"``);
    ``progress`` wraps each sweep's iteration over the frames (a tqdm)."""
    q = np.array(q, dtype=float)
    n, robot = len(masks), tracker.robot
    if q.shape != (n, robot.nq):
        raise ValueError(f"q must have shape ({n}, {robot.nq}) (one pose per frame), not {q.shape}")
    if not weight >= 0 or not np.isfinite(weight):
        raise ValueError(f"weight must be a finite number >= 0, not {weight!r}")
    if not _whole(sweeps):
        raise ValueError(f"sweeps must be a whole number >= 0, not {sweeps!r}")
    given = tuple(starts)
    if not given or any(s not in START_NAMES for s in given) or len(set(given)) != len(given):
        raise ValueError(f"starts must name each of {', '.join(START_NAMES)} at most once, and one at least, "
                         f"not {given!r}")
    starts = tuple(s for s in START_NAMES if s in given)  # a tie (an empty frame: 0 from each) to the frame's pose
    if not _whole(sizes_every):
        raise ValueError(f"sizes_every must be a whole number >= 0, not {sizes_every!r}")
    searches = tuple(searches)
    if not _all_whole(searches):
        raise ValueError(f"searches must be sweeps' numbers, whole numbers >= 0, not {searches!r}")
    searched = {int(k) for k in searches}
    spans = tuple(spans)
    if not _all_whole(spans, 1):
        raise ValueError(f"spans must be distances in frames, whole numbers >= 1, not {spans!r}")
    if not _whole(jobs, 1):
        raise ValueError(f"jobs must be a whole number >= 1, not {jobs!r}")
    names = list(sources) if sources is not None else [f"frame {k}" for k in range(n)]
    own = tracker.scales.copy()
    if not sweeps:
        return Temporal(q, np.array([tracker.fit(q[t], masks[t], source=names[t]) for t in range(n)]), own)
    global _SHARED
    scales, fit, pool, done = own, np.zeros(n), None, False
    try:
        _SHARED = (tracker, masks, names, float(weight))
        if processes(jobs, n) > 1:
            pool = mp.get_context("fork").Pool(processes(jobs, n), initializer=_quiet)
        for k in range(int(sweeps)):
            if sizes_every and k and k % int(sizes_every) == 0:
                tracker.sizes.set_all(scales)  # measured from the sizes in use, however many processes
                scales = tracker.measure_sizes((masks[t], q[t], names[t]) for t in range(0, n, 2) if fit[t] > 0)
            if k in searched and tracker.reach is not None:
                q = _searched(q, scales, pool, int(jobs))
            q, fit = _sweep(q, starts, scales, span(spans, k), pool, int(jobs), progress)
        done = True
    finally:
        _SHARED = None
        tracker.sizes.set_all(own)
        if pool is not None:  # finished, the idle processes leave by themselves; else they are stopped
            if done:
                pool.close()
            else:
                pool.terminate()
            pool.join()
    return Temporal(q, fit, scales)


def _whole(x, least: int = 0) -> bool:
    """Whether ``x`` is a whole number >= ``least`` (anything else, a string, None or NaN: False)."""
    try:
        return int(x) == x and x >= least
    except (TypeError, ValueError, OverflowError):
        return False


def _all_whole(xs: Sequence, least: int = 0) -> bool:
    """Whether every one of ``xs`` is a whole number >= ``least`` (:func:`_whole`), and none a bool."""
    return all(_whole(x, least) and not isinstance(x, bool) for x in xs)


def processes(jobs: int, n: int) -> int:
    """How many processes :func:`temporal` refits ``n`` frames in when given ``jobs``
    (one where it cannot fork)."""
    return min(int(jobs), n) if FORK and n > 1 else 1


#: the refit's tracker, masks, frame names and weight, for the frames' refits (set while
#: :func:`temporal` runs; a forked process starts with them)
_SHARED: tuple | None = None


def _quiet() -> None:
    """A refitting process ignores Ctrl-C (the process that started it handles it) and
    ends quietly on SIGTERM (the pool's terminate; not the command line's handler, which
    raises and would leave the pool's queue locked)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _sweep(q: np.ndarray, starts: tuple[str, ...], scales: np.ndarray, h: int, pool, jobs: int,
           progress: Callable | None) -> tuple[np.ndarray, np.ndarray]:
    """One sweep: every frame refit from the last sweep's poses ``q`` at the body sizes
    ``scales``, the frames beside ``h`` frames away (in ``pool``'s processes if there is
    one); the new poses and their fits."""
    model, n = _SHARED[0].robot.model, len(q)
    middle = targets(model, q, h)
    points = {"pose": q, "target": middle}
    if "neighbours" in starts:
        points["neighbours"] = midpoints(model, q, h)
    items = [(t, np.array([points[s][t] for s in starts]), middle[t], scales) for t in range(n)]
    done = _each(_refit, items, pool, jobs)
    new, fit = q.copy(), np.zeros(n)
    for t in range(n) if progress is None else progress(range(n)):
        new[t], fit[t] = next(done)  # imap keeps the frames' order
    return new, fit


def _searched(q: np.ndarray, scales: np.ndarray, pool, jobs: int) -> np.ndarray:
    """Every frame's limbs searched again from its pose ``q[t]`` at the body sizes
    ``scales`` (:meth:`~kms2pin.ecm.tracker.Tracker.reach_limbs`; in ``pool``'s processes
    if there is one)."""
    return np.array(list(_each(_reach, [(t, q[t], scales) for t in range(len(q))], pool, jobs)))


def _each(fn: Callable, items: list, pool, jobs: int):
    """``fn`` of each of ``items``, in order (in ``pool``'s processes if there is one)."""
    return map(fn, items) if pool is None else pool.imap(fn, items, chunksize=max(1, len(items) // (8 * jobs)))


def _shared_at(scales: np.ndarray) -> tuple:
    """:data:`_SHARED`, its tracker at the body sizes ``scales`` (a forked process holds the
    sizes it was forked with)."""
    if not np.array_equal(_SHARED[0].scales, scales):
        _SHARED[0].sizes.set_all(scales)
    return _SHARED


def _reach(item: tuple[int, np.ndarray, np.ndarray]) -> np.ndarray:
    """Frame ``t``'s limbs searched again from ``q`` at the body sizes ``scales``."""
    t, q, scales = item
    tracker, masks, names, _ = _shared_at(scales)
    return tracker.reach_limbs(q, masks[t], names[t])[0]


def _refit(item: tuple[int, np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, float]:
    """Frame ``t``'s refit at the body sizes ``scales`` from each of its starts towards its
    target (the best fit kept)."""
    t, points, target, scales = item
    tracker, masks, names, weight = _shared_at(scales)
    model = tracker.robot.model
    prior = (RestPrior(weight, model, target, np.arange(model.nv)),) if weight > 0 else ()
    frame = masks[t]
    best, best_fit = None, -np.inf
    for start in points:
        x, f = tracker.refine(start, frame, source=names[t], priors=prior)
        if f > best_fit:
            best, best_fit = x, f
    return best, float(best_fit)
