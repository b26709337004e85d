"""M-step: analytic derivatives, unbiasedness at the truth, recovery of a moved body."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import require_kernels

from kms2pin.ecm import mstep
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.mstep import BodyView, _moved, body_image, body_images, closest_approach, fit_body
from kms2pin.ecm.raycast import render_mask

INNER = np.array([0.3, 0.8, 0.4])


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
    assert mstep.sigmoid(np.array([0.0]))[0] == pytest.approx(0.5)


@pytest.mark.parametrize("native", [True, False], ids=["native", "numpy"])
def test_fit_gradient_is_half_the_cost_derivative_in_both_backends(native, monkeypatch):
    """grad = J^T r with J = dr/d(delta t, omega), so d(cost)/d delta = 2 grad (cost = sum r^2);
    checked by central differences of the cost, for the C kernel and the NumPy code."""
    if native:
        require_kernels()
    monkeypatch.setattr(mstep, "NATIVE", native)
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


def test_native_and_numpy_fits_agree(monkeypatch):
    require_kernels()
    rng = np.random.default_rng(6)
    truth = _pose(rng)
    pose = _moved(truth, np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 0.1, 3)])
    views = _views(_cams(), pose, truth)
    views = [BodyView(v.image, v.y, rng.uniform(0, 0.5, v.y.shape), rng.uniform(0.5, 1, v.y.shape)) for v in views]
    out = {}
    for native in (True, False):
        monkeypatch.setattr(mstep, "NATIVE", native)
        out[native] = mstep.body_cost(views, pose, INNER, True)
    for a, b in zip(out[True], out[False]):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12 * np.abs(b).max())


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
    checked by central differences (with every pixel's term: no saturated-edge cut)."""
    monkeypatch.setattr(mstep, "NATIVE", False)
    monkeypatch.setattr(mstep, "H_CUT", 1e9)
    truth, views = _size_views(np.random.default_rng(11))
    R, t = truth.rotation, truth.translation
    cost, grad, H = mstep.body_scale_cost(views, R, t, INNER)
    h = 1e-6
    fd = np.array([
        (mstep.body_scale_cost(views, R, t, INNER * np.exp(h * e))[0]
         - mstep.body_scale_cost(views, R, t, INNER * np.exp(-h * e))[0]) / (2 * h)
        for e in np.eye(3)
    ])
    np.testing.assert_allclose(2 * grad, fd, rtol=1e-6)
    assert np.all(np.linalg.eigvalsh(H) >= -1e-9)  # a Gauss-Newton matrix


def test_native_and_numpy_size_fits_agree(monkeypatch):
    """The C size kernel (kms2pin/_kernels.c) gives fit_body_scale's sums and result."""
    require_kernels()
    truth, views = _size_views(np.random.default_rng(12))
    out = {}
    for native in (True, False):
        monkeypatch.setattr(mstep, "NATIVE", native)
        out[native] = (
            mstep.body_scale_cost(views, truth.rotation, truth.translation, INNER),
            mstep.fit_body_scale(views, truth, INNER, iterations=4),
        )
    for a, b in zip(out[True][0] + out[True][1], out[False][0] + out[False][1]):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-11 * np.abs(b).max())
    f = out[True][1][0]
    assert f[0] < 0.97 and f[1] > 1.02  # towards the drawn sizes (0.94, 1.08)


@pytest.mark.parametrize("max_step", [None, 0.05])
def test_native_and_numpy_body_fits_agree(monkeypatch, max_step):
    """The C fit (kms2pin/_kernels.c) runs the same damped Gauss-Newton loop as fit_body."""
    require_kernels()
    rng = np.random.default_rng(9)
    truth = _pose(rng)
    pose = _moved(truth, np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 0.1, 3)])
    views = _views(_cams(), pose, truth, delta=1.0)
    fits = {}
    for native in (True, False):
        monkeypatch.setattr(mstep, "NATIVE", native)
        fits[native] = fit_body(views, pose, INNER, iterations=4, damping=1e-2, max_step=max_step)
    a, b = fits[True], fits[False]
    np.testing.assert_allclose(a.pose.homogeneous, b.pose.homogeneous, atol=1e-9)
    np.testing.assert_allclose(a.hessian, b.hessian, rtol=1e-8, atol=1e-10 * np.abs(b.hessian).max())
    assert a.cost == pytest.approx(b.cost, rel=1e-9) and a.evidence == pytest.approx(b.evidence, rel=1e-9)
    assert np.linalg.norm(a.pose.translation - pose.translation) > 1e-4  # it moved


@pytest.mark.parametrize("native", [True, False], ids=["native", "numpy"])
def test_body_images_match_body_image_one_by_one(native, monkeypatch):
    """The vectorized boxes (NumPy, or the C kernel) equal body_image's, also for bodies
    straddling the camera plane or out of view, and under lens distortion (which takes
    the per-body path)."""
    from pathlib import Path

    if native:
        require_kernels()
    monkeypatch.setattr(mstep, "NATIVE", native)

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


def test_vectorized_and_scalar_c_loops_agree_with_numpy_far_from_the_outline(monkeypatch):
    """The C kernel vectorizes its loop over contiguous arrays (with its own exp, clamped
    at e^-40) and keeps a scalar libm loop for strided ones; both must give NumPy's sums,
    also on pixels far outside the body (h << -40) and with weights."""
    require_kernels()
    rng = np.random.default_rng(11)
    truth = _pose(rng)
    pose = _moved(truth, np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 0.1, 3)])
    cam = Camera.default()
    img = body_image(cam, pose, INNER, 0.5, slack_px=60.0)  # a wide margin of far pixels
    y = render_mask(cam, [(truth, INNER)])[img.slices].ravel().astype(float)
    a2, _ = closest_approach(img, pose.rotation, pose.translation, INNER, False)
    assert ((1.0 - a2) / (2.0 * img.delta)).min() < -200.0
    o, w = rng.uniform(0, 0.5, y.shape), rng.uniform(0.5, 1, y.shape)

    def strided(a):
        big = np.zeros((2 * len(a),) + a.shape[1:])
        big[::2] = a
        return big[::2]

    img_s = mstep.BodyImage(img.camera, img.box, img.stride, strided(img.dirs), img.delta)
    assert not img_s.dirs.flags.c_contiguous
    out = {}
    for label, view, native in (
        ("vector", BodyView(img, y, o, w), True),
        ("scalar", BodyView(img_s, strided(y), strided(o), strided(w)), True),
        ("numpy", BodyView(img, y, o, w), False),
    ):
        monkeypatch.setattr(mstep, "NATIVE", native)
        out[label] = mstep.body_cost([view], pose, INNER, True)
    for label in ("vector", "scalar"):
        for a, b in zip(out[label], out["numpy"]):
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12 * np.abs(b).max())


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
