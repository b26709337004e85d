"""Exact ray casting of ellipsoids and capsules."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy import ndimage

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.raycast import Capsule, intersect_capsule, intersect_ellipsoid, render_labels, render_mask

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


# ----------------------------------------------------------------------------- capsules


def _segment_distance(points: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Distance of each point (N, 3) to the segment p0-p1: to the nearest point, its
    parameter clamped to [0, 1]."""
    axis = p1 - p0
    s = np.clip((points - p0) @ axis / max(axis @ axis, 1e-300), 0.0, 1.0)
    return np.linalg.norm(points - (p0 + s[:, None] * axis), axis=1)


def _capsule_hits_by_root_finding(origin, direction, p0, p1, r, reach=50.0):
    """(t_near, t_far) of the unit ray origin + t direction and the capsule of radius r
    about p0-p1, by minimising and bracketing f(t) = distance to the segment - r (convex
    in t); None if the line misses.  Independent of intersect_capsule's algebra."""
    from scipy.optimize import brentq, minimize_scalar

    def f(t):
        return _segment_distance((origin + t * direction)[None], p0, p1)[0] - r

    best = minimize_scalar(f, bounds=(-reach, reach), method="bounded", options={"xatol": 1e-12})
    if best.fun > 0:
        return None
    return (brentq(f, -reach, best.x, xtol=1e-14), brentq(f, best.x, reach, xtol=1e-14))


def test_capsule_ray_hits_equal_an_independent_root_finding_of_the_distance_to_the_segment():
    rng = np.random.default_rng(11)
    hits = misses = 0
    for k in range(60):
        p0, r = rng.uniform(-1, 1, 3), rng.uniform(0.1, 0.6)
        p1 = p0 if k % 10 == 0 else p0 + rng.normal(size=3) * rng.uniform(0.2, 1.5)  # every tenth a sphere
        origin = rng.uniform(-6, 6, 3)
        target = (p0 + p1) / 2 + rng.normal(size=(8, 3)) * 0.6
        dirs = target - origin
        if k % 7 == 0 and np.any(p1 != p0):  # rays along the axis, through both caps
            dirs[0] = p1 - p0
            origin = p0 - 3.0 * (p1 - p0)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        near, far = intersect_capsule(origin, dirs, Capsule(p0, p1, r))
        for d, tn, tf in zip(dirs, near, far):
            expected = _capsule_hits_by_root_finding(origin, d, p0, p1, r)
            if expected is None:
                misses += 1
                assert np.isnan(tn) and np.isnan(tf)
            else:
                hits += 1
                np.testing.assert_allclose([tn, tf], expected, atol=1e-9)
    assert hits > 100 and misses > 100


def test_the_capsule_of_an_ellipsoid_spans_its_longest_axis_end_to_end_with_the_mean_radius():
    rng = np.random.default_rng(12)
    R = random_rotation(rng)
    centre = np.array([0.3, -0.2, 4.0])
    axes = np.array([0.2, 0.7, 0.3])  # longest: body y, a = 0.7; radius (0.2 + 0.3) / 2
    capsule = Capsule.of_ellipsoid(pin.SE3(R, centre), axes)
    along = R[:, 1]
    near, far = intersect_capsule(centre - 5 * along, along[None], capsule)
    assert far[0] - near[0] == pytest.approx(2 * 0.7, abs=1e-12)
    for across in (R[:, 0], R[:, 2], (R[:, 0] + R[:, 2]) / np.sqrt(2)):
        near, far = intersect_capsule(centre - 5 * across, across[None], capsule)
        assert far[0] - near[0] == pytest.approx(2 * 0.25, abs=1e-12)
    assert capsule.radius == pytest.approx(0.25)
    # a sphere is its own capsule: the same hits as the ellipsoid's
    sphere = (pin.SE3(R, centre), np.full(3, 0.4))
    dirs = rng.normal(size=(50, 3)) * 0.1 + [0.0, 0.0, 1.0]
    np.testing.assert_allclose(
        np.array(intersect_capsule(np.zeros(3), dirs, Capsule.of_ellipsoid(*sphere))),
        np.array(intersect_ellipsoid(np.zeros(3), dirs, *sphere)), atol=1e-12, equal_nan=True)


def test_a_capsule_render_holds_every_inside_point_and_only_pixels_whose_rays_meet_it():
    rng = np.random.default_rng(13)
    cam = random_camera(rng, kind=1, dist=DIST)
    T = cam.world_T_camera
    capsule = Capsule.of_ellipsoid(pin.SE3(random_rotation(rng), T.translation + T.rotation @ [0.3, 0.2, 5.0]),
                                   [0.3, 1.2, 0.4])
    mask = render_mask(cam, [capsule])
    # points inside: within r of a point of the segment
    s = rng.uniform(0, 1, (20000, 1))
    v = rng.normal(size=(20000, 3))
    v *= capsule.radius * rng.uniform(0, 1, (20000, 1)) / np.linalg.norm(v, axis=1, keepdims=True)
    inside = capsule.start + s * (capsule.end - capsule.start) + v
    px = np.rint(cam.project(inside)).astype(int)
    ok = (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
    assert ok.sum() > 10000 and ndimage.binary_dilation(mask)[px[ok, 1], px[ok, 0]].all()
    # every masked pixel's ray comes within r of the segment (sampled along the ray)
    v_, u_ = np.nonzero(mask)
    dirs, origin = cam.rays(np.column_stack([u_, v_]).astype(float))
    t = np.linspace(0.0, 12.0, 2401)
    closest = np.array([_segment_distance(origin + t[:, None] * d, capsule.start, capsule.end).min() for d in dirs[::7]])
    assert len(closest) > 100 and (closest <= capsule.radius + 0.01).all()


@pytest.mark.parametrize("dist", [None, DIST])
def test_a_render_cast_only_in_each_body_s_image_box_equals_casting_every_pixel_at_every_body(dist):
    rng = np.random.default_rng(5)
    cam = random_camera(rng, kind=1, dist=dist)
    T = cam.world_T_camera
    bodies = []
    for k in range(12):  # in view, across the image border, one behind the camera
        depth = -3.0 if k == 0 else rng.uniform(2.0, 8.0)
        at = T.translation + T.rotation @ np.array([*rng.uniform(-0.6, 0.6, 2) * depth, depth])
        pose, axes = pin.SE3(random_rotation(rng), at), rng.uniform(0.05, 0.8, 3)
        bodies.append(Capsule.of_ellipsoid(pose, axes) if k % 2 else (pose, axes))
    labels, depth = render_labels(cam, bodies)
    v, u = np.mgrid[0 : cam.height, 0 : cam.width]
    dirs, origin = cam.rays(np.column_stack([u.ravel(), v.ravel()]).astype(float))
    dz = dirs @ T.rotation[:, 2]
    hits = []
    for body in bodies:  # every ray against every body, the nearest hit in front
        near, far = (intersect_capsule(origin, dirs, body) if isinstance(body, Capsule)
                     else intersect_ellipsoid(origin, dirs, *body))
        with np.errstate(invalid="ignore"):
            hits.append(np.where(far > 0, np.maximum(near, 0.0) * dz, np.inf))
    hits = np.array(hits)
    expected = np.where(np.isfinite(hits.min(axis=0)), hits.argmin(axis=0), -1)
    assert (expected >= 0).sum() > 2000 and len(set(expected.tolist())) > 6
    np.testing.assert_array_equal(labels.ravel(), expected)
    np.testing.assert_allclose(depth.ravel(), hits.min(axis=0))
