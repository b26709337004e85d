"""ECM tracker: truth is a fixed point, recovery from a perturbed pose, a short
sequence without drift, flags, one-off fits, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_kernels

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker, Trajectory, TrajectoryCsvWriter
from kms2pin.errors import CameraError, InputDataError

from ._tracking import (
    SPECS,
    _cams,
    _perturbed,
    _robot,
    centre_error,
    joint_errors,
)


@pytest.mark.parametrize("name", SPECS)
def test_truth_is_a_fixed_point(name):
    robot = _robot(name)
    rng = np.random.default_rng(10)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    tr = Tracker(robot, cams, q0=qt)
    r = tr.step(render(robot, qt, cams))
    assert centre_error(robot, r.q, qt) < 0.5
    # puma600's base is a body of revolution about its own joint axis: with a free root,
    # turning the root about it and link1 back is invisible (a gauge); skip that pair.
    errs = joint_errors(robot, r.q, qt)
    if name == "puma600":
        errs = errs[1:]
    # Joints whose bodies the silhouettes hardly fix (fullbody's right elbow: the forearm
    # lies over the trunk in both views, ~13 deg; jplhand's small finger tips, ~3 deg)
    # drift; all but the two worst joints stay < 2 deg.
    assert np.sort(errs)[-3 if len(errs) > 3 else 0] < 2.0
    assert errs.max() < 15.0
    assert r.fit > 0.97


@pytest.mark.parametrize("name", SPECS)
def test_single_frame_recovers_the_pose(name):
    robot = _robot(name)
    rng = np.random.default_rng(11)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    # ECM run to its fixed point: the default stop (0.2 deg, 0.25 px) is set for
    # tracking, where a frame starts near its answer.  From this 8-degree start the
    # full body's right forearm, which lies over the trunk in both views, crosses a
    # plateau (0.16 deg and 0.23 px in one iteration, 16.8 deg off) before it moves on
    # to 1.7 deg; the default stop ends the frame there.
    tr = Tracker(robot, cams, q0=q0, max_iterations=40, tol_deg=0.02, tol_px=0.02, calibrate_sizes=False)
    r = tr.step(render(robot, qt, cams))  # q0 is not the pose shown
    assert r.converged
    before = centre_error(robot, q0, qt)
    after = centre_error(robot, r.q, qt)
    assert after < 0.5 and after < 0.2 * before
    errs = joint_errors(robot, r.q, qt)
    if name == "puma600":
        errs = errs[1:]
    assert np.median(errs) < 2.0 and errs.max() < 6.0
    assert r.fit > 0.97


@pytest.mark.slow
def test_one_camera_single_frame():
    robot = _robot("lowerbody")
    rng = np.random.default_rng(12)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot, 1)
    q0 = _perturbed(robot, qt, rng)
    r = Tracker(robot, cams, q0=q0, max_iterations=10, calibrate_sizes=False).step(render(robot, qt, cams))
    # One camera fits the silhouette but leaves depth (and the tilts that keep an
    # outline) weakly fixed: the 3-D error need not fall (here 1.2 % -> ~2 %).
    assert r.fit > 0.95
    assert centre_error(robot, r.q, qt) < 3.0


@pytest.mark.slow
def test_walk_sequence_stays_accurate(tmp_path):
    robot = _robot("lowerbody")
    cams = _cams(robot)
    motion = make_motion(robot, "walk", 30)
    tr = Tracker(robot, cams)
    errs = []
    with TrajectoryCsvWriter(robot, tmp_path / "t.csv") as w:
        for f, qt in enumerate(motion):
            r = tr.step(render(robot, qt, cams), source=f"frame {f}")
            w.write(f, r)
            errs.append(centre_error(robot, r.q, qt))
    errs = np.array(errs)
    assert errs.mean() < 1.0 and errs.max() < 2.0
    assert errs[-10:].mean() < 1.0  # no drift
    back = Trajectory.from_csv(robot, tmp_path / "t.csv")
    assert len(back) == 30


def test_empty_mask_keeps_the_pose_and_is_flagged():
    robot = _robot("lowerbody")
    cams = _cams(robot)
    tr = Tracker(robot, cams)
    r = tr.step([np.zeros(c.shape, bool) for c in cams])
    assert "empty mask" in r.flags
    np.testing.assert_array_equal(r.q, robot.q_rest)


def test_wrong_mask_size_names_the_frame():
    robot = _robot("lowerbody")
    cams = _cams(robot)
    tr = Tracker(robot, cams)
    with pytest.raises(InputDataError, match="frame 7.*camera 1.*100x50"):
        tr.step([np.zeros((240, 320), bool), np.zeros((50, 100), bool)], source="frame 7")
    with pytest.raises(InputDataError, match="1 masks for 2 cameras"):
        tr.step([np.zeros((240, 320), bool)])


def test_camera_that_does_not_see_the_model():
    robot = _robot("lowerbody")
    away = Camera.look_at(position=[0, 0, 20], target=[0, 0, 40], name="away")
    with pytest.raises(CameraError, match="camera 1 'away' does not see the model"):
        Tracker(robot, [Camera.default(), away])


@pytest.mark.slow
def test_noisy_mismatched_walk_does_not_diverge():
    """Regression: 5 % noise + 10 % body-size mismatch, lowerbody walk, 2 cameras.

    With the side camera level with the front one (``[8, 0, 8]``: two level
    orthogonal views share a mirror ambiguity, the trunk turned by +a or -a with the
    legs swapped looks alike in both) the tracker took the mirrored branch as the
    walker started turning and was 10-15 % of the height off from frame 6 on.
    The fix is the rig: a side camera raised 3 units (~20 deg down), as in
    ``benchmarks/ecm.py``, breaks the symmetry (mean error ~0.3 %).
    """
    from kms2pin.ecm.synth import synthesize

    robot = _robot("lowerbody")
    rng = np.random.default_rng(0)
    motion = make_motion(robot, "walk", 40, rng)
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=robot.q_rest[:3])]
    data = [m for _, m in synthesize(robot, motion, cams, noise=0.05, size_mismatch=0.1, rng=rng)]
    tr = Tracker(robot, cams)
    errs = np.array([centre_error(robot, tr.step(m).q, qt) for m, qt in zip(data, motion)])
    assert errs.mean() < 1.0 and errs.max() < 2.0
    assert errs[-10:].mean() < 1.5 * errs[:10].mean() + 0.2


@pytest.mark.parametrize("outlier, coarse", [(0.0, None), (0.01, None), (0.0, 1.4)])
def test_native_and_numpy_trackers_agree(outlier, coarse):
    """The C kernels (E-step, M-step, static update) and their NumPy twins give the same
    track, on the masks and on their 2x2 binned fractions (coarse_delta_px)."""
    from kms2pin import native

    require_kernels()
    robot = _robot("lowerbody")
    rng = np.random.default_rng(13)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    out = {}
    for backend in native.BACKENDS:
        with native.use(backend):
            tr = Tracker(robot, cams, q0=q0, outlier=outlier, calibrate_sizes=False, coarse_delta_px=coarse)
            out[backend] = tr.step(render(robot, qt, cams))
    np.testing.assert_allclose(out["c"].q, out["numpy"].q, atol=1e-9)
    assert out["c"].iterations == out["numpy"].iterations
    assert centre_error(robot, out["c"].q, qt) < 0.5


def test_max_pixels_subsamples_the_m_step_and_still_recovers(monkeypatch):
    from kms2pin.ecm import loop as loop_mod

    robot = _robot("lowerbody")
    rng = np.random.default_rng(14)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    sizes = []
    real = loop_mod.fit_bodies

    def spy(views, *a, **k):
        sizes.extend((len(v.y), v.image.stride, len(v.image.dirs)) for vs in views for v in vs)
        return real(views, *a, **k)

    monkeypatch.setattr(loop_mod, "fit_bodies", spy)
    r = Tracker(robot, cams, q0=q0, max_pixels=400, max_iterations=10, calibrate_sizes=False).step(render(robot, qt, cams))
    assert max(n for n, _, _ in sizes) <= 400 * 1.3  # strided boxes: about max_pixels each
    assert any(stride > 1 for _, stride, _ in sizes)
    assert all(n == m for n, _, m in sizes)  # mask, others and rays subsampled alike
    assert centre_error(robot, r.q, qt) < 1.0


def test_a_frame_the_model_cannot_fit_is_flagged_poor_fit():
    robot = _robot("lowerbody")
    cams = _cams(robot)
    qt = robot.q_rest.copy()
    good = Tracker(robot, cams, q0=qt).step(render(robot, qt, cams))
    assert good.fit > 0.9 and not any(f.startswith("poor fit") for f in good.flags)
    far = qt.copy()
    far[0] += 0.6 * robot.height  # the silhouettes of a subject well to the side
    r = Tracker(robot, cams, q0=qt, max_iterations=1, min_iterations=1, calibrate_sizes=False).step(render(robot, far, cams))
    assert r.fit < 0.5
    assert any(f.startswith("poor fit") for f in r.flags)


def test_a_lost_track_keeps_its_last_pose_and_does_not_coast():
    """Masks that the model's silhouettes do not touch at all (fit 0) carry no
    information: the tracker keeps the last pose instead of following its constant-
    velocity prediction out of the view, and picks the subject up when it is back."""
    robot = _robot("lowerbody")
    cams = _cams(robot)
    motion = np.repeat(robot.q_rest[None], 4, axis=0)
    for k in range(4):
        motion[k, 0] += 0.01 * k * robot.height  # walking sideways, 1 % of the height a frame
    tr = Tracker(robot, cams, q0=motion[0], calibrate_sizes=False)
    for k in range(3):
        tr.step(render(robot, motion[k], cams))
    last = tr.q.copy()
    blob = [np.zeros(c.shape, dtype=bool) for c in cams]
    for b in blob:
        b[:6, :6] = True  # a speck in a corner, far from the model
    r = tr.step(blob)
    assert r.fit == 0.0 and "lost: kept the last pose" in r.flags
    np.testing.assert_array_equal(r.q, last)
    r = tr.step(render(robot, motion[3], cams))  # back: no velocity carried over the lost frame
    assert r.fit > 0.9
    assert centre_error(robot, r.q, motion[3]) < 0.5


def test_constant_velocity_prediction_is_capped():
    """A joint that turned 90 deg in the last frame (a poorly seen joint starting to spin)
    is predicted to move at most max_prediction_deg; slow joints keep their velocity."""
    robot = _robot("lowerbody")
    cams = _cams(robot)
    tr = Tracker(robot, cams, max_prediction_deg=10.0)  # not the default (20)
    q0 = robot.q_rest.copy()
    q1 = q0.copy()
    q1[7] += np.radians(90.0)  # first revolute joint: a fast spin
    q1[8] += np.radians(3.0)  # a normal walking speed
    q1[0] += 0.5 * robot.height  # the root jumps half a body height
    v = tr.ecm.motion.velocity(q0, q1)
    assert np.degrees(v[6]) == pytest.approx(10.0)
    assert np.degrees(v[7]) == pytest.approx(3.0)
    assert np.abs(v[:3]).max() == pytest.approx(0.1 * robot.height)  # root translation, local axes


def test_refine_fits_one_frame_from_a_given_pose_and_leaves_the_tracker_as_it_was():
    robot = _robot("lowerbody")
    rng = np.random.default_rng(23)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    masks = render(robot, qt, cams)
    tr = Tracker(robot, cams, calibrate_sizes=False)
    tr.step(render(robot, robot.q_rest, cams))
    state = (tr.q.copy(), tr.state.prev.copy(), tr.frame)
    q0 = _perturbed(robot, qt, rng)
    q, fit = tr.refine(q0, masks)
    assert fit > 0.97 and fit == pytest.approx(tr.fit(q, masks))
    assert centre_error(robot, q, qt) < 0.5 < centre_error(robot, q0, qt)
    np.testing.assert_array_equal(tr.q, state[0])
    np.testing.assert_array_equal(tr.state.prev, state[1])
    assert tr.frame == state[2] and tr.cameras == cams


def test_fit_is_the_iou_of_the_model_silhouettes_and_what_a_step_reports():
    """Tracker.fit: at the pose the masks were ray cast from (the spec's sizes) the model
    overlaps them almost exactly; with a knee bent 20° further it fits worse, by the IoU
    of that pose's own ray-cast masks with them; after a step it gives the frame's fit."""
    robot = _robot("lowerbody")
    cams = _cams(robot)
    masks = render(robot, robot.q_rest, cams)
    tr = Tracker(robot, cams, calibrate_sizes=False)
    at_truth = tr.fit(robot.q_rest, masks)
    assert at_truth > 0.97
    q = robot.q_rest.copy()
    q[robot.model.joints[robot.model.getJointId("leftShin_knee")].idx_q] += np.radians(20)
    bent = render(robot, q, cams)
    direct = sum(np.count_nonzero(a & b) for a, b in zip(bent, masks)) / sum(
        np.count_nonzero(a | b) for a, b in zip(bent, masks))
    assert tr.fit(q, masks) == pytest.approx(direct, abs=1e-12)  # the IoU of the two renders, pixel for pixel
    assert tr.fit(q, masks) < at_truth - 0.02
    res = tr.step(masks)
    assert res.fit == pytest.approx(tr.fit(res.q, masks), abs=1e-12)
    with pytest.raises(ValueError, match="nq"):
        tr.fit(robot.q_rest[:5], masks)


def test_a_nearly_full_mask_does_not_drive_the_pose():
    """All-white masks (a light switched on, a failed background model) once pulled the
    root past the camera with a fit of 1.0 and no flag: a mask more than 90 % foreground
    now keeps the pose as an empty one does; with another camera seeing the subject the
    full camera alone is left out."""
    robot = _robot("lowerbody")
    cams = _cams(robot)
    masks = render(robot, robot.q_rest, cams)
    white = [np.ones_like(m) for m in masks]
    tr = Tracker(robot, cams, calibrate_sizes=False)
    r = tr.step(white)
    assert r.flags == ("mask nearly full",) and r.fit == 0.0
    np.testing.assert_array_equal(r.q, robot.q_rest)
    one = Tracker(robot, cams, calibrate_sizes=False)
    r = one.step([masks[0], white[1]])
    assert r.flags == ("mask nearly full in camera 1",)
    assert centre_error(robot, r.q, robot.q_rest) < 0.5
    almost = masks[0].copy()
    almost[: int(0.95 * almost.shape[0])] = True  # 95 % foreground
    assert Tracker(robot, cams[:1], calibrate_sizes=False).step([almost]).flags == ("mask nearly full",)
