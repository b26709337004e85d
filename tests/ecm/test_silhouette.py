"""The silhouette fit: one IoU for the tracker, the initialization and re-acquisition."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from kms2pin import native
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.initialization import coarse_search, scaled_camera
from kms2pin.ecm.mstep import pose_arrays
from kms2pin.ecm.raycast import render_mask
from kms2pin.ecm.silhouette import (
    IncrementalFit,
    _union_args,
    body_coverage,
    group_counts,
    model_silhouette,
    silhouette_counts,
    silhouette_iou,
)
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker

from ._tracking import _cams, _robot


def test_the_model_silhouette_is_the_ray_cast_one():
    """Pixels whose centre ray meets an inner ellipsoid: the same pixels as exact ray
    casting (an independent implementation) at random poses, two cameras."""
    robot = _robot("fullbody")
    inner = np.array([robot.inner(b) for b in robot.bodies])
    rng = np.random.default_rng(0)
    for _ in range(5):
        poses = robot.body_poses(robot.random_configuration(rng, 40))
        for cam in _cams(robot):
            expected = render_mask(cam, [(P, L) for P, L in zip(poses, inner)])
            assert expected.sum() > 500
            np.testing.assert_array_equal(model_silhouette(cam, poses, inner), expected)


def test_an_empty_union_fits_and_a_miss_does_not():
    robot = _robot("lowerbody")
    inner = np.array([robot.inner(b) for b in robot.bodies])
    behind = Camera.look_at(position=robot.q_rest[:3] + [0, 0, 8], target=robot.q_rest[:3] + [0, 0, 16])
    poses = robot.body_poses(robot.q_rest)
    empty = np.zeros(behind.shape, dtype=bool)
    assert silhouette_iou(poses, inner, [behind], [empty]) == 1.0  # nothing seen, nothing there
    full = np.ones(behind.shape, dtype=bool)
    assert silhouette_iou(poses, inner, [behind], [full]) == 0.0


def test_the_initialization_scores_candidates_with_the_trackers_fit():
    """The coarse search's score of each candidate is the tracker's fit of it (spec sizes)
    on the same scaled cameras and masks."""
    robot = _robot("fullbody")
    cams = [scaled_camera(c, 2) for c in _cams(robot)]
    masks = render(robot, robot.q_rest, cams)
    tracker = Tracker(robot, cams, calibrate_sizes=False)
    cands = coarse_search(robot, robot.q_rest, cams, masks, yaw_steps=4, pitches_deg=(0.0,), render_scale=1)
    for score, _, _, q in cands:
        assert score == tracker.fit(q, masks)
    assert cands[0][0] > 0.97 > cands[-1][0]


def _lower_body_at_rest():
    """The default camera and the lower body's poses and inner semi-axes at rest."""
    robot = _robot("lowerbody")
    return Camera.default(), robot.body_poses(robot.q_rest), np.array([robot.inner(b) for b in robot.bodies])


def test_each_body_s_coverage_counts_its_own_silhouette_and_the_mask_under_it():
    cam, poses, inner = _lower_body_at_rest()
    rng = np.random.default_rng(1)
    mask = rng.random(cam.shape) < 0.5
    counts = body_coverage(cam, poses, inner, mask)
    for i in range(len(poses)):  # each body alone, by exact ray casting (kms2pin.ecm.raycast)
        own = render_mask(cam, [(poses[i], inner[i])])
        n, on = int(own.sum()), int((own & mask).sum())
        assert abs(counts[i, 0] - n) <= max(2, 0.01 * n) and abs(counts[i, 1] - on) <= max(2, 0.01 * n)
    assert counts[:, 0].min() > 50


def test_silhouette_counts_in_the_boxes_equal_those_over_the_whole_image():
    cam, poses, inner = _lower_body_at_rest()
    rng = np.random.default_rng(2)
    on = rng.random(cam.shape) < 0.5
    off = ~on & (rng.random(cam.shape) < 0.5)
    for idx in ([0], [1, 2], list(range(len(poses)))):
        sil = model_silhouette(cam, [poses[i] for i in idx], inner[idx])
        expected = (int((sil & on).sum()), int((sil & off).sum()))
        assert silhouette_counts(cam, [poses[i] for i in idx], inner[idx], on, off) == expected
        assert expected[0] > 20
    away = pin.SE3(np.eye(3), np.array([0.0, 0.0, -100.0]))  # out of view: no pixel
    assert silhouette_counts(cam, [away], inner[:1], on, off) == (0, 0)


def test_group_counts_are_each_group_s_ray_cast_counts():
    """Groups of the same bodies at random poses: each group's counts are those of its
    silhouette by exact ray casting (an independent implementation), over the image."""
    robot = _robot("fullbody")
    inner = np.array([robot.inner(b) for b in robot.bodies])
    idx = [1, 2, 3]
    rng = np.random.default_rng(3)
    groups = [[robot.body_poses(robot.random_configuration(rng, 40))[i] for i in idx] for _ in range(4)]
    Rs, ts = (np.array(x) for x in zip(*(pose_arrays(g) for g in groups)))
    for cam in _cams(robot):
        on = rng.random(cam.shape) < 0.5
        off = ~on & (rng.random(cam.shape) < 0.5)
        counts = group_counts(cam, Rs, ts, inner[idx], on, off)
        for g, c in zip(groups, counts.tolist()):
            sil = render_mask(cam, [(P, L) for P, L in zip(g, inner[idx])])
            assert c == [int((sil & on).sum()), int((sil & off).sum())]
        assert counts.min() > 0


