"""Exact ray casting of ellipsoids."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy import ndimage

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.raycast import render_labels, render_mask

from ._util import DIST, random_camera, random_rotation


def _sphere(centre, r):
    return pin.SE3(np.eye(3), np.asarray(centre, dtype=float)), np.array([r, r, r])


def test_the_depth_of_a_sphere_in_front_of_the_camera_is_the_analytic_distance():
    cam = Camera.look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], width=321, height=241)  # pixel (160, 120) on axis
    centre, r = np.array([0.0, 0.0, 5.0]), 0.8
    labels, depth = render_labels(cam, [_sphere(centre, r)])
    assert abs(depth[120, 160] - (5.0 - 0.8)) < 1e-12
    # every hit: distance along the unit ray t = u.c - sqrt((u.c)^2 - |c|^2 + r^2), depth = t * u_z
    v, u = np.nonzero(labels == 0)
    dirs, _ = cam.rays(np.column_stack([u, v]).astype(float))
    uc = dirs @ centre
    t = uc - np.sqrt(uc**2 - centre @ centre + r * r)
    np.testing.assert_allclose(depth[v, u], t * dirs[:, 2], rtol=1e-12)
    assert len(v) > 100 and np.all(np.isinf(depth[labels < 0]))


def test_a_nearer_ellipsoid_occludes_a_farther_one():
    cam = Camera.default()
    far = (
        pin.SE3(random_rotation(np.random.default_rng(0)), np.array([0.0, 0.0, 9.0])),
        np.array([2.0, 1.5, 1.0]),
    )
    near = (pin.SE3(np.eye(3), np.array([0.0, 0.0, 4.0])), np.array([0.4, 0.3, 0.2]))
    labels, depth = render_labels(cam, [far, near])
    assert labels[120, 160] == 1 and labels[119, 159] == 1
    assert abs(depth[120, 160] - 3.8) < 0.01
    assert (labels == 0).sum() > (labels == 1).sum() > 0  # the far body's rim stays visible
    labels_swapped, _ = render_labels(cam, [near, far])
    np.testing.assert_array_equal(labels_swapped, np.where(labels >= 0, 1 - labels, -1))


def test_the_camera_inside_a_body_sees_it_everywhere_at_depth_zero():
    labels, depth = render_labels(Camera.default(), [_sphere([0.0, 0.0, 0.2], 1.0)])
    assert np.all(labels == 0) and np.all(depth == 0.0)


def test_a_distorted_render_contains_the_projection_of_every_surface_point():
    rng = np.random.default_rng(4)
    cam = random_camera(rng, kind=1, dist=DIST)
    T = cam.world_T_camera
    pose = pin.SE3(random_rotation(rng), T.translation + T.rotation @ [0.8, -0.5, 5.0])
    axes = np.array([1.0, 0.6, 0.4])
    mask = render_mask(cam, [(pose, axes)])
    n = rng.normal(size=(20000, 3))
    surface = (n / np.linalg.norm(n, axis=1, keepdims=True)) * axes @ pose.rotation.T + pose.translation
    px = np.rint(cam.project(surface)).astype(int)
    ok = (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
    grown = ndimage.binary_dilation(mask)
    assert ok.sum() > 10000 and grown[px[ok, 1], px[ok, 0]].all()
    undistorted = Camera(cam.K, T, cam.width, cam.height)
    assert (render_mask(undistorted, [(pose, axes)]) != mask).sum() > 20  # distortion did matter
