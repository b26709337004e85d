"""M-step: analytic derivatives, unbiasedness at the truth, recovery of a moved body."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import require_kernels

from kms2pin import _numpy_kernels, native
from kms2pin.ecm import mstep
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.mstep import BodyView, body_image, body_images, closest_approach, fit_body
from kms2pin.ecm.raycast import render_mask

INNER = np.array([0.3, 0.8, 0.4])


def _moved(pose: pin.SE3, delta: np.ndarray) -> pin.SE3:
    """Pose moved by a world translation delta[:3] and a world rotation vector delta[3:]."""
    return pin.SE3(pin.exp3(delta[3:]) @ pose.rotation, pose.translation + delta[:3])


def _cams():
    return [Camera.default(), Camera.look_at(position=[8, 0, 8], target=[0, 0, 8])]


def _pose(rng):
    return pin.SE3(pin.exp3(rng.normal(size=3)), np.array([0.2, -0.1, 8.0]))


def _views(cams, pose, truth, delta=0.7, others=None):
    views = []
    for c in cams:
        img = body_image(c, pose, INNER, delta)
        mask = render_mask(c, [(truth, INNER)])
        y = mask[img.slices].ravel().astype(float)
        o = np.zeros_like(y) if others is None else others(c, img)
        views.append(BodyView(img, y, o))
    return views


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    cam = Camera.look_at(position=[8, 1, 8], target=[0, 0, 8])
    pose = _pose(rng)
    img = body_image(cam, pose, INNER, 1.0)
    a2, D = closest_approach(img, pose.rotation, pose.translation, INNER, True)
    h = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        p2 = _moved(pose, d)
        b2, _ = closest_approach(img, p2.rotation, p2.translation, INNER, False)
        np.testing.assert_allclose((b2 - a2) / h, D[:, k], atol=1e-4 * np.abs(D[:, k]).max())


def test_truth_is_nearly_a_fixed_point():
    rng = np.random.default_rng(2)
    truth = _pose(rng)
    fit = fit_body(_views(_cams(), truth, truth), truth, INNER, iterations=5)
    assert np.linalg.norm(fit.pose.translation - truth.translation) < 0.01  # 0.25 % of the body length
    assert np.degrees(np.linalg.norm(pin.log3(fit.pose.rotation @ truth.rotation.T))) < 1.0


@pytest.mark.parametrize("ncams", [1, 2])
def test_recovers_a_moved_body(ncams):
    rng = np.random.default_rng(3)
    truth = _pose(rng)
    start = _moved(truth, np.r_[rng.uniform(-0.05, 0.05, 3), np.radians(5) * rng.normal(size=3) / np.sqrt(3)])
    pose = start
    for delta in (2.0, 1.0, 0.7, 0.7):
        pose = fit_body(_views(_cams()[:ncams], pose, truth, delta), pose, INNER, iterations=3).pose
    err = pose.translation - truth.translation
    start_err = np.linalg.norm(start.translation - truth.translation)
    if ncams == 2:
        assert np.linalg.norm(err) < 0.3 * start_err + 0.01
    else:  # one camera (default: looking along z): depth is only weakly fixed by the image size
        assert np.linalg.norm(err[:2]) < 0.3 * start_err + 0.01
        assert abs(err[2]) < 0.15


def test_pixels_explained_by_others_do_not_pull():
    """A neighbour's pixels (o = 1) leave the body where it is."""
    rng = np.random.default_rng(4)
    truth = _pose(rng)
    neighbour = pin.SE3(truth.rotation, truth.translation + truth.rotation @ np.array([0.0, 1.2, 0.0]))

    def others(cam, img):
        return render_mask(cam, [(neighbour, INNER)])[img.slices].ravel().astype(float)

    views = []
    for c in _cams():
        img = body_image(c, truth, INNER, 0.7)
        y = render_mask(c, [(truth, INNER), (neighbour, INNER)])[img.slices].ravel().astype(float)
        views.append(BodyView(img, y, others(c, img)))
    fit = fit_body(views, truth, INNER, iterations=5)
    assert np.linalg.norm(fit.pose.translation - truth.translation) < 0.01


def test_no_views_keeps_the_pose():
    rng = np.random.default_rng(5)
    pose = _pose(rng)
    fit = fit_body([], pose, INNER)
    assert fit.pose == pose and fit.evidence == 0.0


def test_fit_gradient_is_half_the_cost_derivative_in_both_backends(backend):
    """grad = J^T r with J = dr/d(delta t, omega), so d(cost)/d delta = 2 grad (cost = sum r^2);
    checked by central differences of the cost, for the C kernel and the NumPy code."""
    rng = np.random.default_rng(5)
    truth = _pose(rng)
    pose = _moved(truth, np.r_[rng.normal(0, 0.03, 3), rng.normal(0, 0.05, 3)])
    views = _views(_cams(), pose, truth, delta=1.5)
    cost, grad, H, _ = mstep.body_cost(views, pose, INNER, True)
    h = 1e-6
    fd = np.empty(6)
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        fd[k] = (mstep.body_cost(views, _moved(pose, d), INNER, False)[0]
                 - mstep.body_cost(views, _moved(pose, -d), INNER, False)[0]) / (2 * h)
    np.testing.assert_allclose(2 * grad, fd, atol=2e-3 * np.abs(fd).max())
    assert np.all(np.linalg.eigvalsh(H) >= -1e-9)  # a Gauss-Newton matrix


