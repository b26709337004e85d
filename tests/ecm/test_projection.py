"""Ellipsoid silhouettes as conics, checked against exact ray casting."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.projection import (
    BBox,
    ProjectionError,
    Visibility,
    body_bbox,
    conic_values,
    ellipse_parameters,
    ellipsoid_conic,
    ellipsoid_visibility,
    inside_conic,
)
from kms2pin.ecm.raycast import render_mask

from ._util import DIST, boundary_pixels, pixel_grid, random_body_in_view, random_camera


@pytest.mark.parametrize("seed", range(60))
def test_conic_inside_test_matches_the_raycast_silhouette_except_at_boundary_pixels(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, kind=seed % 3)
    pose, axes = random_body_in_view(rng, cam, scale=rng.choice([0.3, 1.0, 2.0]))
    truth = render_mask(cam, [(pose, axes)])
    conic = ellipsoid_conic(cam, pose, axes)
    inside = inside_conic(conic, pixel_grid(cam))
    assert truth.sum() > 0
    wrong = inside != truth
    assert not np.any(wrong & ~boundary_pixels(truth)), np.argwhere(wrong & ~boundary_pixels(truth))[:5]
    assert wrong.sum() <= 0.02 * boundary_pixels(truth).sum()  # almost all boundary pixels agree too


@pytest.mark.parametrize("seed", range(8))
def test_conic_of_undistorted_pixels_matches_the_raycast_silhouette_of_a_distorted_camera(seed):
    rng = np.random.default_rng(100 + seed)
    cam = random_camera(rng, kind=1 + seed % 2, dist=DIST)
    pose, axes = random_body_in_view(rng, cam)
    truth = render_mask(cam, [(pose, axes)])
    conic = ellipsoid_conic(cam, pose, axes)
    ideal = cam.undistort_pixels(pixel_grid(cam).reshape(-1, 2)).reshape(cam.height, cam.width, 2)
    wrong = inside_conic(conic, ideal) != truth
    assert truth.sum() > 0 and not np.any(wrong & ~boundary_pixels(truth))


@pytest.mark.parametrize("with_dist", [False, True])
@pytest.mark.parametrize("seed", range(10))
def test_body_bbox_holds_the_whole_raycast_silhouette(seed, with_dist):
    rng = np.random.default_rng(200 + seed)
    cam = random_camera(rng, kind=seed % 3, dist=DIST if with_dist else None)
    pose, axes = random_body_in_view(rng, cam, scale=2.0)
    truth = render_mask(cam, [(pose, axes)])
    box = body_bbox(cam, pose, axes, margin=0)
    assert box is not None
    outside = truth.copy()
    outside[box.slices] = False
    assert not outside.any()
    inside_image = box.u0 > 0 and box.v0 > 0 and box.u1 < cam.width and box.v1 < cam.height
    if not with_dist and inside_image:  # tight: the box's border rows and columns touch the silhouette
        rows, cols = np.nonzero(truth)
        assert box.v0 >= rows.min() - 1 and box.v1 <= rows.max() + 2
        assert box.u0 >= cols.min() - 1 and box.u1 <= cols.max() + 2


def test_ellipse_parameters_recover_a_known_ellipse():
    rng = np.random.default_rng(5)
    for _ in range(20):
        centre = rng.uniform(0, 300, 2)
        a, b = sorted(rng.uniform(2, 80, 2), reverse=True)
        ang = rng.uniform(0, 180)
        t = math.radians(ang)
        R = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
        M = R @ np.diag([1 / a**2, 1 / b**2]) @ R.T
        C = np.zeros((3, 3))
        C[:2, :2] = M
        C[:2, 2] = C[2, :2] = -M @ centre
        C[2, 2] = centre @ M @ centre - 1
        for sign in (1, -1):
            e = ellipse_parameters(sign * 7.0 * C)
            np.testing.assert_allclose(e.centre, centre, atol=1e-8)
            np.testing.assert_allclose(e.semi_axes, [a, b], rtol=1e-9)
            d = abs(e.angle_deg - ang) % 180
            assert min(d, 180 - d) < 1e-6


def test_ellipse_boundary_points_lie_on_the_conic_and_its_centre_inside():
    rng = np.random.default_rng(9)
    cam = Camera.default()
    pose, axes = random_body_in_view(rng, cam)
    C = ellipsoid_conic(cam, pose, axes)
    e = ellipse_parameters(C)
    th = np.linspace(0, 2 * np.pi, 50)
    t = math.radians(e.angle_deg)
    R = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    ring = e.centre + np.column_stack([e.semi_axes[0] * np.cos(th), e.semi_axes[1] * np.sin(th)]) @ R.T
    scale = np.abs(conic_values(C, e.centre[None]))[0]
    assert np.max(np.abs(conic_values(C, ring))) < 1e-9 * scale
    assert inside_conic(C, e.centre[None])[0]


def test_the_projected_centre_is_inside_and_far_pixels_outside_the_conic():
    cam = Camera.default()
    pose = pin.SE3(np.eye(3), np.array([0.0, 0.0, 5.0]))
    C = ellipsoid_conic(cam, pose, [0.5, 0.5, 0.5])
    assert inside_conic(C, np.array([[159.5, 119.5]]))[0]
    assert not inside_conic(C, np.array([[0.0, 0.0]]))[0]
    assert np.linalg.norm(C) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "centre, expected",
    [
        ([0.0, 0.0, 0.5], Visibility.CONTAINS_CAMERA),
        ([0.0, 0.0, -5.0], Visibility.BEHIND),
        ([3.0, 0.0, 0.5], Visibility.STRADDLES),
        ([0.0, 0.0, 5.0], Visibility.FRONT),
    ],
)
def test_visibility_classifies_the_ellipsoid_against_the_camera(centre, expected):
    pose = pin.SE3(np.eye(3), np.array(centre))
    assert ellipsoid_visibility(Camera.default(), pose, [1.0, 1.0, 2.0]) is expected


@pytest.mark.parametrize("centre", [[0.0, 0.0, 0.5], [0.0, 0.0, -5.0], [3.0, 0.0, 0.5]])
def test_a_conic_is_refused_unless_the_ellipsoid_is_in_front(centre):
    pose = pin.SE3(np.eye(3), np.array(centre))
    with pytest.raises(ProjectionError, match="not an ellipse"):
        ellipsoid_conic(Camera.default(), pose, [1.0, 1.0, 2.0])


def test_bbox_is_none_behind_the_camera_and_the_full_image_when_straddling():
    cam = Camera.default()
    assert body_bbox(cam, pin.SE3(np.eye(3), np.array([0.0, 0.0, -5.0])), [1, 1, 1]) is None
    full = body_bbox(cam, pin.SE3(np.eye(3), np.array([3.0, 0.0, 0.5])), [1, 1, 2])
    assert full == BBox(0, 0, 320, 240)
    assert body_bbox(cam, pin.SE3(np.eye(3), np.array([50.0, 0.0, 5.0])), [1, 1, 1]) is None
