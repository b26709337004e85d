"""ECM tracking of a sequence (thesis §2.1.2): the tracker keeps the sequence and calls the parts.

Per frame :meth:`Tracker.step`:

1. checks the masks (:mod:`~kms2pin.ecm.masks`) and leaves out cameras that see nothing;
2. on the first frame measures the body sizes (:mod:`~kms2pin.ecm.sizes`);
3. predicts the pose from the last frame's motion (:mod:`~kms2pin.ecm.prediction`);
4. runs ECM (:mod:`~kms2pin.ecm.loop`: E-step, M-step, static update with the priors
   of :mod:`~kms2pin.ecm.priors`) until the pose settles, and measures the silhouette
   fit (:mod:`~kms2pin.ecm.silhouette`);
5. on a falling fit tries the limb search (:mod:`~kms2pin.ecm.limbsearch`);
6. tracks the alternative hypotheses (:mod:`~kms2pin.ecm.hypotheses`), switching to one
   that leads;
7. flags poor fits, refines the body sizes on good frames, and moves on;
8. with ``second_track``, reports the pose of a tracker beside of the same frames (the
   options with some changed, going on by itself) where that fits better.

The options are :class:`~kms2pin.ecm.options.TrackerOptions`; guidance:
docs/tracking.md; how it is built: docs/design/tracker.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np
import pinocchio as pin

from ..errors import CameraError, InputDataError, OptionError
from ..robot import Robot
from .camera import Camera
from .hypotheses import KIND_WORDS, Hypotheses
from .limbs import sagittal_mirror
from .limbsearch import LimbMove, LimbSearch
from .loop import FrameECM, new_timings
from .masks import Views, check_masks, mask_problem
from .mstep import BodyView
from .options import SEGMENTED_MASKS, Preset, TrackerOptions, as_options, resolved, track_changes
from .priors import GroundPrior, feet, standing_priors
from .reach import ReachSearch
from .secondtrack import better
from .silhouette import IncrementalFit, visible_bodies
from .sizes import BodySizes
from .state import RunningFit, SequenceState
from .symmetry import Symmetry
from .trajectory import FrameResult, Trajectory, TrajectoryCsvWriter, poor_fit_flag
from .workers import BesideTracks

__all__ = ["SEGMENTED_MASKS", "FrameResult", "Tracker", "Trajectory", "TrajectoryCsvWriter"]


class Tracker:
    """ECM tracker for one robot seen by one or more cameras (thesis §2.1.2).

    Args:
        robot: the model (``root="free"`` for a moving subject).
        cameras: one :class:`Camera` per mask stream, or a single camera.
        options: a :class:`TrackerOptions` or a preset (``SEGMENTED_MASKS``, ``PEOPLE``, ``PEOPLE_TRACKS``,
            ``PEOPLE_ONE_CAMERA``); default the defaults.
        q0: starting pose (default ``robot.q_rest``); every camera must see part of
            the model there, else :class:`CameraError`.
        scales: (n_bodies, 3) factors on the spec's semi-axes to start from (default 1).
        jobs: processes to track in with tracks beside (``second_track``): track ``i`` in
            process ``i % jobs``, 0 this one, the others forked from it
            (:mod:`~kms2pin.ecm.workers`; the same results; :meth:`close` ends them).
        **overrides: options by their flat names (``upright=0.1``), over ``options``.

    The options as resolved for this robot and these cameras (the automatic ones
    decided) are :attr:`options`.
    """

    def __init__(self, robot: Robot, cameras: Camera | Sequence[Camera], options: TrackerOptions | Preset | None = None,
                 *, q0=None, scales=None, jobs: int = 1, **overrides: Any):
        opts = given = as_options(options, overrides)
        tracks = track_changes(opts.hypotheses.second_track)
        self.robot = robot
        self.cameras = [cameras] if isinstance(cameras, Camera) else list(cameras)
        if not self.cameras:
            raise OptionError("a tracker needs at least one camera")
        self.sizes = BodySizes(robot, scales)
        self._sagittal = sagittal_mirror(robot) if robot.root == "free" else None
        self._symmetry = Symmetry.of(robot)
        self.options = opts = resolved(opts, robot, len(self.cameras), self._sagittal, self._symmetry)
        self._reset(robot.q_rest if q0 is None else q0, "initial pose")
        # each camera binned 2x2, for the coarse iterations, the limb search's screening
        self._binned = {c: c.binned(2) for c in self.cameras if min(c.width, c.height) >= 8}
        free = robot.root == "free"
        joint_dofs = np.arange(6 if free else 0, robot.model.nv)  # every dof but a free root's six
        priors = standing_priors(robot, opts.priors, self.q, self.sizes.inner)
        self.ecm = FrameECM(robot, opts, self.sizes, priors)
        self._set_ground(self.q)
        self.limbs = LimbSearch(robot, self.ecm, self._symmetry)
        self.reach = self._reach_search(opts) if opts.limbs.reach_search else None
        hyp, lim = opts.hypotheses, opts.limbs
        kinds = {"mirror": hyp.mirror_margin} if hyp.mirror_hypothesis else {}
        kinds |= {"swap": hyp.swap_margin} if hyp.swap_hypothesis else {}
        kinds |= {"limb": lim.limb_margin} if lim.limb_hypothesis else {}
        self.hypotheses = Hypotheses(robot, self.ecm, self.ecm.motion, kinds, self._sagittal, self._symmetry,
                                     joint_dofs, hyp.hypothesis_iterations, hyp.binned_hypotheses,
                                     opts.iteration.prediction != "previous")
        # the tracks beside (second_track): the same options with each one's changes, each going on by itself
        beside = [Tracker(robot, self.cameras, given.replace(second_track="", **changes), q0=q0, scales=scales)
                  for changes in tracks]
        for c, cam in enumerate(self.cameras):
            if not self.visible_bodies(cameras=[cam]):
                name = f" '{cam.name}'" if cam.name else ""
                raise CameraError(
                    f"camera {c}{name} does not see the model at the starting pose: no body of "
                    f"'{robot.system.name}' falls in its {cam.width}x{cam.height} image (camera at "
                    f"{np.round(cam.centre, 3).tolist()}); check the camera's placement or the initial pose"
                )
        self._beside = BesideTracks(beside, jobs)  # forked here, with jobs > 1

    # ------------------------------------------------------------------ sizes
    @property
    def scales(self) -> np.ndarray:
        """(n_bodies, 3) the measured body sizes relative to the spec's."""
        return self.sizes.scales

    @property
    def inner(self) -> np.ndarray:
        """(n_bodies, 3) the inner semi-axes in use (the spec's times :attr:`scales`)."""
        return self.sizes.inner

    @property
    def outer(self) -> np.ndarray:
        """(n_bodies, 3) the outer semi-axes in use."""
        return self.sizes.outer

    def calibrate(self, masks, source: str = "frame", q: np.ndarray | None = None) -> np.ndarray:
        """Measure every body's semi-axes on ``masks`` with the configuration held at ``q``
        (default the current pose, i.e. ``q0`` before the first frame;
        :meth:`BodySizes.calibrate`); returns the scales (n_bodies, 3) relative to the spec."""
        self._beside.check()  # tracks beside that cannot go on: nothing changed here either
        checked = check_masks(masks, self.cameras, source, self.options.silhouette.clean)
        self._calibrate(Views.of(self.cameras, checked), self.q if q is None else np.asarray(q, dtype=float))
        self._beside.calibrate(masks, source, q)  # the masks as given: each checks (and cleans) them itself
        return self.scales.copy()

    def measure_sizes(self, frames: Iterable[tuple[Any, np.ndarray, str]]) -> np.ndarray:
        """(n_bodies, 3) the body sizes measured afresh (relative to the spec's) on
        ``frames``, each (one frame's masks, the configuration held there, its name for
        errors) (:meth:`BodySizes.remeasured`); the tracker is left as it was."""
        clean, delta = self.options.silhouette.clean, self.options.iteration.delta_final
        views = ((Views.of(self.cameras, check_masks(m, self.cameras, src, clean)), q) for m, q, src in frames)
        return self.sizes.remeasured(((self._e_step_on(v), np.asarray(q, dtype=float)) for v, q in views), delta)

    def _calibrate(self, views: Views, q: np.ndarray) -> None:
        it = self.options.iteration
        self.sizes.calibrate(self._e_step_on(views), q, self.options.sizes.size_iterations, it.delta_start,
                             it.delta_final)
        self._set_ground(q)

    def _reach_search(self, opts: TrackerOptions) -> ReachSearch:
        """The reach search; the arms it re-aims every frame (``reach_always="arms"``) are the
        limbs that do not reach the floor at the starting pose (its feet as the ground prior's)."""
        lim = opts.limbs
        on = feet(self.robot, self.q, self.sizes.inner, opts.priors.up)[0] if lim.reach_always == "arms" else ()
        return ReachSearch(self.robot, self.ecm, lim.reach_always, on, lim.reach_skip, lim.reach_always_directions,
                           lim.reach_rest)

    def _set_ground(self, q: np.ndarray) -> None:
        """The ground prior (``ground``) with its feet and floor (unless ``ground_height``
        is given) taken at ``q`` with the sizes in use: at q0, again once they are measured."""
        pri = self.options.priors
        if self.robot.root != "free" or pri.ground <= 0:
            return
        prior = GroundPrior.of(pri.ground, self.robot, pri.up, self.sizes.inner, q, pri.ground_height)
        self.ecm.priors = [p for p in self.ecm.priors if not isinstance(p, GroundPrior)] + [prior]

    def _e_step_on(self, views: Views):
        return lambda q, delta: self.ecm.e_step(q, views.cameras, views.masks, delta)

    # ------------------------------------------------------------------ one frame
    def step(self, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame") -> FrameResult:
        """Track one frame: ``masks`` is one (H, W) mask per camera (bool or 0/1).

        A frame whose masks are all empty keeps the last pose and is flagged
        ``"empty mask"``; a camera whose mask alone is empty is left out of the
        frame (flag ``"empty mask in camera k"``).  A mask more than 90 % foreground
        (:data:`~kms2pin.ecm.masks.NEARLY_FULL`) says nothing of the pose either:
        ``"mask nearly full"`` (every camera) or ``"mask nearly full in camera k"``.
        """
        if not len(self._beside):
            return self._step(masks, source)
        res, others = self._beside.step(masks, source, lambda: self._step(masks, source))
        return better(self, res, others, masks, source)

    def _step(self, masks, source: str) -> FrameResult:
        """:meth:`step` on this track alone."""
        opts, state = self.options, self.state
        masks = check_masks(masks, self.cameras, source, opts.silhouette.clean)
        timings = new_timings()
        problems = [mask_problem(m) for m in masks]
        if all(problems):  # nothing to go on: the pose is kept, with no velocity
            what = "mask nearly full" if "mask nearly full" in problems else "empty mask"
            res = FrameResult(self.q.copy(), self.robot.maximal_coordinates(self.q), 0, 0.0, False, (what,), timings)
            self.ecm.motion.learn(None, self.q)
            state.advance(self.q, keep_velocity=False)
            self.hypotheses.alts.clear()
            return res
        flags = tuple(f"{p} in camera {c}" for c, p in enumerate(problems) if p)
        views = Views.of(self.cameras, masks).seeing()
        if opts.sizes.calibrate_sizes and not self.sizes.calibrated:
            self._calibrate(views, self.q)
        q = self.q.copy()
        if opts.iteration.prediction != "previous":
            q = self.ecm.motion.predict(q, state.prev)
        coarse = self._coarse(views)
        q, it, converged = self.ecm.run(q, views, timings, coarse=coarse)
        fit = self.ecm.fit(q, views)
        q, fit, moved, spawn = self._limb_search(q, fit, views, coarse, timings)
        flags += moved
        if self.reach is not None:
            q, fit, reached = self.reach.search(q, fit, views, views.binned(self._binned), coarse, timings)
            flags += tuple(f for move in reached for f in self._moved(q, move))
        if self.hypotheses.margins:
            q, fit, switched = self.hypotheses.step(q, fit, state, views, timings, coarse,
                                                    lambda: views.binned(self._binned), spawn)
            if switched:
                flags += (f"switched to the {KIND_WORDS[switched]} hypothesis",)
        else:
            state.running.update(fit, state.frame)
        poor = fit < opts.silhouette.poor_fit
        if poor:
            flags += (poor_fit_flag(fit),)
        if fit == 0.0:  # the model's silhouettes miss the masks: nothing to go on
            q = self.q.copy()
            flags += ("lost: kept the last pose",)
        # a frame fitting at least as well as the running fit, with nothing to report, is
        # evidence on the body sizes (the first frame counts twice: its calibration at the
        # starting pose, then this refinement at the tracked pose; docs/design/tracking-history.md)
        every = opts.sizes.size_every
        if self.sizes.calibrated and every > 0 and state.frame % every == 0 and not flags \
                and fit >= state.running.score:
            t0 = time.perf_counter()
            self.sizes.refine(self._e_step_on(views), q, opts.iteration.delta_final)
            timings["sizes"] += time.perf_counter() - t0
        res = FrameResult(q.copy(), self.robot.maximal_coordinates(q), it, fit, converged, flags, timings)
        # a poorly fitting pose is no basis for a velocity: coasting on it carries a lost
        # track out of the view
        self.ecm.motion.learn(None if poor else self.q, q)
        state.advance(q, keep_velocity=not poor)
        return res

    def _coarse(self, views: Views) -> Views | None:
        """The binned views of the wide-edge iterations (``coarse_delta_px``), or None."""
        it = self.options.iteration
        if it.coarse_delta_px is None or it.delta_start < it.coarse_delta_px:
            return None
        return views.binned(self._binned)

    def _limb_search(self, q: np.ndarray, fit: float, views: Views, coarse: Views | None, timings: dict):
        """The limb search on a falling fit, or the limb-search hypothesis's candidate on a
        smaller fall, then (one camera) the exchange of twin limbs that crossed.  Returns
        the configuration, its fit, the moves' flags and the candidate to spawn (or None)."""
        lim, state = self.options.limbs, self.state
        moved: tuple[str, ...] = ()
        spawn = None
        score = state.running.score
        if lim.limb_search and state.running.settled(state.frame) and fit < score - lim.limb_search_drop:
            q, fit, move = self.limbs.search(q, fit, views, views.binned(self._binned), self._coarse(views), timings)
            moved = self._moved(q, move)
        elif lim.limb_hypothesis and state.frame > 0 and "limb" not in self.hypotheses.alts \
                and fit < score - lim.limb_hypothesis_drop:
            qs, fs, move = self.limbs.search(q, fit, views, views.binned(self._binned), None, timings,
                                             screen_only=True)
            spawn = (qs, fs, move) if move is not None else None
        if lim.limb_search and state.frame > 0 and len(views) == 1:
            # after twins cross, only one view can mistake one for the other
            q, fit, move = self.limbs.exchange_crossed(q, fit, state, views, lambda: self._coarse(views), timings)
            again = self._moved(q, move)
            # twins exchanged twice this frame are back in place: no exchange to report
            moved = () if again and again == moved else moved + again
        return q, fit, moved, spawn

    def _moved(self, q: np.ndarray, move: LimbMove | None) -> tuple[str, ...]:
        """After the limb search kept ``move`` in ``q``: the moved limbs' last pose as in
        ``q`` (the move is no motion to carry on), and the frame's flag."""
        if move is None:
            return ()
        self.q[move.indices] = q[move.indices]
        return (move.flag(),)

    # ------------------------------------------------------------------ one-off fits
    @property
    def q(self) -> np.ndarray:
        """The last frame's pose (the starting pose before the first frame)."""
        return self.state.q

    @q.setter
    def q(self, value: np.ndarray) -> None:
        self.state.q = value

    @property
    def tracks_beside(self) -> tuple[Tracker, ...]:
        """The trackers of the tracks beside (``second_track``), each going on by itself (one
        run by another process, ``jobs``: a :class:`~kms2pin.ecm.workers.RemoteTrack`, its pose ``q``)."""
        return self._beside.tracks

    @property
    def jobs(self) -> int:
        """The processes the tracks run in (``jobs`` as used: at most one per track)."""
        return self._beside.jobs

    def close(self) -> None:
        """End the processes of the tracks beside (``jobs``); nothing to do without them."""
        self._beside.close()

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def frame(self) -> int:
        """Frames tracked since the start (or the last :meth:`restart`)."""
        return self.state.frame

    def visible_bodies(self, q: np.ndarray | None = None, cameras: Sequence[Camera] | None = None) -> list[int]:
        """Indices of bodies whose inner silhouette falls in at least one camera."""
        poses = self.robot.body_poses(self.q if q is None else q)
        return visible_bodies(poses, self.inner, self.cameras if cameras is None else cameras)

    def fit(self, q: np.ndarray, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame") -> float:
        """The silhouette fit at ``q`` (:func:`~kms2pin.ecm.silhouette.silhouette_iou`) over
        every camera, at the tracker's current body sizes, as :attr:`FrameResult.fit`
        reports it for a frame that every camera sees."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.robot.model.nq,):
            raise ValueError(f"q has shape {q.shape}; the model has nq = {self.robot.model.nq}")
        masks = check_masks(masks, self.cameras, source, self.options.silhouette.clean)
        return self.ecm.fit(q, Views.of(self.cameras, masks))

    def part_fit(self, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame") -> IncrementalFit:
        """:meth:`fit` on one frame's ``masks`` for poses that differ from a base pose in a
        few bodies (:class:`~kms2pin.ecm.silhouette.IncrementalFit`: the same numbers, from
        the moved bodies alone), at the tracker's current body sizes."""
        masks = check_masks(masks, self.cameras, source, self.options.silhouette.clean)
        return IncrementalFit(self.robot, self.cameras, masks, self.ecm.sizes.inner)

    def e_step(self, q: np.ndarray, masks: Sequence[np.ndarray], delta_px: float,
               cameras: Sequence[Camera] | None = None) -> tuple[list[pin.SE3], list[list[BodyView]]]:
        """The E-step at ``q`` (:class:`~kms2pin.ecm.estep.UnionEStep`): the body poses and
        every body's views; ``cameras`` those of ``masks`` (default the tracker's)."""
        return self.ecm.e_step(q, self.cameras if cameras is None else cameras, masks, delta_px)

    def iterate(self, q: np.ndarray, masks: Sequence[np.ndarray], delta_px: float, timings: dict,
                cameras: Sequence[Camera] | None = None) -> np.ndarray:
        """One ECM iteration from ``q`` (:meth:`FrameECM.iterate`); returns the new q."""
        return self.ecm.iterate(q, Views.of(self.cameras if cameras is None else cameras, masks), delta_px, timings)

    def _seeing(self, masks, source: str) -> Views:
        """One frame's ``masks``, checked, as views of the cameras that can drive the pose."""
        return Views.of(self.cameras, check_masks(masks, self.cameras, source, self.options.silhouette.clean)).seeing()

    def _one_frame(self, q, masks, source: str, priors: Sequence = ()) -> tuple[Views, np.ndarray, dict] | None:
        """ECM from ``q`` on one frame's masks (no prediction, no hypotheses; ``priors``
        added to the standing ones), or None if no mask can drive the pose
        (:func:`~kms2pin.ecm.masks.mask_problem`)."""
        views = self._seeing(masks, source)
        if not len(views):
            return None
        timings = new_timings()
        q_new, _, _ = self.ecm.run(self.robot.clamp(np.array(q, dtype=float)), views, timings,
                                   coarse=self._coarse(views), priors=priors)
        return views, q_new, timings

    def refine(self, q: np.ndarray, masks, source: str = "frame", priors: Sequence = ()) -> tuple[np.ndarray, float]:
        """ECM on one frame's ``masks`` from ``q``, leaving the tracker as it was; returns
        the configuration and its fit (IoU).  ``priors``: springs of the static update
        added for this frame (:mod:`kms2pin.ecm.temporal`)."""
        done = self._one_frame(q, masks, source, priors)
        if done is None:
            return np.array(q, dtype=float), 0.0
        views, q_new, _ = done
        return q_new, self.ecm.fit(q_new, views)

    def swing_limbs(self, q: np.ndarray, masks, source: str = "frame") -> tuple[np.ndarray, float, LimbMove | None]:
        """The limb search on one frame: ECM from ``q`` (as :meth:`refine`), then every
        :class:`LimbMove`, leaving the tracker as it was.  Returns the configuration, its
        fit (IoU) and the move kept (None if none improved the fit)."""
        done = self._one_frame(q, masks, source)
        if done is None:
            return np.array(q, dtype=float), 0.0, None
        views, q0, timings = done
        return self.limbs.search(q0, self.ecm.fit(q0, views), views, views.binned(self._binned),
                                 self._coarse(views), timings)

    def reach_limbs(self, q: np.ndarray, masks, source: str = "frame") -> tuple[np.ndarray, float, int]:
        """The reach search (:mod:`~kms2pin.ecm.reach`) on one frame from ``q`` as it is (no
        ECM before it, no prediction, no rest after earlier searches), leaving the tracker as
        it was.  Returns the configuration, its fit (IoU) and the moves kept (0 without
        ``reach_search``, or where no mask can drive the pose)."""
        q = np.array(q, dtype=float)
        views = self._seeing(masks, source)
        if not len(views):
            return q, 0.0, 0
        fit = self.ecm.fit(q, views)
        if self.reach is None:
            return q, fit, 0
        q, fit, moves = self.reach.search_once(q, fit, views, views.binned(self._binned), self._coarse(views),
                                               new_timings())
        return q, fit, len(moves)

    # ------------------------------------------------------------------ sequences
    def restart(self, q0: np.ndarray) -> None:
        """Go on from ``q0`` as from a first frame's pose (no velocity, no alternative
        hypotheses), keeping every option, the measured body sizes and the root's upright
        axis, e.g. when the subject has been found again after leaving the view."""
        self._beside.check()
        self._reset(q0, "restart pose")
        self._beside.restart(q0)
        self.hypotheses.alts.clear()
        self.ecm.forget_motion()
        if self.reach is not None:
            self.reach.forget()

    def _reset(self, q0, what: str) -> None:
        q0 = np.array(q0, dtype=float)
        if q0.shape != (self.robot.nq,):
            raise InputDataError(f"{what} has {q0.size} values but '{self.robot.system.name}' needs {self.robot.nq}")
        if not np.isfinite(q0).all():
            raise InputDataError(f"{what} is not finite (coordinate {int(np.flatnonzero(~np.isfinite(q0))[0])})")
        self.state = SequenceState(q0, RunningFit(self.options.hypotheses.hypothesis_smoothing))

    def track(self, frames: Iterable, *, progress: bool = False,
              on_frame: Callable[[int, FrameResult], None] | None = None) -> Trajectory:
        """Track a sequence; each item is the frame's masks (one per camera)."""
        results: list[FrameResult] = []
        iterator = frames
        if progress:
            from tqdm import tqdm

            iterator = tqdm(frames, unit="frame", desc="tracking")
        for k, masks in enumerate(iterator):
            r = self.step(masks, source=f"frame {k}")
            results.append(r)
            if on_frame is not None:
                on_frame(k, r)
        return Trajectory(self.robot, np.array([r.q for r in results]).reshape(-1, self.robot.nq), results,
                          scales=self.scales)
