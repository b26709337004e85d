"""Prediction and convergence: the outline test of a frame's iterations."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import require_kernels

from kms2pin import native
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.prediction import (
    LEARNT_PRIOR_DEG,
    Motion,
    VelocityGain,
    image_motion,
    outline_pixels,
    outline_points,
)
from kms2pin.ecm.silhouette import PoseCache
from kms2pin.ecm.tracker import Tracker

from ._tracking import (
    _robot,
    _still_subject,
    centre_error,
)


def test_image_motion_is_the_pinhole_displacement_of_the_outline_points():
    robot = _robot("lowerbody")
    cam = Camera.default()
    inner = np.array([robot.inner(b) for b in robot.bodies])
    cache = PoseCache(robot)

    def points(q):
        _, Rs, ts = cache(q)
        return outline_points(Rs, ts, inner)

    q = robot.q_rest.copy()
    a = points(q)
    assert a.shape == (7 * len(robot.bodies), 3)
    # each body's centre and the ends of its inner ellipsoid's axes
    centres = robot.maximal_coordinates(q)[:, :3]
    np.testing.assert_allclose(a.reshape(-1, 7, 3).mean(axis=1), centres, atol=1e-12)
    q2 = q.copy()
    q2[0] += 0.05  # the root 0.05 along world x, across the default camera's view
    b = points(q2)
    np.testing.assert_allclose(b - a, np.tile([0.05, 0.0, 0.0], (len(a), 1)), atol=1e-12)
    # pinhole: a point at depth z moves f * dx / z pixels
    z = (a - cam.centre) @ cam.world_R_camera[:, 2]
    expected = cam.K[0, 0] * 0.05 / z.min()
    moved = image_motion(outline_pixels(points(q), [cam]), outline_pixels(points(q2), [cam]))
    assert moved == pytest.approx(expected, rel=1e-9)
    # the poses kept for the last configuration follow it, also when it is changed in place
    np.testing.assert_array_equal(points(q), a)
    q[0] += 0.05
    np.testing.assert_array_equal(points(q), b)


def test_one_camera_still_subject_converges_on_the_outline_test():
    """With one camera, a body's depth is barely seen and creeps from iteration to
    iteration after its outline has settled: the outline test stops the iterations."""
    robot, cams, qt, masks, kw = _still_subject()
    tr = Tracker(robot, cams, **kw)
    res = [tr.step(masks) for _ in range(4)]
    assert all(r.converged for r in res[1:])
    assert max(r.iterations for r in res[1:]) < tr.options.iteration.max_iterations
    # one view fixes depth only through the outline's size: the track settles about 3 %
    # of the height off in depth (as with the joint-angle test alone), not further
    assert centre_error(robot, res[-1].q, qt) < 5.0


def test_the_learnt_share_is_the_least_squares_fit_of_each_velocity_on_the_one_before():
    rng = np.random.default_rng(3)
    memory, n = 6.0, 25
    v = rng.normal(size=(n, 4)) * 0.05 + np.array([0.04, -0.03, 0.0, 0.01])
    gain = VelocityGain(4, memory)
    for x in v:
        gain.update(x)
    # an independent sum: frame k (of the n - 1 pairs) weighs (1 - 1/memory)^(n - 1 - k), the prior the oldest
    w = (1.0 - 1.0 / memory) ** np.arange(n - 2, -1, -1)
    prior = np.radians(LEARNT_PRIOR_DEG) ** 2 * (1.0 - 1.0 / memory) ** (n - 1)
    expected = (prior + (w[:, None] * v[1:] * v[:-1]).sum(0)) / (prior + (w[:, None] * v[:-1] ** 2).sum(0))
    np.testing.assert_allclose(gain.gain, np.clip(expected, 0.0, 1.0), rtol=1e-12)


def test_a_steady_motion_is_carried_on_and_a_jitter_is_not():
    gain = VelocityGain(2, 10.0)
    for k in range(30):
        gain.update(np.radians([3.0, 5.0 * (-1) ** k]))
    assert gain.gain[0] == pytest.approx(1.0) and gain.gain[1] == 0.0
    gain.update(None)  # a frame without a velocity: the next one pairs with nothing
    before = gain.gain.copy()
    gain.update(np.radians([-40.0, 40.0]))
    np.testing.assert_array_equal(gain.gain, before)


def test_the_learnt_prediction_moves_a_jittering_joint_by_its_share_only():
    robot = _robot("lowerbody")
    motion = Motion(robot, 20.0)
    motion.learnt = VelocityGain(robot.nv, 10.0)
    prev, cur = robot.q_rest.copy(), robot.q_rest.copy()
    cur[7] += np.radians(2.0)  # one joint moves 2 deg a frame, steadily
    cur[8] += np.radians(4.0)  # another jitters by 4 deg
    for k in range(20):
        motion.learn(prev, cur)
        prev, cur = cur, cur.copy()
        cur[7] += np.radians(2.0)
        cur[8] += np.radians(4.0) * (-1) ** (k + 1) * 2
    step = np.degrees(pin.difference(robot.model, cur, motion.predict(cur, prev)))
    assert step[6] == pytest.approx(2.0, abs=1e-6) and abs(step[7]) < 1e-9


def test_prediction_learnt_is_a_tracker_option_whose_model_a_restart_forgets():
    robot, cams, _, masks, kw = _still_subject()
    tr = Tracker(robot, cams, prediction="learnt", **kw)
    tr.step(masks)
    tr.step(masks)
    assert tr.ecm.motion.learnt.last is not None
    tr.restart(robot.q_rest)
    assert tr.ecm.motion.learnt.last is None
    assert Tracker(robot, cams).ecm.motion.learnt is None


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_the_outline_kernel_projects_as_the_camera_does(backend):
    """outline_pixels (the kernel the iterations' outline test calls) gives Camera.project
    of outline_points to rounding, NaN where a point is at or behind the camera plane."""
    if backend == "c":
        require_kernels()
    kernel = native.implementations("outline_pixels")[backend]
    rng = np.random.default_rng(4)
    n = 30
    R = np.array([pin.Quaternion(*rng.normal(size=4)).normalized().toRotationMatrix() for _ in range(n)])
    cam = Camera(np.array([[400.0, 0.0, 320.0], [0.0, 410.0, 240.0], [0.0, 0.0, 1.0]]),
                 pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.array([0.2, -0.1, 0.0])), 640, 480)
    t = cam.centre + np.c_[rng.uniform(-1, 1, (n, 2)), rng.uniform(-0.5, 5.0, n)] @ cam.world_R_camera.T
    inner = rng.uniform(0.05, 0.4, (n, 3))
    out = np.empty((7 * n, 2))
    kernel(R.reshape(n, 9), t, inner, cam.world_R_camera, cam.centre, cam.K, out)
    expected = cam.project(outline_points(R, t, inner))
    behind = np.isnan(expected[:, 0])
    assert 0 < behind.sum() < len(behind)
    np.testing.assert_array_equal(np.isnan(out[:, 0]), behind)
    np.testing.assert_allclose(out[~behind], expected[~behind], rtol=1e-12, atol=1e-9)


def test_image_motion_leaves_out_what_is_behind_a_camera_and_what_overflows():
    a = [np.array([[0.0, 0.0], [1.0, 1.0], [np.nan, np.nan]]), np.array([[5.0, 5.0]])]
    b = [np.array([[3.0, 4.0], [1.0, 1.0], [2.0, 2.0]]), np.array([[np.nan, np.nan]])]
    assert image_motion(a, b) == 5.0
    huge = [np.array([[1e300, 0.0], [0.0, 0.0]])]
    with np.errstate(over="ignore"):  # 2e300 squared
        assert image_motion(huge, [np.array([[-1e300, 0.0], [0.0, 2.0]])]) == 2.0
    assert image_motion([np.full((2, 2), np.nan)], [np.zeros((2, 2))]) == 0.0


def test_body_pose_arrays_are_the_body_poses_and_do_not_move_with_the_next_configuration():
    robot = _robot("lowerbody")
    q = robot.q_rest.copy()
    Rs, ts = robot.body_pose_arrays(q)
    poses = robot.body_poses(q)
    np.testing.assert_array_equal(Rs, [P.rotation for P in poses])
    np.testing.assert_array_equal(ts, [P.translation for P in poses])
    q2 = q.copy()
    q2[0] += 0.3
    robot.forward(q2)  # Pinocchio's frames move; the arrays read before do not
    np.testing.assert_array_equal(ts, [P.translation for P in poses])