def test_group_counts_with_a_distorted_camera_count_each_group_s_whole_silhouette():
    """A distorted camera takes the per-body path: each group's counts are still those of
    its silhouette (model_silhouette, which is the ray-cast one) over the whole image."""
    robot = _robot("fullbody")
    inner = np.array([robot.inner(b) for b in robot.bodies])
    cam = Camera(Camera.default().K, pin.SE3.Identity(), 320, 240, dist=np.array([-0.12, 0.03, 0.001, -0.0015, 0.0]))
    idx = [1, 2, 3]
    rng = np.random.default_rng(4)
    groups = [[robot.body_poses(robot.random_configuration(rng, 40))[i] for i in idx] for _ in range(3)]
    Rs, ts = (np.array(x) for x in zip(*(pose_arrays(g) for g in groups)))
    on = rng.random(cam.shape) < 0.5
    off = ~on & (rng.random(cam.shape) < 0.5)
    counts = group_counts(cam, Rs, ts, inner[idx], on, off)
    for g, c in zip(groups, counts.tolist()):
        sil = model_silhouette(cam, g, inner[idx])
        assert c == [int((sil & on).sum()), int((sil & off).sum())]
    assert counts.min() > 0


def _ray_cast_iou(cams, poses, inner, masks) -> float:
    """The fit by exact ray casting (kms2pin.ecm.raycast, an independent implementation)."""
    sils = [render_mask(c, [(P, L) for P, L in zip(poses, inner)]) for c in cams]
    inter = sum(int((s & m).sum()) for s, m in zip(sils, masks))
    union = sum(int((s | m).sum()) for s, m in zip(sils, masks))
    return inter / union if union else 1.0


def _part_trials(robot, rng, base, n):
    """Trials made from ``base``: one joint (and the joints below it) as in another random
    pose, a limb's part taken from elsewhere; and the root moved (every body)."""
    trials = []
    for _ in range(n):
        other = robot.random_configuration(rng, 40)
        j = robot.joints[rng.integers(len(robot.joints))]
        jid = robot.model.getJointId(j.name)
        t = base.copy()
        for k in robot.model.subtrees[jid]:
            sl = slice(robot.model.idx_qs[k], robot.model.idx_qs[k] + robot.model.nqs[k])
            t[sl] = other[sl]
        trials.append(t)
    return trials


@pytest.mark.parametrize("distorted", [False, True])
def test_the_incremental_fit_is_the_fit_to_the_pixel(distorted, monkeypatch):
    """Trials that move one joint and those below it (and the root: every body), scored from
    a base pose that changes as trials are kept: the same fit as silhouette_iou, and the
    ray-cast one (to the pixel where the two silhouettes agree), on two cameras; a
    distorted camera (the per-body path) too."""
    robot = _robot("fullbody")
    inner = np.array([robot.inner(b) for b in robot.bodies])
    cams = _cams(robot)
    if distorted:
        cams[0] = Camera(cams[0].K, cams[0].world_T_camera, cams[0].width, cams[0].height,
                         dist=np.array([-0.12, 0.03, 0.001, -0.0015, 0.0]))
    rng = np.random.default_rng(7)
    base = robot.random_configuration(rng, 40)
    masks = render(robot, robot.random_configuration(rng, 40), cams)
    swaps = []
    swap = native.kernels.silhouette_swap
    monkeypatch.setattr(native.kernels, "silhouette_swap", lambda *a: swaps.append(1) or swap(*a))
    fit = IncrementalFit(robot, cams, masks, inner)
    with pytest.raises(RuntimeError, match="rebase"):
        fit(base)
    assert fit.rebase(base) == silhouette_iou(robot.body_poses(base), inner, cams, masks)
    fits = set()
    for k, trial in enumerate(_part_trials(robot, rng, base, 60)):
        poses = robot.body_poses(trial)
        expected = silhouette_iou(poses, inner, cams, masks)
        got = fit(trial)
        assert got == expected
        fits.add(got)
        if k % 5 == 0:
            assert fit.rebase(trial) == expected
        if k % 20 == 0 and not distorted:
            assert got == _ray_cast_iou(cams, poses, inner, masks)
    assert len(fits) > 30  # the trials moved the silhouettes
    assert (len(swaps) == 0) if distorted else (len(swaps) >= 100)  # counted from the moved bodies
    anywhere = robot.random_configuration(rng, 40)  # every body moved
    assert fit(anywhere) == silhouette_iou(robot.body_poses(anywhere), inner, cams, masks)
    fit.rebase(base)
    assert fit(base.copy()) == fit.rebase(base)  # nothing moved
    # the root at the first camera, its bodies across the camera's plane: the per-body path
    close = base.copy()
    close[:3] = cams[0].centre + 0.3 * np.asarray(cams[0].world_R_camera)[:, 2]
    Rs, ts = robot.body_pose_arrays(close)
    assert _union_args(cams[0], Rs, ts, inner) is None
    assert fit(close) == silhouette_iou(robot.body_poses(close), inner, cams, masks)
