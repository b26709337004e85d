"""kms2pin.ecm.loop: a frame's ECM stops where a loop testing every iteration would."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin.ecm.loop import new_timings
from kms2pin.ecm.masks import Views
from kms2pin.ecm.prediction import body_outline_pixels, image_motion
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker

from ._tracking import _cams, _perturbed, _robot, centre_error


def _every_iteration_tested(ecm, q, views, limit):
    """FrameECM.run as it was written first: the convergence tests on every iteration."""
    it_opt = ecm.options.iteration
    delta, tol = it_opt.delta_start, np.radians(it_opt.tol_deg)

    def outline(x):
        _, Rs, ts = ecm.poses(x)
        return body_outline_pixels(Rs, ts, ecm.sizes.inner, views.cameras)

    pts = outline(q) if it_opt.tol_px is not None else None
    for it in range(1, limit + 1):
        q_new = ecm.iterate(q, views, delta, new_timings())
        settled = ecm.motion.change(q, q_new) < tol
        if pts is not None:
            pts_new = outline(q_new)
            settled = settled or image_motion(pts, pts_new) < it_opt.tol_px
            pts = pts_new
        q = q_new
        at_final = delta <= it_opt.delta_final * 1.0001
        delta = max(it_opt.delta_final, 0.5 * delta)
        if at_final and it >= min(it_opt.min_iterations, limit) and settled:
            return q, it, True
    return q, it, False


@pytest.mark.parametrize("options", [{}, {"tol_px": None}, {"min_iterations": 1}, {"min_iterations": 5},
                                     {"tol_deg": 5.0, "min_iterations": 1}, {"delta_start": 0.7}])
@pytest.mark.parametrize("limit", [1, 2, 3, 8])
def test_a_frame_stops_where_testing_every_iteration_would(options, limit):
    robot = _robot("lowerbody")
    rng = np.random.default_rng(5)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    masks = render(robot, qt, cams)
    tr = Tracker(robot, cams, calibrate_sizes=False, **options)
    views = Views.of(cams, masks)
    q0 = _perturbed(robot, qt, rng)
    q, its, done = tr.ecm.run(q0, views, new_timings(), max_iterations=limit)
    q_ref, its_ref, done_ref = _every_iteration_tested(tr.ecm, q0, views, limit)
    np.testing.assert_array_equal(q, q_ref)
    assert (its, done) == (its_ref, done_ref)
    # and from outside the loop: the iterations within their bounds, and the pose nearer
    # the truth it was rendered at than its start (every case here takes it closer)
    it_opt = tr.options.iteration
    assert 1 <= its <= limit and (not done or its >= min(it_opt.min_iterations, limit))
    assert done or its == limit
    assert centre_error(robot, q, qt) < centre_error(robot, q0, qt)