def _size_views(rng):
    """Two views of a body drawn 8 % longer and 6 % thinner than INNER, with a share of
    each pixel explained by other bodies and inlier weights below 1."""
    truth = _pose(rng)
    scaled = INNER * np.array([0.94, 1.08, 1.0])
    views = []
    for c in _cams():
        img = body_image(c, truth, INNER * 1.2, 1.5)
        y = render_mask(c, [(truth, scaled)])[img.slices].ravel().astype(float)
        views.append(BodyView(img, y, rng.uniform(0, 0.3, y.shape), rng.uniform(0.5, 1, y.shape)))
    return truth, views


def test_size_gradient_matches_finite_differences(monkeypatch):
    """The size fit's gradient in the log semi-axes is half the derivative of its cost,
    checked by central differences (with every pixel's term: no saturated-edge cut, so
    in NumPy)."""
    monkeypatch.setattr(_numpy_kernels, "H_CUT", 1e9)
    truth, views = _size_views(np.random.default_rng(11))
    R, t = truth.rotation, truth.translation
    h = 1e-6
    with native.use("numpy"):
        cost, grad, H = mstep.body_scale_cost(views, R, t, INNER)
        fd = np.array([
            (mstep.body_scale_cost(views, R, t, INNER * np.exp(h * e))[0]
             - mstep.body_scale_cost(views, R, t, INNER * np.exp(-h * e))[0]) / (2 * h)
            for e in np.eye(3)
        ])
    np.testing.assert_allclose(2 * grad, fd, rtol=1e-6)
    assert np.all(np.linalg.eigvalsh(H) >= -1e-9)  # a Gauss-Newton matrix


def test_size_fit_moves_towards_the_drawn_sizes(backend):
    truth, views = _size_views(np.random.default_rng(12))
    f, H = mstep.fit_body_scale(views, truth, INNER, iterations=4)
    assert f[0] < 0.97 and f[1] > 1.02  # towards the drawn sizes (0.94, 1.08)
    assert np.all(np.linalg.eigvalsh(H) >= -1e-9)


def test_body_images_match_body_image_one_by_one(backend):
    """The vectorized boxes (the body_boxes kernel) equal body_image's, also for bodies
    straddling the camera plane or out of view, and under lens distortion (which takes
    the per-body path)."""
    from pathlib import Path

    from kms2pin.robot import load

    robot = load(Path(__file__).resolve().parents[2] / "specs" / "fullbody.kms", root="free")
    rng = np.random.default_rng(3)
    centre = robot.q_rest[:3]
    cams = [
        Camera.default(),
        Camera.look_at(position=[8, 3, 8], target=centre),
        Camera.look_at(position=[0.5, 0, 6.5], target=centre),  # close: some bodies straddle
    ]
    cams.append(Camera(cams[1].K, cams[1].world_T_camera, cams[1].width, cams[1].height, dist=[0.1, -0.05, 0, 0, 0]))
    inners = [robot.inner(b) for b in robot.bodies]
    kinds = set()
    for _ in range(20):
        q = robot.random_configuration(rng, 60)
        q[:3] += rng.normal(0, 1.5, 3)
        poses = robot.body_poses(q)
        for cam in cams:
            for delta_px in (0.7, 3.0):
                for a, (P, L) in zip(body_images(cam, poses, inners, delta_px), zip(poses, inners)):
                    b = body_image(cam, P, L, delta_px)
                    assert (a is None) == (b is None)
                    kinds.add("none" if a is None else "full" if a.box.shape == cam.shape else "box")
                    if a is not None:
                        assert (a.box, a.stride) == (b.box, b.stride)
                        assert a.delta == pytest.approx(b.delta, rel=1e-12)
                        np.testing.assert_array_equal(a.dirs, b.dirs)
    assert kinds == {"none", "full", "box"}


def test_box_kernel_rejects_malformed_arrays_instead_of_crashing():
    k = require_kernels()
    n = 3
    args = [np.zeros((n, 9)), np.zeros((n, 3)), np.ones((n, 3)), np.eye(3), np.zeros(3), np.eye(3), 0.7, 2.0, 320, 240]
    outs = [np.zeros((n, 4)), np.zeros(n), np.zeros(n)]
    k.body_boxes(*args, *outs)  # well formed: bodies at the camera centre are not in view
    assert not outs[2].any()
    bad_t = list(args)
    bad_t[1] = np.zeros((n + 1, 3))
    with pytest.raises(ValueError, match="wrong shape"):
        k.body_boxes(*bad_t, *outs)
    with pytest.raises(ValueError, match="wrong shape"):
        k.body_boxes(*args, np.zeros((n, 3)), outs[1], outs[2])
    with pytest.raises(TypeError, match="float64"):
        k.body_boxes(args[0].astype(np.float32), *args[1:], *outs)
    with pytest.raises(TypeError, match="13 arguments"):
        k.body_boxes(*args)
