"""The per-frame ECM loop (thesis §2.1.2): E-step, M-step, static update, until the pose settles.

One iteration (:meth:`FrameECM.iterate`):

1. E-step (:class:`~kms2pin.ecm.estep.UnionEStep`): every body's sharp silhouette at
   the current, kinematically valid pose and what the others explain of each pixel;
2. M-step (:func:`~kms2pin.ecm.mstep.fit_bodies`): each body's 6-DoF pose refit on
   its own, the others held: the intermediate bodies;
3. static update (:mod:`~kms2pin.ecm.springs`, eq. 2.28 with the springs of eq. 2.33
   and the priors): the configuration pulled back to a valid one.

A frame (:meth:`FrameECM.run`) anneals the silhouettes' edge width from
``delta_start`` to ``delta_final`` pixels, halving it each iteration (a wide edge for
capture range, a narrow one for accuracy), and stops once, at the final width and
after ``min_iterations``, no joint moves more than ``tol_deg`` or no outline more than
``tol_px`` pixels.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ..robot import Robot
from ..virtual_work import SpringTerm
from .camera import Camera
from .estep import UnionEStep
from .masks import Views
from .mstep import BodyView, fit_bodies, fit_packed
from .options import TrackerOptions
from .prediction import Motion, VelocityGain, body_outline_pixels, image_motion
from .priors import DepthPrior
from .silhouette import PoseCache, silhouette_iou
from .sizes import BodySizes
from .springs import diagonal_update, full_update

__all__ = ["FrameECM", "new_timings"]


def new_timings() -> dict[str, float]:
    """Seconds spent per part of a frame, as :attr:`FrameResult.timings` reports them."""
    return {"e_step": 0.0, "m_step": 0.0, "static_update": 0.0, "sizes": 0.0}


class FrameECM:
    """ECM on one frame's views for ``robot`` with the tracker's ``options``, body
    ``sizes`` and standing ``priors`` (the depth prior is added per frame)."""

    def __init__(self, robot: Robot, options: TrackerOptions, sizes: BodySizes, priors: Sequence[SpringTerm] = ()):
        self.robot = robot
        self.options = options
        self.sizes = sizes
        self.priors = list(priors)
        sil = options.silhouette
        self.estep = UnionEStep(sil.max_pixels, sil.outlier, sil.outlier_px)
        self.poses = PoseCache(robot)
        self.motion = Motion(robot, options.iteration.max_prediction_deg)
        self.forget_motion()
        self._depth: DepthPrior | None = None

    def forget_motion(self) -> None:
        """Start the learnt motion model afresh (``prediction="learnt"``; else nothing)."""
        it = self.options.iteration
        if it.prediction == "learnt":
            self.motion.learnt = VelocityGain(self.robot.model.nv, it.prediction_memory)

    def e_step(self, q: np.ndarray, cameras: Sequence[Camera], masks: Sequence[np.ndarray],
               delta_px: float) -> tuple[list[pin.SE3], list[list[BodyView]]]:
        """The body poses at ``q`` and every body's views (:class:`UnionEStep`)."""
        poses, Rs, ts = self.poses(q)
        return poses, self.estep(poses, Rs, ts, self.sizes.inner, cameras, masks, delta_px)

    def fit(self, q: np.ndarray, views: Views) -> float:
        """The silhouette fit (IoU) at ``q`` (:func:`silhouette_iou`)."""
        poses, Rs, ts = self.poses(q)
        return silhouette_iou(poses, self.sizes.inner, views.cameras, views.masks, (Rs, ts))

    def iterate(self, q: np.ndarray, views: Views, delta_px: float, timings: dict,
                priors: Sequence[SpringTerm] = ()) -> np.ndarray:
        """One ECM iteration from ``q`` (``priors``: springs added to the standing ones);
        returns the new configuration."""
        opt = self.options
        m = opt.mstep
        t0 = time.perf_counter()
        poses, Rs, ts = self.poses(q)
        inner = self.sizes.inner
        packed = self.estep.packed(Rs, ts, inner, views.cameras, views.masks, delta_px)
        body_views = None if packed is not None else self.estep(poses, Rs, ts, inner, views.cameras, views.masks,
                                                                  delta_px)
        t1 = time.perf_counter()
        if packed is not None:  # the same fits as fit_bodies', in one kernel call
            fits = fit_packed(packed, Rs, ts, inner, iterations=m.m_iterations, damping=m.damping, max_step=m.max_step)
        else:
            fits = fit_bodies(body_views, poses, inner, iterations=m.m_iterations, damping=m.damping,
                              max_step=m.max_step)
        t2 = time.perf_counter()
        if opt.springs.static == "diagonal":
            q_new = diagonal_update(self.robot, q, fits, opt.springs.stiffness_floor)
        else:
            terms = ([self._depth] if self._depth is not None else []) + self.priors + list(priors)
            q_new = full_update(self.robot, q, fits, self.sizes.inner, opt.springs.stiffness_floor,
                                opt.springs.static_iterations, terms)
        t3 = time.perf_counter()
        timings["e_step"] += t1 - t0
        timings["m_step"] += t2 - t1
        timings["static_update"] += t3 - t2
        return q_new

    def _outline(self, q: np.ndarray, cameras: Sequence[Camera]) -> list[np.ndarray]:
        _, Rs, ts = self.poses(q)
        return body_outline_pixels(Rs, ts, self.sizes.inner, cameras)

    def run(self, q: np.ndarray, views: Views, timings: dict, max_iterations: int | None = None,
            coarse: Views | None = None, binned: bool = False,
            priors: Sequence[SpringTerm] = ()) -> tuple[np.ndarray, int, bool]:
        """ECM iterations from ``q`` until the configuration settles (module docstring),
        at most ``max_iterations`` (default the options'); returns the configuration, the
        iterations run and whether it converged.  ``coarse``: the views binned 2x2 for the
        iterations whose edge is at least ``coarse_delta_px`` wide, or for all if ``binned``;
        ``priors``: springs added to the standing ones for this run only."""
        it_opt = self.options.iteration
        self._set_depth_prior(q, views.cameras)
        it = 0
        delta = it_opt.delta_start
        limit = it_opt.max_iterations if max_iterations is None else max(1, int(max_iterations))
        tol = np.radians(it_opt.tol_deg)
        fewest = min(it_opt.min_iterations, limit)
        outlines = it_opt.tol_px is not None

        def tested(k: int, d: float) -> bool:  # whether iteration k (edge width d) tests for convergence
            return k >= fewest and d <= it_opt.delta_final * 1.0001

        # the tests are left out where they cannot stop the loop (a screen's few iterations)
        pts = self._outline(q, views.cameras) if outlines and tested(1, delta) else None
        for it in range(1, limit + 1):
            if coarse is not None and (binned or delta >= it_opt.coarse_delta_px * 0.9999):
                q_new = self.iterate(q, coarse, 0.5 * delta, timings, priors)
            else:
                q_new = self.iterate(q, views, delta, timings, priors)
            test = tested(it, delta)
            settled = test and self.motion.change(q, q_new) < tol
            delta_next = max(it_opt.delta_final, 0.5 * delta)
            if outlines:
                compare = test and not settled  # this iteration's outline test
                needed = compare or (it < limit and tested(it + 1, delta_next))  # or the next one's
                pts_new = self._outline(q_new, views.cameras) if needed else None
                if compare:
                    settled = image_motion(pts, pts_new) < it_opt.tol_px
                pts = pts_new
            q = q_new
            delta = delta_next
            if test and settled:
                return q, it, True
        return q, it, False

    def _set_depth_prior(self, q: np.ndarray, cameras: Sequence[Camera]) -> None:
        """The depth prior of a frame started at ``q`` (a free root's position, the anchor)."""
        weight = self.options.priors.depth_prior
        free = self.robot.root == "free"
        self._depth = DepthPrior(weight, q[:3].copy(), [c.centre for c in cameras]) if free and weight > 0 else None
