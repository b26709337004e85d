"""The thesis's occlusion E-step (reference): soft assignment of foreground pixels with occlusion."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from ecm._util import random_body_in_view, random_camera

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.density import projected_density
from kms2pin.ecm.raycast import render_mask
from kms2pin.errors import InputDataError
from kms2pin.reference.occlusion import e_step, runs, transmittance


def _at(pose_xyz, inner, k=1.3, R=None):
    pose = pin.SE3(np.eye(3) if R is None else R, np.asarray(pose_xyz, dtype=float))
    inner = np.asarray(inner, dtype=float)
    return pose, inner, inner * k


def _overlapping_pair():
    far = _at([0.3, 0.0, 8.0], [1.2, 0.8, 0.8])
    near = _at([-0.2, 0.0, 5.0], [0.5, 0.4, 0.4])
    return [far, near]  # the nearer body is listed second on purpose


@pytest.mark.parametrize("occlusion", ["middle", "entry"])
def test_the_nearer_of_two_overlapping_bodies_gets_the_overlap_pixels(occlusion):
    cam = Camera.default()
    bodies = _overlapping_pair()
    mask = render_mask(cam, [(p, i) for p, i, _ in bodies])
    res = e_step(mask, cam, bodies, occlusion=occlusion)
    f_far = projected_density(cam, *bodies[0])
    f_near = projected_density(cam, *bodies[1])
    overlap = mask & (f_far == 1.0) & (f_near == 1.0)
    assert overlap.sum() > 100
    far_img, near_img = res.weight_image(0), res.weight_image(1)
    np.testing.assert_allclose(near_img[overlap], 1.0 / 1.05)
    assert not far_img[overlap].any()
    far_only = mask & (f_far == 1.0) & (f_near == 0.0)
    assert far_only.sum() > 100
    np.testing.assert_allclose(far_img[far_only], 1.0 / 1.05)


def test_weights_of_bodies_and_outlier_sum_to_one_on_every_foreground_pixel_and_vanish_elsewhere():
    rng = np.random.default_rng(21)
    cam = random_camera(rng, kind=1)
    bodies = []
    for _ in range(7):
        pose, inner = random_body_in_view(rng, cam, depth=(4.0, 10.0))
        bodies.append((pose, inner, inner * rng.uniform(1.1, 1.6, 3)))
    mask = render_mask(cam, [(p, i) for p, i, _ in bodies]) | (rng.random(cam.shape) < 0.05)
    res = e_step(mask, cam, bodies, outlier=0.05)
    total = res.outlier.copy()
    for i in range(len(bodies)):
        p = res.pixels[i].astype(int)
        assert np.all(mask[p[:, 1], p[:, 0]]) and np.all(res.weights[i] > 1e-3)
        np.add.at(total, (p[:, 1], p[:, 0]), res.weights[i])
    np.testing.assert_allclose(total[mask], 1.0, atol=1e-12)
    assert not total[~mask].any()
    contested = sum((res.weight_image(i) > 0).astype(int) for i in range(len(bodies))) >= 2
    assert contested.any()


def test_a_foreground_pixel_far_from_every_body_goes_to_the_outlier_class():
    cam = Camera.default()
    bodies = _overlapping_pair()
    mask = render_mask(cam, [(p, i) for p, i, _ in bodies])
    mask[5, 5] = True
    res = e_step(mask, cam, bodies)
    assert res.outlier[5, 5] == 1.0
    assert not any(np.any((p[:, 0] == 5) & (p[:, 1] == 5)) for p in res.pixels)
    assert res.outlier[120, 140] == pytest.approx(0.05 / 1.05)


def test_a_single_body_gets_its_density_over_density_plus_outlier_at_each_pixel():
    rng = np.random.default_rng(3)
    cam = random_camera(rng, kind=2)
    pose, inner = random_body_in_view(rng, cam)
    outer = inner * 1.5
    mask = np.ones(cam.shape, dtype=bool)
    res = e_step(mask, cam, [(pose, inner, outer)], outlier=0.1)
    f = projected_density(cam, pose, inner, outer)
    expected = f / (f + 0.1)
    p = res.pixels[0].astype(int)
    np.testing.assert_allclose(res.weights[0], expected[p[:, 1], p[:, 0]], atol=1e-12)
    kept = np.zeros(cam.shape, dtype=bool)
    kept[p[:, 1], p[:, 0]] = True
    np.testing.assert_array_equal(kept, expected > 1e-3)


def test_transmittance_is_the_product_of_one_minus_density_of_the_bodies_in_front():
    group = np.array([0, 0, 0, 4, 7, 7])
    factor = np.array([0.5, 0.0, 0.25, 0.3, 0.8, 0.9])
    run, first = runs(group)
    np.testing.assert_allclose(transmittance(run, first, factor), [1.0, 0.5, 0.0, 1.0, 1.0, 0.8])


def test_an_empty_mask_assigns_nothing():
    res = e_step(np.zeros((240, 320), dtype=bool), Camera.default(), _overlapping_pair())
    assert all(len(p) == 0 for p in res.pixels) and not res.outlier.any()


def test_a_mask_of_the_wrong_size_is_an_input_data_error_naming_the_source():
    with pytest.raises(InputDataError, match=r"walk\.mp4 frame 12: mask is 10x20 but camera 'default' is 320x240"):
        e_step(np.zeros((20, 10), dtype=bool), Camera.default(), [], source="walk.mp4 frame 12")
    with pytest.raises(InputDataError, match="boolean"):
        e_step(np.full((240, 320), 0.5), Camera.default(), [])


def test_with_no_body_in_view_every_foreground_pixel_is_an_outlier():
    mask = np.zeros((240, 320), dtype=bool)
    mask[100:120, 50:90] = True
    behind = _at([0.0, 0.0, -5.0], [1.0, 1.0, 1.0])
    res = e_step(mask, Camera.default(), [behind])
    assert len(res.pixels[0]) == 0
    np.testing.assert_array_equal(res.outlier, mask.astype(float))
