"""The projected generalized density and per-pixel body depth."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.density import body_depth, density_region, projected_density
from kms2pin.ecm.projection import BBox, body_bbox, ellipsoid_conic, inside_conic
from kms2pin.ecm.raycast import render_labels

from ._util import DIST, pixel_grid, random_body_in_view, random_camera


def _body(rng, cam, k=None):
    pose, inner = random_body_in_view(rng, cam)
    outer = inner * (k if k is not None else rng.uniform(1.05, 1.8, size=3))
    return pose, inner, outer


def _interior(mask: np.ndarray) -> np.ndarray:
    """Pixels whose whole 3x3 neighbourhood is in ``mask``."""
    from scipy import ndimage

    return ndimage.minimum_filter(mask.astype(np.uint8), size=3, mode="nearest").astype(bool)


def radial_linear_density(p_body: np.ndarray, inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """The 3-D density by its definition: linear along each radial line from the centre.

    On the half-line from the centre through p the inner surface is at distance
    r_in and the outer one at r_out; the density is 1 up to r_in, falls
    linearly to 0 at r_out, and is 0 beyond.
    """
    r = np.linalg.norm(p_body, axis=-1)
    u = p_body / np.maximum(r, 1e-300)[..., None]
    r_in = 1.0 / np.sqrt(np.sum((u / inner) ** 2, axis=-1))
    r_out = 1.0 / np.sqrt(np.sum((u / outer) ** 2, axis=-1))
    g = (r_out - r) / (r_out - r_in)
    return np.where(r <= r_in, 1.0, np.clip(g, 0.0, 1.0))


def brute_force_ray_max(cam, pose, inner, outer, pixels, samples=4001):
    """Max of the 3-D density over points sampled along each pixel's ray (then refined)."""
    dirs, c = cam.rays(pixels)
    R, t = pose.rotation, pose.translation
    far = np.linalg.norm(c - t) + 2 * outer.max()
    out = np.empty(len(pixels))
    for k, d in enumerate(dirs):
        s = np.linspace(0.0, far, samples)
        for _ in range(3):  # zoom in around the best sample
            g = radial_linear_density((c + s[:, None] * d - t) @ R, inner, outer)
            j = int(np.argmax(g))
            step = s[1] - s[0]
            s = np.linspace(max(s[j] - 2 * step, 0.0), s[j] + 2 * step, 401)
        out[k] = g.max()
    return out


@pytest.mark.parametrize("seed", range(20))
def test_density_is_one_inside_the_inner_conic_zero_outside_the_outer_and_between_elsewhere(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, kind=seed % 3)
    pose, inner, outer = _body(rng, cam)
    px = pixel_grid(cam)
    f = projected_density(cam, pose, inner, outer)
    in_inner = inside_conic(ellipsoid_conic(cam, pose, inner), px)
    in_outer = inside_conic(ellipsoid_conic(cam, pose, outer), px)
    sure_inner = _interior(in_inner)
    sure_out = _interior(~in_outer)
    sure_between = _interior(in_outer & ~in_inner)
    assert sure_inner.any() and sure_between.any()
    assert np.all(f[sure_inner] == 1.0)
    assert np.all(f[sure_out] == 0.0)
    assert np.all((f[sure_between] > 0.0) & (f[sure_between] < 1.0))


@pytest.mark.parametrize("seed", range(10))
def test_density_does_not_increase_along_lines_leaving_the_projected_centre(seed):
    rng = np.random.default_rng(50 + seed)
    cam = random_camera(rng, kind=seed % 3)
    pose, inner, outer = _body(rng, cam)
    centre = cam.project(pose.translation[None])[0]
    r = np.linspace(0.0, 300.0, 1500)
    for theta in np.linspace(0, 2 * np.pi, 16, endpoint=False):
        line = centre + r[:, None] * [np.cos(theta), np.sin(theta)]
        f = projected_density(cam, pose, inner, outer, line)
        assert f[0] == 1.0 and f[-1] == 0.0
        assert np.any((f > 0) & (f < 1))
        assert np.all(np.diff(f) <= 1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_density_is_the_brute_force_ray_maximum_of_the_radially_linear_3d_density_if_scaled(seed):
    rng = np.random.default_rng(80 + seed)
    cam = random_camera(rng, kind=seed % 3, dist=DIST if seed == 5 else None)
    pose, inner, outer = _body(rng, cam, k=rng.uniform(1.1, 2.0))
    box = body_bbox(cam, pose, outer)
    pixels = rng.uniform([box.u0, box.v0], [box.u1, box.v1], size=(60, 2))
    f = projected_density(cam, pose, inner, outer, pixels)
    expected = brute_force_ray_max(cam, pose, inner, outer, pixels)
    assert np.any((expected > 0.05) & (expected < 0.95))
    np.testing.assert_allclose(f, expected, atol=1e-5)


@pytest.mark.parametrize("seed", range(4))
def test_density_bounds_the_brute_force_ray_maximum_from_above_for_general_outers(seed):
    rng = np.random.default_rng(90 + seed)
    cam = random_camera(rng, kind=1)
    pose, inner, outer = _body(rng, cam)
    box = body_bbox(cam, pose, outer)
    pixels = rng.uniform([box.u0, box.v0], [box.u1, box.v1], size=(60, 2))
    f = projected_density(cam, pose, inner, outer, pixels)
    expected = brute_force_ray_max(cam, pose, inner, outer, pixels)
    assert np.all(f >= expected - 1e-5)
    assert np.all((expected < 1.0) | (f == 1.0))  # a ray through the inner body has density 1 in both


def test_the_radially_linear_3d_density_is_linear_in_the_radius_between_the_surfaces():
    inner, outer = np.array([1.0, 0.5, 0.3]), np.array([1.5, 0.6, 0.9])
    u = np.array([0.3, -0.4, 0.5])
    u /= np.linalg.norm(u)
    r_in = 1 / np.linalg.norm(u / inner)
    r_out = 1 / np.linalg.norm(u / outer)
    r = np.linspace(r_in, r_out, 11)
    g = radial_linear_density(r[:, None] * u, inner, outer)
    np.testing.assert_allclose(g, np.linspace(1, 0, 11), atol=1e-12)


@pytest.mark.parametrize("with_dist", [False, True])
def test_density_region_equals_the_full_image_slice_and_the_density_is_zero_outside_it(with_dist):
    rng = np.random.default_rng(11)
    cam = random_camera(rng, kind=1, dist=DIST if with_dist else None)
    pose, inner, outer = _body(rng, cam)
    full = projected_density(cam, pose, inner, outer)
    box, region = density_region(cam, pose, inner, outer)
    np.testing.assert_array_equal(region, full[box.slices])
    rest = full.copy()
    rest[box.slices] = 0
    assert full[box.slices].max() == 1.0 and not rest.any()
    sub = BBox(box.u0 + 2, box.v0 + 1, box.u1 - 3, box.v1 - 2)
    np.testing.assert_array_equal(projected_density(cam, pose, inner, outer, bbox=sub), full[sub.slices])


def test_density_at_pixel_coordinates_matches_the_image_at_pixel_centres():
    rng = np.random.default_rng(12)
    cam = random_camera(rng, kind=2, dist=DIST)
    pose, inner, outer = _body(rng, cam)
    full = projected_density(cam, pose, inner, outer)
    v, u = rng.integers(0, cam.height, 300), rng.integers(0, cam.width, 300)
    at = projected_density(cam, pose, inner, outer, np.column_stack([u, v]).astype(float))
    np.testing.assert_allclose(at, full[v, u], atol=1e-9)


def test_a_body_behind_the_camera_has_zero_density_and_one_around_the_camera_is_one_everywhere():
    cam = Camera.default()
    behind = pin.SE3(np.eye(3), np.array([0.0, 0.0, -4.0]))
    assert not projected_density(cam, behind, [1, 1, 1], [2, 2, 2]).any()
    around = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.5]))
    assert np.all(projected_density(cam, around, [1, 1, 1], [2, 2, 2]) == 1.0)


def test_outer_smaller_than_inner_is_rejected():
    with pytest.raises(ValueError, match="outer"):
        projected_density(Camera.default(), pin.SE3.Identity(), [1, 1, 1], [2, 0.5, 2])


@pytest.mark.parametrize("with_dist", [False, True])
@pytest.mark.parametrize("seed", range(5))
def test_body_depth_matches_the_raycast_depth(seed, with_dist):
    rng = np.random.default_rng(300 + seed)
    cam = random_camera(rng, kind=seed % 3, dist=DIST if with_dist else None)
    pose, axes = random_body_in_view(rng, cam)
    labels, depth = render_labels(cam, [(pose, axes)])
    d = body_depth(cam, pose, axes)
    hit = labels == 0
    np.testing.assert_allclose(d[hit], depth[hit], rtol=1e-9)
    assert np.all(np.isinf(d[~hit]) == np.isinf(depth[~hit]))
